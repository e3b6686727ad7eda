"""`guardrail import kitti`: KITTI odometry frames as a drive folder, on made-up sequences (every
error) and on the real scans of ../shared/realdata (rings, lattice, projection into the image)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from guardrail_core.cli import main
from guardrail_core.errors import (
    FrameRangeError,
    InputInsideOutputError,
    MissingCalibrationError,
    MissingSourceFileError,
    SourceFormatError,
)
from guardrail_core.extract.lattice import build_lattice
from guardrail_core.formats.drive import load_drive
from guardrail_core.importers.kitti import import_kitti, parse_frames, recover_rings
from guardrail_core.sensors.scanner import MULTIBEAM
from tests.file_tree import file_tree
from tests.kitti_data import KITTI_RAW, KITTI_SEQ01, require_kitti

IDENTITY_3X4 = " ".join(["1", "0", "0", "0", "0", "1", "0", "0", "0", "0", "1", "0"])
# KITTI's Tr: velodyne (x forward, y left, z up) -> camera 0 (x right, y down, z forward).
TR_3X4 = "0 -1 0 0 0 0 -1 0 1 0 0 0"


def _sweep(rings: int, per_ring: int, rng: np.random.Generator) -> np.ndarray:
    """(rings * per_ring, 4) float32: a scan written ring by ring, highest beam first, each ring
    a sweep of increasing azimuth over the whole turn, at 10 m."""
    rows = []
    for ring in range(rings):
        elevation = np.deg2rad(2.0 - 0.4 * ring)
        azimuth = np.sort(rng.uniform(-np.pi, np.pi, per_ring))
        r = 10.0
        rows.append(
            np.stack(
                [
                    r * np.cos(elevation) * np.cos(azimuth),
                    r * np.cos(elevation) * np.sin(azimuth),
                    np.full(per_ring, r * np.sin(elevation)),
                    np.full(per_ring, 0.5),
                ],
                axis=1,
            )
        )
    return np.concatenate(rows).astype(np.float32)


def _sequence(root: Path, frames: int = 3, *, scans: tuple[int, ...] = (0, 1, 2)) -> Path:
    """A small KITTI-layout sequence: the car drives 1 m along its x axis per frame."""
    rng = np.random.default_rng(0)
    (root / "velodyne").mkdir(parents=True)
    (root / "calib.txt").write_text(f"P0: {IDENTITY_3X4}\nTr: {TR_3X4}\n")
    poses = []
    for f in range(frames):
        # Camera 0 moves along its z axis (forward).
        pose = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, float(f)]], np.float64)
        poses.append(" ".join(f"{v:g}" for v in pose.ravel()))
    (root / "poses.txt").write_text("\n".join(poses) + "\n")
    (root / "times.txt").write_text("\n".join(f"{0.1 * f:.6f}" for f in range(frames)) + "\n")
    for f in scans:
        _sweep(8, 200, rng).tofile(root / "velodyne" / f"{f:06d}.bin")
    return root


def test_parse_frames() -> None:
    assert parse_frames("280,281") == [280, 281]
    assert parse_frames("270-273") == [270, 271, 272, 273]
    assert parse_frames("5, 1-2,2") == [1, 2, 5]
    for bad in ("a", "3-1", "1,,2", "-4"):
        with pytest.raises(FrameRangeError):
            parse_frames(bad)


def test_recover_rings_from_order_and_elevation() -> None:
    scan = _sweep(16, 300, np.random.default_rng(1))
    ring, found = recover_rings(scan[:, :3])
    assert found == 16
    np.testing.assert_array_equal(ring, np.repeat(np.arange(16), 300))
    # Rows follow elevation, not file order: reversing the rings' order reverses nothing.
    reordered = np.concatenate([scan[300 * k : 300 * (k + 1)] for k in range(15, -1, -1)])
    ring, _ = recover_rings(reordered[:, :3])
    np.testing.assert_array_equal(ring, np.repeat(np.arange(15, -1, -1), 300))


def test_import_merges_frames_with_their_poses(tmp_path: Path) -> None:
    seq = _sequence(tmp_path / "seq")
    result = import_kitti(seq, tmp_path / "drive", frames=[1, 2])
    drive = load_drive(tmp_path / "drive")
    assert result.frames == [1, 2] and result.rings == 8 and result.n_images == 0
    assert len(drive.points) == 2 * 8 * 200
    assert drive.scanner.kind == MULTIBEAM and drive.cameras == {} and drive.images == []
    # The world is frame 1's sensor: its points sit at 10 m from the origin, frame 2's from
    # (1, 0, 0), one metre further along the drive.
    first = np.isclose(drive.points.gps_time, 0.1)
    np.testing.assert_allclose(np.linalg.norm(drive.points.xyz[first], axis=1), 10.0, atol=1e-4)
    second = ~first
    shifted = drive.points.xyz[second] - [1.0, 0.0, 0.0]
    np.testing.assert_allclose(np.linalg.norm(shifted, axis=1), 10.0, atol=1e-4)
    # The trajectory runs through frames 0..2 (the neighbours give the heading): yaw 0, 1 m steps.
    np.testing.assert_allclose(drive.trajectory.position[:, 0], [-1.0, 0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(drive.trajectory.attitude, 0.0, atol=1e-9)
    # Two frames occupy separate blocks of lattice rows.
    lattice = build_lattice(
        drive.points.rotation, drive.points.phase, drive.scanner.points_per_rotation
    )
    assert lattice.grid.shape[0] == 2 * 9 - 1
    assert np.all(lattice.grid[8] == -1)


def test_default_frames_are_the_scans_present(tmp_path: Path) -> None:
    seq = _sequence(tmp_path / "seq", frames=5, scans=(3,))
    assert import_kitti(seq, tmp_path / "drive").frames == [3]


@pytest.mark.parametrize(
    ("damage", "error", "words"),
    [
        (lambda s: (s / "calib.txt").unlink(), MissingSourceFileError, "calib.txt"),
        (
            lambda s: (s / "calib.txt").write_text(f"P0: {IDENTITY_3X4}\n"),
            MissingCalibrationError,
            "Tr",
        ),
        (lambda s: (s / "calib.txt").write_text("Tr: 1 2 3\n"), SourceFormatError, "12"),
        (lambda s: (s / "poses.txt").unlink(), MissingSourceFileError, "poses.txt"),
        (lambda s: (s / "times.txt").write_text("0\n0.1\n"), SourceFormatError, "times.txt"),
        (lambda s: (s / "velodyne" / "000001.bin").unlink(), MissingSourceFileError, "000001.bin"),
        (
            lambda s: (s / "velodyne" / "000001.bin").write_bytes(b"\0" * 10),
            SourceFormatError,
            "16 bytes",
        ),
        (lambda s: (s / "velodyne" / "000001.bin").write_bytes(b""), SourceFormatError, "empty"),
        (lambda s: (s / "image_2").mkdir(), MissingSourceFileError, "image_2"),
    ],
)
def test_bad_sequences_name_what_is_missing(
    tmp_path: Path, damage, error: type[Exception], words: str
) -> None:
    seq = _sequence(tmp_path / "seq")
    damage(seq)
    with pytest.raises(error, match=words):
        import_kitti(seq, tmp_path / "drive", frames=[0, 1])
    assert not (tmp_path / "drive").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["seq"]  # no staging folder left behind


def test_frame_out_of_range(tmp_path: Path) -> None:
    seq = _sequence(tmp_path / "seq")
    with pytest.raises(FrameRangeError, match=r"0\.\.2"):
        import_kitti(seq, tmp_path / "drive", frames=[2, 3])
    assert main(["import", "kitti", str(seq), "--frames", "7", "--out", str(tmp_path / "d")]) == 2
    assert not (tmp_path / "d").exists()


def test_cli_imports(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    seq = _sequence(tmp_path / "seq")
    out = tmp_path / "drive"
    assert main(["import", "kitti", str(seq), "--frames", "0-1", "--out", str(out), "--quiet"]) == 0
    assert "imported 2 frames (3,200 points, 8 rings, 0 images)" in capsys.readouterr().out
    assert len(load_drive(out).points) == 3200


def test_a_sequence_inside_the_output_is_refused_and_survives(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The data loss of issue 19: with SEQ inside OUT, `--overwrite` used to delete SEQ."""
    out = tmp_path / "out"
    seq = _sequence(out / "seq")
    (out / "notes.txt").write_text("an earlier drive's notes")
    before = file_tree(out)
    command = ["import", "kitti", str(seq), "--frames", "1", "--out", str(out), "--overwrite"]
    assert main([*command, "--quiet"]) == 2
    assert "InputInsideOutputError" in capsys.readouterr().err
    with pytest.raises(InputInsideOutputError, match="would delete the input"):
        import_kitti(seq, out, frames=[1], overwrite=True)
    with pytest.raises(InputInsideOutputError, match="is the input"):
        import_kitti(seq, seq / "velodyne", frames=[1], overwrite=True)
    assert file_tree(out) == before  # byte for byte, and no staging folder
    # A drive beside the sequence's files is no part of it: written, and replaced again.
    import_kitti(seq, seq / "drive", frames=[1])
    import_kitti(seq, seq / "drive", frames=[1, 2], overwrite=True)
    assert load_drive(seq / "drive").source["frames"] == [1, 2]
    assert {k: v for k, v in file_tree(out).items() if "/drive" not in k} == before


