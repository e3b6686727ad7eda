"""Label the guardrail points of the real KITTI frames (``../shared/realdata``) by geometry, and
write them as the test fixtures ``tests/data/real_frames/*.npz``.

Usage::

    .venv/bin/python benchmarks/label_real_frames.py [--plot DIR]

How (frame 280 of sequence 01, a German motorway; ``--plot`` draws what is said here):

1. **Road.** A plane through the carriageway's returns (``|y| < 3.5 m``, 4-40 m from the
   sensor, within 0.3 m of the sensor's 1.72 m height, refined three times on the returns within
   0.1 m of it): its residual is 19 mm. Height ``h`` is above that plane.
2. **Rail lines.** For each of the four barriers seen on plots of the scan (the shoulder
   W-beam, the median's near and far rails, the far-side guardrail beyond the opposite
   carriageway) a quadratic ``y(x)`` is fitted to the returns in the barrier's band at its
   rail's height, refitted three times on the returns within 0.25 m of it.
3. **Rail points** (``guardrail``): within the barrier's half-width of its line and inside its
   rail's height range (below). These are the beams' faces and backs: the crops of every
   barrier show one W-beam (or, in the median, one per carriageway) at a steady height.
4. **Not judged** (``judged`` False): what could be a post or a delineator as much as grass or
   hedge: within 0.3 m of a rail line from 0.1 m above the ground up to the rail, and 0.4 m
   above the rail. A benchmark neither credits nor blames a model for these.
5. Everything else is judged and is not guardrail.

No camera image comes with frame 280. The Karlsruhe street (``raw_2011_09_26_f0000``) holds no
guardrail (seen in its image): every point is judged and none is guardrail.

The fixtures hold, per point of the ``.bin`` in its order: ``guardrail`` and ``judged``
(packed bits), ``barrier`` (uint8: 0 none, else the barrier's number), the barrier ``names``,
the frame's ``n_points`` and the ``sha256`` of the ``.bin`` (the benchmark checks both).
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SEQUENCES = ROOT.parent / "shared" / "realdata" / "kitti-odometry" / "sequences"
FIXTURES = ROOT / "tests" / "data" / "real_frames"
SENSOR_HEIGHT_M = 1.72
BIN_M = 2.0
#: Metres across a rail line within which what is not rail is not judged (posts, blockouts).
DOUBT_M = 0.5


@dataclass(frozen=True)
class Barrier:
    """One barrier of a frame: where to find its rail and how wide and high the rail is.

    Attributes
    ----------
    name : what it is
    band_y : (lo, hi) metres, sensor frame: the band the rail line is fitted in
    rail_h : (lo, hi) metres above the road plane: the rail's height range
    half_width : metres across the rail line that belong to the rail
    """

    name: str
    band_y: tuple[float, float]
    rail_h: tuple[float, float]
    half_width: float


#: The barriers of KITTI sequence 01, frame 280 (see the module's docstring).
FRAME_280 = (
    Barrier("shoulder W-beam (right, y ~ -4.8 m)", (-5.6, -4.0), (0.30, 0.80), 0.20),
    Barrier("median, near rail (y ~ 6.4 m)", (6.0, 6.9), (0.40, 0.88), 0.15),
    Barrier("median, far rail (y ~ 8.2 m)", (7.5, 8.6), (0.62, 1.10), 0.15),
    Barrier("far-side guardrail (y ~ 19.4 m)", (17.8, 20.3), (0.52, 1.10), 0.15),
)


def read_bin(path: Path) -> np.ndarray:
    """(N, 4) float32 x, y, z, reflectance of a KITTI scan."""
    return np.fromfile(path, dtype="<f4").reshape(-1, 4)


def road_height(xyz: np.ndarray) -> np.ndarray:
    """(N,) metres of every point above a plane fitted to the carriageway's returns."""
    x, y, z = xyz.T
    keep = (np.abs(y) < 3.5) & (np.abs(z + SENSOR_HEIGHT_M) < 0.3) & (np.hypot(x, y) > 4)
    keep &= np.abs(x) < 40
    for _ in range(3):
        design = np.c_[x[keep], y[keep], np.ones(int(keep.sum()))]
        coef, *_ = np.linalg.lstsq(design, z[keep], rcond=None)
        residual = z - design_plane(coef, x, y)
        keep &= np.abs(residual) < 0.1
    return z - design_plane(coef, x, y)


