"""Real KITTI scans through the whole product with the shipped default model: the motorway's
W-beam guardrail found and reconstructed (sequence 01, frame 280), and the Karlsruhe street's
image crops cut at the projected points with no guardrail reported (raw 2011_09_26, frame 0).

Frame 280 is unlabelled; the figures come from where its README (and a look at the scan) places
things in the sensor frame, which is the imported drive's frame: the road at z = -1.72 m, the
W-beam on the right shoulder at y in [-5.5, -3.5] m with its rail 0.3-0.9 m above the road, the
median barrier at y in [5.5, 9] m, a far-side guardrail at y ~ 19.5 m.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import laspy
import numpy as np
import pytest

from guardrail_core.cli import main
from guardrail_core.export.run_export import load_export_source
from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR, load_model
from guardrail_core.extract.crops import CROP_OK, CropParams, crop_window, cut_crop
from guardrail_core.formats.drive import Drive, load_drive
from guardrail_core.formats.run_folder import Run, load_run
from guardrail_core.importers.kitti import import_kitti
from guardrail_core.process import process_drive
from guardrail_core.review.run_crops import read_crops
from tests.export.test_export_opendrive import Reader, _check_objects
from tests.kitti_data import KITTI_RAW, KITTI_SEQ01, require_kitti

ROAD_Z_M = -1.72
WINDOW_M = 40.0


def _process(sequence: Path, frame: int, root: Path) -> tuple[Drive, Run, Path]:
    import_kitti(sequence, root / "drive", frames=[frame])
    drive = load_drive(root / "drive")
    process_drive(drive, load_model(DEFAULT_MODEL_DIR), root / "run")
    return drive, load_run(root / "run"), root / "run"


@pytest.fixture(scope="module")
def motorway(tmp_path_factory: pytest.TempPathFactory) -> tuple[Drive, Run, Path]:
    require_kitti(KITTI_SEQ01)
    return _process(KITTI_SEQ01, 280, tmp_path_factory.mktemp("kitti01"))


def _guardrail_points(run: Run) -> np.ndarray:
    segment = run.point_segment
    found = np.zeros(len(segment), bool)
    inside = segment >= 0
    found[inside] = run.segments["label"][segment[inside]]
    return found


def test_motorway_guardrail_found_along_the_window(motorway) -> None:
    drive, run, _ = motorway
    x, y, z = drive.points.xyz.T
    found = _guardrail_points(run)
    height = z - ROAD_Z_M
    window = np.abs(x) < WINDOW_M
    rail = window & (height > 0.3) & (height < 0.9)

    # The right shoulder's W-beam: guardrail points in >= 85% of the one-metre stretches where
    # the scan has at least 5 points at rail height.
    shoulder = rail & (y > -5.5) & (y < -3.5)
    stretch = np.floor(x + WINDOW_M).astype(np.int64)
    scanned = np.bincount(stretch[shoulder], minlength=80) >= 5
    hit = np.bincount(stretch[shoulder & found], minlength=80) > 0
    assert scanned.sum() >= 40
    assert hit[scanned].mean() >= 0.85

    # The median barrier (two rails with a hedge between them): found in every four-metre
    # stretch (a post spacing) and in >= 85% of the one-metre stretches.
    median = rail & (y > 5.5) & (y < 9.0)
    block = np.floor((x + WINDOW_M) / 4).astype(np.int64)
    scanned = np.bincount(block[median], minlength=20) >= 20
    hit = np.bincount(block[median & found], minlength=20) > 0
    assert scanned.sum() >= 15 and hit[scanned].all()
    scanned = np.bincount(stretch[median], minlength=80) >= 5
    hit = np.bincount(stretch[median & found], minlength=80) > 0
    assert hit[scanned].mean() >= 0.85

    # Few guardrail points anywhere else: not on the road, not in the verges.
    barriers = ((y > -5.5) & (y < -3.5)) | ((y > 5.5) & (y < 9.0)) | ((y > 18.0) & (y < 21.0))
    assert np.count_nonzero(found & ~barriers) <= 0.01 * np.count_nonzero(found)


def test_motorway_w_beam_reconstructed_with_section_and_posts(motorway) -> None:
    _, _, run_dir = motorway
    with (run_dir / "reconstruction" / "inventory.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    shoulder = [
        r for r in rows if r["status"] == "reconstructed" and -5.5 < float(r["start_y"]) < -3.5
    ]
    assert len(shoulder) == 1
    beam = shoulder[0]
    assert beam["type"] == "beam" and beam["signature"].startswith("beam h")
    # A W-beam's section (the standard A profile is 310 mm tall and 85 mm deep) with its top
    # 0.6-0.85 m above the ground, on posts spaced as motorway posts are (4 m).
    section = json.loads(beam["design"])
    assert 0.28 <= section["height_m"] <= 0.40
    assert 0.06 <= section["depth_m"] <= 0.14
    assert 0.6 <= float(beam["rail_top_m"]) <= 0.85
    assert 3.8 <= float(beam["pole_spacing_m"]) <= 4.6
    # The model follows the rail beyond the posts the scan shows (within 5 m of the car; the
    # one at x = -4.6 m has 6 points and is found or not as the run's points change).
    assert int(beam["poles_seen"]) >= 2
    assert float(beam["length_m"]) >= 25.0
    assert (run_dir / "reconstruction" / "meshes" / f"run_{int(beam['run_id']):03d}.glb").is_file()

    models = json.loads((run_dir / "reconstruction" / "models.json").read_text())
    run = next(r for r in models["runs"] if r["run_id"] == int(beam["run_id"]))
    seen = sorted(p["position"][0] for p in run["poles"] if p["n_points"] > 0)
    assert np.all(np.abs(np.diff(seen) - 4.2) < 0.3)
    # Every post stands on the rail's line (a delineator post before it is not one of them).
    posts_y = np.array([p["position"][1] for p in run["poles"]])
    posts_x = np.array([p["position"][0] for p in run["poles"]])
    assert np.all(np.abs(posts_y - np.interp(posts_x, [-10.0, 25.0], [-4.97, -4.64])) < 0.15)
    # The section fits the superimposed points: median distance under 2 cm.
    points = np.load(run_dir / "reconstruction" / "superimposed.npz")[
        f"run_{int(beam['run_id']):03d}_points"
    ][:, [2, 1]]
    curve = np.array(run["model"]["section"])
    points = points[(points[:, 1] >= curve[0, 1]) & (points[:, 1] <= curve[-1, 1])]
    a, ab = curve[:-1], np.diff(curve, axis=0)
    t = np.clip(((points[:, None] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
    distance = np.linalg.norm(points[:, None] - (a + t[..., None] * ab), axis=-1).min(axis=1)
    assert np.median(distance) < 0.02


def test_motorway_exports_las_and_opendrive_and_refuses_the_map_formats(
    motorway, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A KITTI odometry frame has no georeference (its CRS is the velodyne frame): LAS and
    OpenDRIVE are written in that frame, and the formats that place it on the Earth refuse it
    by name with nothing written."""
    _, _, run_dir = motorway
    xodr, laz = tmp_path / "road.xodr", tmp_path / "points.laz"
    assert main(["export", str(run_dir), "--opendrive", str(xodr), "--las", str(laz)]) == 0
    reader = Reader(xodr)
    assert reader.root.find("header/geoReference") is None
    source = load_export_source(run_dir)
    _check_objects(reader, source)
    assert len(reader.objects("barrier")) >= 1  # the W-beam at least
    assert laspy.read(str(laz)).header.point_count > 0
    for option, name in (("--cityjson", "x.city.json"), ("--osm", "x.osm"), ("--3dtiles", "t")):
        capsys.readouterr()
        assert main(["export", str(run_dir), option, str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert "ExportError" in err and "Traceback" not in err, err
        assert not (tmp_path / name).exists()


@pytest.fixture(scope="module")
def street(tmp_path_factory: pytest.TempPathFactory) -> tuple[Drive, Run, Path]:
    require_kitti(KITTI_RAW)
    return _process(KITTI_RAW, 0, tmp_path_factory.mktemp("kitti_raw"))


def test_street_reports_no_guardrail(street) -> None:
    drive, run, run_dir = street
    with (run_dir / "reconstruction" / "inventory.csv").open(newline="") as handle:
        assert list(csv.DictReader(handle)) == []
    # What the segment labels call guardrail is a scatter of tiny far pieces, no run of rail.
    found = _guardrail_points(run)
    assert np.count_nonzero(found) <= 0.002 * len(found)


def test_street_crops_come_from_the_real_image(street) -> None:
    drive, run, run_dir = street
    segments = run.segments
    ok = np.flatnonzero(segments["crop_status"] == CROP_OK)
    assert len(ok) >= 20
    assert set(segments["image"][ok].tolist()) == {0}
    image = drive.read_image(drive.images[0])
    top_left, side = crop_window(segments["rect"][ok], CropParams())
    crops = read_crops(run, ok, 128, drive_root=drive.root)
    cut = np.stack([cut_crop(image, top_left[i], int(side[i]), 128) for i in range(len(ok))])
    # Each crop is its window of the real image, cut exactly as the pipeline cut it.
    np.testing.assert_array_equal(crops, cut)
    assert not (run_dir / "crops").exists()
    # The windows hold the segments' projected points: the rectangles lie on the image.
    rect = segments["rect"][ok]
    assert np.all((rect[:, 0] >= 0) & (rect[:, 2] < image.shape[1]))
    assert np.all((rect[:, 1] >= 0) & (rect[:, 3] < image.shape[0]))
