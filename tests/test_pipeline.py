"""The extraction pipeline end to end on the test drive: the run folder, its invariants, the
figures against the truth, and bad inputs that must leave nothing half-written."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from guardrail_core.classes import GUARDRAIL_CLASSES
from guardrail_core.drive import Drive, load_drive
from guardrail_core.errors import EmptyDriveError, OutputExistsError
from guardrail_core.evaluate import evaluate_run, segment_truth
from guardrail_core.extract.crops import CROP_NO_IMAGE, CROP_OK
from guardrail_core.extract.model_store import load_model
from guardrail_core.io.las import write_points
from guardrail_core.pipeline import process_drive
from guardrail_core.run_folder import POINT_OFF_ROAD, POINT_ROAD, load_run


def test_every_kept_point_lies_in_exactly_one_segment(drive: Drive, run_path: Path) -> None:
    run = load_run(run_path)
    segment = run.point_segment
    assert segment.shape == (len(drive.points),)
    assert set(np.unique(segment[segment < 0])) <= {POINT_ROAD, POINT_OFF_ROAD}
    # Each point carries one segment id, so "exactly one" reduces to: ids valid and counts agree.
    counts = np.bincount(segment[segment >= 0], minlength=len(run))
    assert len(counts) == len(run)
    np.testing.assert_array_equal(counts, run.segments["n_points"])
    assert run.info["counts"]["segment_points"] == int((segment >= 0).sum())
    assert run.info["counts"]["segment_points"] + run.info["counts"]["road_points"] + run.info[
        "counts"
    ]["off_road_points"] == len(drive.points)


def test_road_removal_keeps_guardrails_and_drops_the_road(drive: Drive, run_path: Path) -> None:
    run = load_run(run_path)
    assert drive.truth is not None
    cls = drive.truth.point_class
    guardrail = np.isin(cls, list(GUARDRAIL_CLASSES))
    kept = run.point_segment >= 0
    assert kept[guardrail].mean() >= 0.99
    road_class = np.isin(cls, [1, 2])  # road, road marking
    assert kept[road_class].mean() <= 0.01


def test_segments_follow_the_slices(drive: Drive, run_path: Path) -> None:
    """Segments are 0.5 m slices: the points of one segment span at most 0.5 m along the track
    (plus the slack of a straight road's heading within its bounding box)."""
    run = load_run(run_path)
    lateral = run.segments["lateral"]
    assert np.all(lateral[:, 1] >= lateral[:, 0])
    # The test street is straight at a 35 degree heading: project the bounding boxes on it.
    heading = np.deg2rad(35.0)
    axis = np.array([np.cos(heading), np.sin(heading)])
    seg = run.point_segment
    xyz = drive.points.xyz
    station = xyz[:, :2] @ axis
    big = np.flatnonzero(run.segments["n_points"] >= 20)
    for s in big[:: max(1, len(big) // 50)]:
        along = station[seg == s]
        assert along.max() - along.min() <= 0.5 + 0.02


def test_crops_are_written_for_every_segment_with_an_image(run_path: Path) -> None:
    run = load_run(run_path)
    status = run.segments["crop_status"]
    ok = np.flatnonzero(status == CROP_OK)
    assert len(ok) > 100
    written = sorted(p.name for p in (run_path / "crops").iterdir())
    assert written == [f"{s:06d}.jpg" for s in ok]
    crop = cv2.imread(str(run.crop_path(int(ok[0]))))
    assert crop.shape == (128, 128, 3)
    crop_probability = run.segments["crop_probability"]
    assert np.all(np.isfinite(crop_probability[ok]))
    assert np.all(np.isnan(crop_probability[status != CROP_OK]))
    # The segment head answers for every segment, with or without a crop.
    assert np.all(np.isfinite(run.segments["probability"]))
    embeddings = run.embeddings()
    assert embeddings is not None and embeddings.shape == (len(run), 1280)


def test_chosen_image_holds_all_points_of_its_segment(drive: Drive, run_path: Path) -> None:
    run = load_run(run_path)
    ok = np.flatnonzero(run.segments["crop_status"] == CROP_OK)
    rng = np.random.default_rng(0)
    for s in rng.choice(ok, size=40, replace=False):
        record = drive.images[int(run.segments["image"][s])]
        camera = drive.cameras[record.camera]
        uv, valid = camera.project(drive.points.xyz[run.point_segment == s], record.T_world_camera)
        assert valid.all() and camera.inside(uv).all()
        x0, y0, x1, y1 = run.segments["rect"][s]
        assert x0 <= uv[:, 0].min() + 0.5 and uv[:, 0].max() - 0.5 <= x1
        assert y0 <= uv[:, 1].min() + 0.5 and uv[:, 1].max() - 0.5 <= y1


def test_timings_name_every_stage_with_points_and_seconds(drive: Drive, run_path: Path) -> None:
    timings = json.loads((run_path / "timings.json").read_text())
    assert timings["points_in"] == len(drive.points)
    stages = timings["stages"]
    expected = ["track", "lattice", "road_removal", "components", "slices", "features", "crops"]
    assert list(stages)[: len(expected)] == expected
    assert {"classify", "correction", "write"} <= set(stages)
    for entry in stages.values():
        assert entry["seconds"] >= 0 and entry["points"] >= 0
    assert timings["total_seconds"] >= sum(e["seconds"] for e in stages.values()) - 1e-3


def test_in_sample_detection_is_near_perfect(drive: Drive, run_path: Path) -> None:
    """Trained on this very drive, the classifier must fit it (the held-out figures of unseen
    drives are measured by benchmarks/accuracy_extraction.py)."""
    run = load_run(run_path)
    result = evaluate_run(drive, run)
    assert result["detection"]["guardrail"]["f1"] >= 0.95
    assert result["detection"]["other"]["f1"] >= 0.97
    # Guardrail points are found, also those of segments without a crop (where no camera saw
    # the whole segment: the first metres of the drive): the segment head judges their shape.
    assert drive.truth is not None
    guardrail = np.isin(drive.truth.point_class, list(GUARDRAIL_CLASSES))
    seg = run.point_segment
    found = (seg >= 0) & run.segments["label"][np.maximum(seg, 0)]
    assert found[guardrail].mean() >= 0.97
    assert result["points"]["guardrail"]["precision"] >= 0.95


def test_segment_truth_is_the_majority_of_points() -> None:
    point_class = np.array([6, 6, 1, 1, 1, 7, 7, 12, 6])
    point_segment = np.array([0, 0, 0, 1, 1, 2, 2, 2, -1])
    np.testing.assert_array_equal(segment_truth(point_class, point_segment, 3), [True, False, True])


def test_existing_run_folder_is_not_overwritten(drive: Drive, model_path: Path, tmp_path: Path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "keep.txt").write_text("operator notes")
    with pytest.raises(OutputExistsError):
        process_drive(drive, load_model(model_path), out)
    assert (out / "keep.txt").read_text() == "operator notes"


def test_a_failure_half_way_leaves_no_folder(
    drive: Drive, model_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = load_model(model_path)

    def broken(*args, **kwargs):
        raise RuntimeError("simulated crash in the classifier")

    monkeypatch.setattr(model, "predict_proba", broken)
    with pytest.raises(RuntimeError):
        process_drive(drive, model, tmp_path / "run")
    assert list(tmp_path.iterdir()) == []


def test_a_drive_without_images_is_processed_and_reported(
    drive_path: Path, model_path: Path, tmp_path: Path
) -> None:
    copy = tmp_path / "drive"
    shutil.copytree(drive_path, copy)
    (copy / "images.json").write_text("[]")
    drive = load_drive(copy)
    info = process_drive(drive, load_model(model_path), tmp_path / "run")
    run = load_run(tmp_path / "run")
    assert len(run) > 0
    status = run.segments["crop_status"]
    assert (status == CROP_NO_IMAGE).sum() == info["counts"]["crops"]["no_image"] > 0
    assert not (status == CROP_OK).any()
    assert np.isnan(run.segments["crop_probability"]).all()
    # The segment head finds the guardrails from their shape alone.
    detection = evaluate_run(drive, run)["detection"]
    assert detection["guardrail"]["f1"] >= 0.95 and detection["other"]["f1"] >= 0.97


def test_an_empty_drive_is_a_named_error(
    drive_path: Path, model_path: Path, tmp_path: Path
) -> None:
    copy = tmp_path / "drive"
    shutil.copytree(drive_path, copy)
    drive = load_drive(copy)
    empty = np.zeros(0)
    write_points(
        copy / "points.laz",
        np.zeros((0, 3)),
        np.asarray(drive.origin),
        empty,
        empty.astype(np.uint16),
        empty.astype(np.int64),
        empty.astype(np.int64),
    )
    np.savez_compressed(
        copy / "truth" / "points.npz", **{"class": np.zeros(0, np.uint8)}, object_id=np.zeros(0)
    )
    with pytest.raises(EmptyDriveError, match="no points"):
        process_drive(load_drive(copy), load_model(model_path), tmp_path / "run")
    assert not (tmp_path / "run").exists()