def design_plane(coef: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return coef[0] * x + coef[1] * y + coef[2]


def rail_line(xyz: np.ndarray, h: np.ndarray, barrier: Barrier) -> tuple[np.ndarray, np.ndarray]:
    """The barrier's rail line: knots x (K,) and y (K,), metres, 2 m apart along x.

    A quadratic ``y(x)`` fitted within 20 m of the sensor starts it; from there it is followed
    outward bin by bin (the median y of the rail-height returns within 0.3 m of where the line
    heads), so a rail that bends away is followed; it ends after 10 m without a return.
    """
    x, y = xyz[:, 0], xyz[:, 1]
    lo, hi = barrier.band_y
    rail_height = (h > barrier.rail_h[0]) & (h < barrier.rail_h[1])
    keep = rail_height & (y > lo) & (y < hi) & (np.abs(x) < 20)
    coef = np.polyfit(x[keep], y[keep], 2)
    for _ in range(3):
        near = keep & (np.abs(y - np.polyval(coef, x)) < 0.25)
        coef = np.polyfit(x[near], y[near], 2)
    knots = {float(k): float(np.polyval(coef, k)) for k in np.arange(-20.0, 20.1, BIN_M)}
    for step in (BIN_M, -BIN_M):
        edge = 20.0 if step > 0 else -20.0
        last, before, empty = knots[edge], knots[edge - step], 0
        k = edge + step
        while empty < 5 and abs(k) < 120:
            heading = last + (last - before)
            inside = rail_height & (np.abs(x - k) < BIN_M / 2) & (np.abs(y - heading) < 0.3)
            if inside.sum() >= 3:
                before, last, empty = last, float(np.median(y[inside])), 0
                knots[k] = last
            else:
                before, last, empty = last, heading, empty + 1
            k += step
    kx = np.array(sorted(knots))
    return kx, np.array([knots[k] for k in kx])


def across_rail(xyz: np.ndarray, line: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """(N,) metres from the rail line along y; infinite beyond the line's ends."""
    kx, ky = line
    x = xyz[:, 0]
    across = xyz[:, 1] - np.interp(x, kx, ky)
    return np.where((x >= kx[0]) & (x <= kx[-1]), across, np.inf)


def label_frame(xyz: np.ndarray, barriers: tuple[Barrier, ...]) -> dict[str, np.ndarray]:
    """Per point (N,): ``guardrail`` bool, ``judged`` bool and ``barrier`` uint8 (1-based)."""
    h = road_height(xyz)
    n = len(xyz)
    guardrail = np.zeros(n, bool)
    judged = np.ones(n, bool)
    barrier_of = np.zeros(n, np.uint8)
    for number, barrier in enumerate(barriers, start=1):
        across = across_rail(xyz, rail_line(xyz, h, barrier))
        lo, hi = barrier.rail_h
        rail = (np.abs(across) < barrier.half_width) & (h >= lo) & (h <= hi)
        doubtful = (np.abs(across) < DOUBT_M) & (h > 0.1) & (h < hi + 0.4) & ~rail
        guardrail |= rail
        barrier_of[rail] = number
        judged &= ~doubtful
    judged |= guardrail
    return {"guardrail": guardrail, "judged": judged, "barrier": barrier_of, "height": h}


def write_fixture(
    path: Path, scan_path: Path, labels: dict[str, np.ndarray], names: list[str]
) -> None:
    data = scan_path.read_bytes()
    np.savez_compressed(
        path,
        guardrail=np.packbits(labels["guardrail"]),
        judged=np.packbits(labels["judged"]),
        barrier=labels["barrier"],
        names=np.array(names),
        n_points=np.int64(len(labels["guardrail"])),
        sha256=np.array(hashlib.sha256(data).hexdigest()),
    )


def plot(path: Path, xyz: np.ndarray, labels: dict[str, np.ndarray]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x, y, _ = xyz.T
    h = labels["height"]
    colour = np.where(labels["guardrail"], 2, np.where(labels["judged"], 0, 1))
    fig, axes = plt.subplots(2, 1, figsize=(20, 14))
    near = (np.abs(x) < 60) & (np.abs(y) < 25)
    axes[0].scatter(x[near], y[near], c=colour[near], s=0.4, cmap="brg")
    axes[0].set_title("guardrail (green), not judged (red), other (blue); top view, metres")
    axes[0].set_aspect("equal")
    side = near & (h > -0.5) & (h < 2)
    axes[1].scatter(y[side], h[side], c=colour[side], s=0.4, cmap="brg")
    axes[1].set_title("across (y) and height above the road, metres")
    fig.savefig(path, dpi=70)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plot", type=Path, help="draw each frame's labels into this folder")
    args = parser.parse_args(argv)
    motorway = SEQUENCES / "01" / "velodyne" / "000280.bin"
    street = SEQUENCES / "raw_2011_09_26_f0000" / "velodyne" / "000000.bin"
    if not motorway.is_file() or not street.is_file():
        parser.error(f"the real KITTI scans are not under {SEQUENCES}")
    FIXTURES.mkdir(parents=True, exist_ok=True)
    scan = read_bin(motorway)[:, :3].astype(np.float64)
    labels = label_frame(scan, FRAME_280)
    write_fixture(FIXTURES / "kitti01_000280.npz", motorway, labels, [b.name for b in FRAME_280])
    n_street = len(read_bin(street))
    empty = {
        "guardrail": np.zeros(n_street, bool),
        "judged": np.ones(n_street, bool),
        "barrier": np.zeros(n_street, np.uint8),
    }
    write_fixture(FIXTURES / "kitti_raw_2011_09_26_000000.npz", street, empty, [])
    for number, barrier in enumerate(FRAME_280, start=1):
        print(f"{barrier.name}: {int((labels['barrier'] == number).sum()):,} rail points")
    print(f"not judged: {int((~labels['judged']).sum()):,} of {len(scan):,} points")
    if args.plot:
        args.plot.mkdir(parents=True, exist_ok=True)
        plot(args.plot / "kitti01_000280_labels.png", scan, labels)
    return 0


if __name__ == "__main__":
    sys.exit(main())