def test_a_real_sequence_inside_the_output_survives(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`guardrail import kitti SEQ --frames 280 --out OUT --overwrite` with SEQ inside OUT."""
    require_kitti(KITTI_SEQ01)
    out = tmp_path / "out"
    seq = out / "01"
    (seq / "velodyne").mkdir(parents=True)
    for name in ("calib.txt", "poses.txt", "times.txt", "velodyne/000280.bin"):
        shutil.copyfile(KITTI_SEQ01 / name, seq / name)
    before = file_tree(out)
    command = ["import", "kitti", str(seq), "--frames", "280", "--out", str(out), "--overwrite"]
    assert main([*command, "--quiet"]) == 2
    assert "InputInsideOutputError" in capsys.readouterr().err
    assert file_tree(out) == before


# ------------------------------------------------------------------------- real KITTI scans


@pytest.fixture(scope="module")
def seq01_drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    require_kitti(KITTI_SEQ01)
    out = tmp_path_factory.mktemp("kitti") / "seq01_280"
    import_kitti(KITTI_SEQ01, out, frames=[280])
    return out


def test_real_scan_rings_follow_elevation(seq01_drive: Path) -> None:
    drive = load_drive(seq01_drive)
    raw = np.fromfile(KITTI_SEQ01 / "velodyne" / "000280.bin", np.float32).reshape(-1, 4)
    assert len(drive.points) == len(raw) == 89_801
    assert drive.scanner.rings in (64, 65)  # a beam split at the scan's cut counts twice
    elevation = np.arctan2(raw[:, 2], np.hypot(raw[:, 0], raw[:, 1]))
    rows = drive.points.rotation
    medians = np.array([np.median(elevation[rows == r]) for r in np.unique(rows)])
    assert np.all(np.diff(medians) < 0)
    # Lattice neighbours along a ring and across rings are neighbours in space.
    lattice = build_lattice(rows, drive.points.phase, drive.scanner.points_per_rotation)
    xyz = drive.points.xyz
    for step in [(0, 1), (0, 2), (1, 0)]:
        other = lattice.neighbour(*step)
        ok = other >= 0
        gap = np.linalg.norm(xyz[ok] - xyz[other[ok]], axis=1)
        near = np.linalg.norm(xyz[ok], axis=1) < 10.0
        assert np.median(gap[near]) < 0.25, step


def test_real_image_lines_up_with_the_points(tmp_path: Path) -> None:
    """The scan projected through the imported camera lands on the image's silhouettes: points
    at a depth jump along a ring (the left and right outlines of cars, posts, trunks) fall where
    the image's horizontal gradient is strongest, and moving them a few pixels loses that."""
    require_kitti(KITTI_RAW)
    import cv2

    import_kitti(KITTI_RAW, tmp_path / "drive")
    drive = load_drive(tmp_path / "drive")
    record = drive.images[0]
    camera = drive.cameras[record.camera]
    image = drive.read_image(record)
    assert image.shape == (375, 1242, 3)
    lattice = build_lattice(
        drive.points.rotation, drive.points.phase, drive.scanner.points_per_rotation
    )
    xyz = drive.points.xyz
    rng_m = np.linalg.norm(xyz, axis=1)
    outline = np.zeros(len(xyz), bool)  # the near side of a jump of more than 1 m
    for d in (1, 2, -1, -2):
        other = lattice.neighbour(0, d)
        ok = other >= 0
        outline[np.flatnonzero(ok)[rng_m[other[ok]] - rng_m[ok] > 1.0]] = True
    uv, visible = camera.project(xyz[outline], record.T_world_camera)
    uv = uv[visible & camera.inside(uv)]
    assert len(uv) > 200
    grey = cv2.GaussianBlur(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32), (3, 3), 0)
    gradient = np.abs(cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3))

    def score(du: int, dv: int) -> float:
        p = np.rint(uv + (du, dv)).astype(int)
        inside = (p[:, 0] >= 0) & (p[:, 0] < image.shape[1]) & (p[:, 1] >= 0)
        inside &= p[:, 1] < image.shape[0]
        return float(np.mean(gradient[p[inside, 1], p[inside, 0]]))

    shifts = range(-12, 13)
    across = {du: score(du, 0) for du in shifts}
    assert abs(max(across, key=across.__getitem__)) <= 3
    assert across[0] > 1.4 * max(across[-10], across[10])
    up_down = {dv: score(0, dv) for dv in shifts}
    assert abs(max(up_down, key=up_down.__getitem__)) <= 4
    assert up_down[0] > 1.1 * max(up_down[-10], up_down[10])
