"""Make the README figures from the sample drive.

Usage::

    .venv/bin/python docs/make_figures.py [--drive demo_output/sample_drive] [--out docs/images]

Simulates the sample drive first (scene ``sample``, seed 7, as ``guardrail demo`` does) when the
drive folder does not exist, then writes into ``--out``:

``camera_projection.png``
    a side-camera image with the drive's laser points projected over it (points within 25 m and
    not hidden behind nearer points), guardrails in red and orange, other points by distance;
``point_cloud.png``
    a perspective view of the point cloud from above and behind the vehicle, grey by intensity,
    guardrails in red, other classes faintly tinted;
``truth_mask.png``
    a camera image beside its truth class mask.

Only numpy, OpenCV and the project's own code are used.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from guardrail_core.classes import GUARDRAIL_CLASSES, TruthClass  # noqa: E402
from guardrail_core.formats.drive import Drive, ImageRecord, load_drive  # noqa: E402
from guardrail_core.geom.frames import invert_transform, transform_points  # noqa: E402

MAX_BYTES = 600_000
PROJECTION_RANGE_M = 25.0

#: Display colours (RGB) of the truth classes.
PALETTE: dict[int, tuple[int, int, int]] = {
    TruthClass.NONE: (20, 24, 32),
    TruthClass.ROAD: (110, 110, 120),
    TruthClass.ROAD_MARKING: (240, 240, 240),
    TruthClass.CURB: (170, 150, 110),
    TruthClass.SIDEWALK: (190, 170, 200),
    TruthClass.TERRAIN: (110, 160, 70),
    TruthClass.GUARDRAIL: (235, 30, 30),
    TruthClass.GUARDRAIL_POLE: (255, 150, 0),
    TruthClass.FENCE: (60, 180, 170),
    TruthClass.WALL: (150, 120, 90),
    TruthClass.BICYCLE_RACK: (200, 80, 200),
    TruthClass.BOLLARD: (240, 220, 40),
    TruthClass.POLE: (80, 130, 240),
    TruthClass.SIGN: (40, 90, 200),
    TruthClass.TREE: (30, 120, 40),
    TruthClass.CAR: (120, 200, 250),
    TruthClass.BUILDING: (130, 140, 170),
    TruthClass.PEDESTRIAN: (250, 120, 180),
    TruthClass.VEGETATION: (150, 230, 60),
}


def palette_lut() -> np.ndarray:
    """(256, 3) uint8 RGB colour of every class id (unknown ids black)."""
    lut = np.zeros((256, 3), np.uint8)
    for cls, colour in PALETTE.items():
        lut[int(cls)] = colour
    return lut


# ----------------------------------------------------------------------------------- helpers


def ensure_drive(path: Path) -> Drive:
    """Load the drive at ``path``, simulating the sample drive there first if it is absent."""
    if not (path / "drive.json").is_file():
        from guardrail_core.synth.scene import load_scene_spec
        from guardrail_core.synth.simulate import simulate_drive

        print(f"simulating the sample drive into {path} (about a minute)")
        simulate_drive(load_scene_spec("sample"), path, seed=7, overwrite=True, progress=True)
    return load_drive(path)


def write_png(path: Path, rgb: np.ndarray, max_bytes: int = MAX_BYTES) -> None:
    """Write an RGB image as PNG (compression 9), reducing colours and then size to fit."""
    bgr = np.ascontiguousarray(rgb[:, :, ::-1])
    for levels in (256, 64, 32, 16):
        step = 256 // levels
        img = bgr if levels == 256 else (bgr // step * step + step // 2).astype(np.uint8)
        ok, data = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        if ok and len(data) <= max_bytes:
            path.write_bytes(data.tobytes())
            print(f"wrote {path} ({rgb.shape[1]}x{rgb.shape[0]}, {len(data) / 1000:.0f} kB)")
            return
    smaller = cv2.resize(rgb, None, fx=0.85, fy=0.85, interpolation=cv2.INTER_AREA)
    write_png(path, smaller, max_bytes)


def put_label(img: np.ndarray, text: str, org: tuple[int, int], scale: float = 0.6) -> None:
    """White text on a dark translucent box, top-left corner at ``org`` (in place)."""
    font, thick = cv2.FONT_HERSHEY_SIMPLEX, 1
    (w, h), base = cv2.getTextSize(text, font, scale, thick)
    x, y = org
    x0, y0, x1, y1 = x, y, min(x + w + 12, img.shape[1]), min(y + h + base + 10, img.shape[0])
    img[y0:y1, x0:x1] = (img[y0:y1, x0:x1] * 0.35).astype(np.uint8)
    cv2.putText(img, text, (x + 6, y + h + 5), font, scale, (255, 255, 255), thick, cv2.LINE_AA)


def draw_legend(
    img: np.ndarray, items: list[tuple[str, tuple[int, int, int]]], org: tuple[int, int]
) -> None:
    """A column of colour swatches with names on a dark box (in place)."""
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.5
    row = 20
    width = max(cv2.getTextSize(t, font, scale, 1)[0][0] for t, _ in items) + 40
    x, y = org
    y1, x1 = min(y + row * len(items) + 10, img.shape[0]), min(x + width, img.shape[1])
    img[y:y1, x:x1] = (img[y:y1, x:x1] * 0.3).astype(np.uint8)
    for i, (text, colour) in enumerate(items):
        cy = y + 8 + i * row
        cv2.rectangle(img, (x + 8, cy), (x + 22, cy + 12), colour, -1)
        cv2.putText(img, text, (x + 30, cy + 11), font, scale, (255, 255, 255), 1, cv2.LINE_AA)


def legend_strip(
    width: int, items: list[tuple[str, tuple[int, int, int]]], height: int = 30
) -> np.ndarray:
    """A dark strip ``width`` pixels wide with colour swatches and names in a row."""
    strip = np.full((height, width, 3), 32, np.uint8)
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.5
    x = 10
    for text, colour in items:
        tw = cv2.getTextSize(text, font, scale, 1)[0][0]
        if x + tw + 30 > width:
            break
        cy = height // 2
        cv2.rectangle(strip, (x, cy - 6), (x + 12, cy + 6), colour, -1)
        cv2.putText(strip, text, (x + 18, cy + 5), font, scale, (235, 235, 235), 1, cv2.LINE_AA)
        x += tw + 36
    return strip


def class_name(cls: int) -> str:
    return TruthClass(cls).name.lower().replace("_", " ")


def depth_colours(depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """(N, 3) uint8 RGB for distances: cyan (near) to violet (far), a ramp free of red."""
    t = np.clip((depth - near) / (far - near), 0.0, 1.0)[:, None]
    near_c = np.array([90, 255, 230], np.float64)
    mid_c = np.array([70, 140, 255], np.float64)
    far_c = np.array([150, 70, 220], np.float64)
    c = np.where(
        t < 0.5, near_c + (mid_c - near_c) * (t / 0.5), mid_c + (far_c - mid_c) * ((t - 0.5) / 0.5)
    )
    return c.astype(np.uint8)


def visible_points(
    uv: np.ndarray, depth: np.ndarray, shape: tuple[int, int], cell: int = 4, slack: float = 0.04
) -> np.ndarray:
    """Which projected points are not hidden: a z-buffer on ``cell``-pixel cells.

    Scan points are sparse, so a strict one-pixel z-buffer lets far points shine through the gaps
    between near ones; a coarse cell with a relative depth slack keeps the nearest surface only.
    """
    h, w = shape
    cu = np.clip((uv[:, 0] + 0.5).astype(np.int64) // cell, 0, (w - 1) // cell)
    cv_ = np.clip((uv[:, 1] + 0.5).astype(np.int64) // cell, 0, (h - 1) // cell)
    index = cv_ * ((w - 1) // cell + 1) + cu
    nearest = np.full(index.max() + 1 if len(index) else 1, np.inf)
    np.minimum.at(nearest, index, depth)
    return depth <= nearest[index] * (1.0 + slack) + 0.15


# ------------------------------------------------------------------------- camera projection


def camera_points(drive: Drive, record: ImageRecord, max_range: float = PROJECTION_RANGE_M):
    """Indices, pixel coordinates and camera depths of the points seen in an image, nearest kept."""
    camera = drive.cameras[record.camera]
    centre = record.T_world_camera[:3, 3]
    near = np.flatnonzero(np.linalg.norm(drive.points.xyz - centre, axis=1) <= max_range)
    uv, valid = camera.project(drive.points.xyz[near], record.T_world_camera)
    keep = valid & camera.inside(uv)
    idx, uv = near[keep], uv[keep]
    depth = transform_points(invert_transform(record.T_world_camera), drive.points.xyz[idx])[:, 2]
    seen = visible_points(uv, depth, (camera.height, camera.width))
    return idx[seen], uv[seen], depth[seen]


def pick_image(drive: Drive, camera: str) -> ImageRecord:
    """The image of ``camera`` onto which the most guardrail (pipe and beam) points project."""
    assert drive.truth is not None
    best, best_count = None, -1
    rail = drive.truth.point_class == TruthClass.GUARDRAIL
    for record in drive.images:
        if record.camera != camera:
            continue
        idx, _, _ = camera_points(drive, record)
        count = int(np.count_nonzero(rail[idx]))
        if count > best_count:
            best, best_count = record, count
    if best is None:
        raise SystemExit(f"the drive has no images of the camera {camera!r}")
    print(f"camera_projection: {best.file} ({best_count} guardrail points in view)")
    return best


def make_camera_projection(drive: Drive, out: Path, camera: str = "left") -> ImageRecord:
    assert drive.truth is not None
    record = pick_image(drive, camera)
    image = drive.read_image(record)
    idx, uv, depth = camera_points(drive, record)
    cls = drive.truth.point_class[idx]

    # Dim and desaturate the photo a little so that the points stand out.
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)[:, :, None].astype(np.float64)
    canvas = (0.7 * image + 0.2 * grey).clip(0, 255).astype(np.uint8)

    is_rail = np.isin(cls, list(GUARDRAIL_CLASSES))
    colours = depth_colours(depth, 2.0, PROJECTION_RANGE_M)
    colours[cls == TruthClass.GUARDRAIL] = PALETTE[TruthClass.GUARDRAIL]
    colours[cls == TruthClass.GUARDRAIL_POLE] = PALETTE[TruthClass.GUARDRAIL_POLE]

    # Other points as single pixels (the photo shows between the scan lines), far first so that
    # near points win; guardrail points on top as small discs.
    px = np.round(uv).astype(np.int32)
    others = np.flatnonzero(~is_rail)
    others = others[np.argsort(-depth[others])]
    layer = canvas.copy()
    layer[px[others, 1], px[others, 0]] = colours[others]
    canvas = cv2.addWeighted(layer, 0.85, canvas, 0.15, 0)
    for i in np.flatnonzero(is_rail)[np.argsort(-depth[is_rail])]:
        cv2.circle(canvas, (int(px[i, 0]), int(px[i, 1])), 2, tuple(int(c) for c in colours[i]), -1)

    name = Path(record.file).name
    put_label(
        canvas,
        f"{record.camera} camera, {name}: {len(idx):,} laser points within {PROJECTION_RANGE_M:g} m",
        (10, 10),
    )
    near, far = depth_colours(np.array([2.0, PROJECTION_RANGE_M]), 2.0, PROJECTION_RANGE_M)
    draw_legend(
        canvas,
        [
            ("guardrail (pipes, beams)", PALETTE[TruthClass.GUARDRAIL]),
            ("guardrail pole", PALETTE[TruthClass.GUARDRAIL_POLE]),
            ("other points, 2 m", tuple(int(c) for c in near)),
            (f"other points, {PROJECTION_RANGE_M:g} m", tuple(int(c) for c in far)),
        ],
        (10, canvas.shape[0] - 100),
    )
    write_png(out / "camera_projection.png", canvas)
    return record


# ------------------------------------------------------------------------------- point cloud


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_camera of an OpenCV camera (x right, y down, z forward) at ``eye`` facing ``target``."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, np.float64))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    t = np.eye(4)
    t[:3, :3] = np.column_stack([x, y, z])
    t[:3, 3] = eye
    return t


def splat(
    xyz: np.ndarray,
    rgb: np.ndarray,
    T_world_camera: np.ndarray,
    size: tuple[int, int],
    focal: float,
    radius: int = 1,
    background: tuple[int, int, int] = (24, 28, 38),
) -> tuple[np.ndarray, np.ndarray]:
    """Render points with a z-buffer, each a (2 radius)-pixel square; returns image and depth."""
    w, h = size
    cam = transform_points(invert_transform(T_world_camera), xyz)
    front = cam[:, 2] > 0.5
    cam, rgb = cam[front], rgb[front]
    u = focal * cam[:, 0] / cam[:, 2] + w / 2
    v = focal * cam[:, 1] / cam[:, 2] + h / 2
    # Points nearer the eye are drawn larger.
    zs, us, vs, cs = [], [], [], []
    offsets = [
        (du, dv) for du in range(-radius + 1, radius + 1) for dv in range(-radius + 1, radius + 1)
    ]
    for du, dv in offsets:
        ui = np.floor(u).astype(np.int64) + du
        vi = np.floor(v).astype(np.int64) + dv
        ok = (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
        zs.append(cam[ok, 2])
        us.append(ui[ok])
        vs.append(vi[ok])
        cs.append(rgb[ok])
    z, ui, vi, c = (np.concatenate(a) for a in (zs, us, vs, cs))
    pix = vi * w + ui
    order = np.lexsort((z, pix))  # by pixel, then nearest first
    first = np.ones(len(order), bool)
    first[1:] = pix[order][1:] != pix[order][:-1]
    win = order[first]
    image = np.empty((h * w, 3), np.uint8)
    image[:] = background
    depth = np.full(h * w, np.inf)
    image[pix[win]] = c[win]
    depth[pix[win]] = z[win]
    return image.reshape(h, w, 3), depth.reshape(h, w)


def eye_dome(image: np.ndarray, depth: np.ndarray, strength: float = 0.7) -> np.ndarray:
    """Darken pixels that lie behind their neighbours (eye-dome lighting): edges read better."""
    finite = np.isfinite(depth)
    logd = np.where(finite, np.log(np.where(finite, depth, 1.0)), np.nan)
    shade = np.zeros_like(depth)
    for du, dv in ((2, 0), (-2, 0), (0, 2), (0, -2)):
        nb = np.roll(np.roll(logd, dv, axis=0), du, axis=1)
        diff = logd - nb
        shade += np.where(np.isfinite(diff), np.maximum(diff, 0.0), 0.0)
    factor = np.exp(-strength * 40.0 * shade)
    out = image.astype(np.float64)
    out[finite] *= factor[finite, None]
    return out.clip(0, 255).astype(np.uint8)


def overview_pose(drive: Drive) -> tuple[np.ndarray, np.ndarray]:
    """Eye (3,) and T_world_camera (4, 4) of the overview: a stretch a little past the middle
    of the drive, seen from above and behind."""
    traj = drive.trajectory
    t_mid = traj.time[0] + 0.38 * (traj.time[-1] - traj.time[0])
    pos, _ = traj.interpolate(np.array([t_mid]))
    ahead, _ = traj.interpolate(np.array([t_mid + 1.0]))
    pos, ahead = pos[0], ahead[0]
    heading = (ahead - pos) / np.linalg.norm(ahead - pos)
    side = np.cross([0.0, 0.0, 1.0], heading)
    eye = pos - 14.0 * heading + 3.0 * side + np.array([0, 0, 11.0])
    return eye, look_at(eye, pos + 16.0 * heading + np.array([0, 0, -1.0]))


def make_point_cloud(drive: Drive, out: Path, size: tuple[int, int] = (1400, 800)) -> None:
    assert drive.truth is not None
    eye, pose = overview_pose(drive)

    xyz = drive.points.xyz
    near = np.linalg.norm(xyz[:, :2] - eye[:2], axis=1) < 90.0
    xyz, cls = xyz[near], drive.truth.point_class[near]
    inten = drive.points.intensity[near].astype(np.float64)
    lo, hi = np.percentile(inten, [2, 98])
    grey = np.clip((inten - lo) / max(hi - lo, 1.0), 0, 1) ** 0.8
    grey = 70 + 175 * grey
    rgb = np.repeat(grey[:, None], 3, axis=1)
    tint = palette_lut()[cls].astype(np.float64)
    rgb = 0.7 * rgb + 0.3 * tint
    rail = np.isin(cls, list(GUARDRAIL_CLASSES))
    rgb[cls == TruthClass.GUARDRAIL] = PALETTE[TruthClass.GUARDRAIL]
    rgb[cls == TruthClass.GUARDRAIL_POLE] = PALETTE[TruthClass.GUARDRAIL_POLE]
    rgb = rgb.clip(0, 255).astype(np.uint8)

    focal = 0.62 * size[0]
    image, depth = splat(xyz, rgb, pose, size, focal, radius=1)
    # Guardrails again on top (with a depth slack) so that thin pipes stay visible at distance.
    rail_img, rail_depth = splat(xyz[rail], rgb[rail], pose, size, focal, radius=1)
    win = rail_depth <= depth + 0.3
    image[win & np.isfinite(rail_depth)] = rail_img[win & np.isfinite(rail_depth)]
    depth = np.minimum(depth, rail_depth)
    image = eye_dome(image, depth)

    put_label(
        image,
        f"sample drive: {len(drive.points):,} laser points, grey by intensity; "
        "truth guardrails in red, their poles in orange",
        (10, 10),
    )
    shown = [
        TruthClass.GUARDRAIL,
        TruthClass.GUARDRAIL_POLE,
        TruthClass.FENCE,
        TruthClass.WALL,
        TruthClass.POLE,
        TruthClass.TREE,
        TruthClass.CAR,
        TruthClass.BUILDING,
    ]
    draw_legend(
        image,
        [(class_name(c), PALETTE[c]) for c in shown],
        (10, size[1] - 20 * len(shown) - 20),
    )
    write_png(out / "point_cloud.png", image)


# -------------------------------------------------------------------------------- truth mask


def make_truth_mask(drive: Drive, out: Path, record: ImageRecord) -> None:
    image = drive.read_image(record)
    mask = drive.read_mask(record)
    coloured = palette_lut()[mask]
    blend = (0.25 * image + 0.75 * coloured).astype(np.uint8)
    gap = np.full((image.shape[0], 12, 3), 255, np.uint8)
    both = np.concatenate([image, gap, blend], axis=1)
    scale = 1400 / both.shape[1]
    both = cv2.resize(both, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    x_right = int(round((image.shape[1] + gap.shape[1]) * scale))
    put_label(both, f"{record.camera} camera image", (8, 8), 0.55)
    put_label(both, "truth class mask (truth/masks)", (x_right + 8, 8), 0.55)
    present = [int(c) for c in np.unique(mask) if int(c) in PALETTE and c != TruthClass.NONE]
    # Guardrail classes first, then the others by id.
    present.sort(key=lambda c: (c not in GUARDRAIL_CLASSES, c))
    strip = legend_strip(both.shape[1], [(class_name(c), PALETTE[c]) for c in present])
    both = np.concatenate([both, strip], axis=0)
    write_png(out / "truth_mask.png", both)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Make the README figures from the sample drive.")
    parser.add_argument("--drive", type=Path, default=Path("demo_output/sample_drive"))
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "images")
    parser.add_argument("--camera", default="left", help="camera of the projection figure")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    drive = ensure_drive(args.drive)
    if drive.truth is None:
        raise SystemExit(f"{args.drive}: not a simulated drive (no truth/), cannot colour by class")
    record = make_camera_projection(drive, args.out, args.camera)
    make_point_cloud(drive, args.out)
    make_truth_mask(drive, args.out, record)
    return 0


if __name__ == "__main__":
    sys.exit(main())
