"""The extraction pipeline end to end on the test drive: the run folder, its invariants, the
figures against the truth, and bad inputs that must leave nothing half-written."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from guardrail_core.classes import GUARDRAIL_CLASSES
from guardrail_core.cli import main
from guardrail_core.errors import EmptyDriveError, InputInsideOutputError, OutputExistsError
from guardrail_core.evaluate.detection import evaluate_run
from guardrail_core.extract.classify.model_folder import load_model
from guardrail_core.extract.crops import CROP_NO_IMAGE, CROP_OK
from guardrail_core.extract.segment_truth import segment_truth
from guardrail_core.formats.drive import Drive, PointCloud, load_drive
from guardrail_core.formats.run_folder import POINT_OFF_ROAD, POINT_ROAD, load_run
from guardrail_core.process import process_drive
from guardrail_core.reconstruct.run_models import load_run_models
from tests.drive_files import write_drive_copy
from tests.file_tree import file_tree


def test_every_kept_point_lies_in_exactly_one_segment(drive: Drive, run_path: Path) -> None:
    run = load_run(run_path)
    segment = run.point_segment
    assert segment.shape == (len(drive.points),)
    assert set(np.unique(segment[segment < 0])) <= {POINT_ROAD, POINT_OFF_ROAD}
    # Each point carries one segment id, so "exactly one" reduces to: ids valid and counts agree.
    counts = np.bincount(segment[segment >= 0], minlength=len(run))
    assert len(counts) == len(run)
    np.testing.assert_array_equal(counts, run.segments["n_points"])
    counts = run.info.counts
    assert counts.segment_points == int((segment >= 0).sum())
    assert counts.segment_points + counts.road_points + counts.off_road_points == len(drive.points)
    assert counts.points == len(drive.points) and counts.segments == len(run)


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


def test_no_crop_is_stored_and_the_asked_ones_are_those_the_shape_leaves_open(
    run_path: Path, model_path: Path
) -> None:
    run = load_run(run_path)
    status = run.segments["crop_status"]
    ok = np.flatnonzero(status == CROP_OK)
    assert len(ok) > 100
    # Each crop is cut from the drive's image when needed (review/run_crops.py), none stored.
    assert not (run_path / "crops").exists()
    # The CNN was asked about exactly the crops whose segment's shape leaves the label open (on
    # this drive, with a model trained on it, none: tests/extract/test_segment_scores.py has the others).
    asked = (status == CROP_OK) & ~load_model(model_path).shape_decides(run.segments["features"])
    assert asked.sum() < len(ok) and run.info.counts.crops.asked == asked.sum()
    crop_probability = run.segments["crop_probability"]
    np.testing.assert_array_equal(np.isfinite(crop_probability), asked)
    # The segment head answers for every segment, with or without a crop.
    assert np.all(np.isfinite(run.segments["probability"]))
    embeddings = run.embeddings()
    assert embeddings is not None and embeddings.shape == (len(run), 1280)
    finite = np.isfinite(embeddings).all(axis=1)
    np.testing.assert_array_equal(finite, asked | (status != CROP_OK))
    assert not embeddings[status != CROP_OK].any()  # zeros where there is no crop


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
    assert result.detection.guardrail.f1 >= 0.95
    assert result.detection.other.f1 >= 0.97
    # Guardrail points are found, also those of segments without a crop (where no camera saw
    # the whole segment: the first metres of the drive): the segment head judges their shape.
    assert drive.truth is not None
    guardrail = np.isin(drive.truth.point_class, list(GUARDRAIL_CLASSES))
    seg = run.point_segment
    found = (seg >= 0) & run.segments["label"][np.maximum(seg, 0)]
    assert found[guardrail].mean() >= 0.97
    assert result.points.precision >= 0.95


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


def test_a_failure_half_way_leaves_no_folder_and_the_old_one_as_it_was(
    drive: Drive, model_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = load_model(model_path)
    out = tmp_path / "run"
    out.mkdir()
    (out / "run.json").write_text("the previous run")

    def broken(*args, **kwargs):
        raise RuntimeError("simulated crash in the classifier")

    monkeypatch.setattr(model, "segment_proba", broken)
    with pytest.raises(RuntimeError):
        process_drive(drive, model, out, overwrite=True)
    assert file_tree(out) == {"run.json": b"the previous run"}
    assert [p.name for p in tmp_path.iterdir()] == ["run"]  # no staging folder left


def test_an_output_holding_the_drive_or_the_model_is_refused_and_they_survive(
    drive_path: Path, model_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    drive_copy, model_copy = out / "drive", out / "model"
    shutil.copytree(drive_path, drive_copy)
    shutil.copytree(model_path, model_copy)
    before = file_tree(out)
    drive, model = load_drive(drive_copy), load_model(model_copy)
    for target in (out, drive_copy, drive_copy / "images"):
        with pytest.raises(InputInsideOutputError, match="would delete"):
            process_drive(drive, model, target, overwrite=True)
    command = ["process", str(drive_copy), "--model", str(model_copy), "--out", str(model_copy)]
    assert main([*command, "--overwrite", "--quiet"]) == 2
    assert "InputInsideOutputError" in capsys.readouterr().err
    assert file_tree(out) == before


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
    assert (status == CROP_NO_IMAGE).sum() == info.counts.crops.no_image > 0
    assert info.counts.crops.ok == 0 and not (status == CROP_OK).any()
    assert np.isnan(run.segments["crop_probability"]).all()
    # What process_drive returns is run.json as written, with the reconstruction's summary.
    assert info.reconstruction is not None
    assert info.reconstruction.runs == len(load_run_models(tmp_path / "run").runs)
    written = dataclasses.replace(info, reconstruction=None).to_json()
    assert json.loads(json.dumps(written)) == json.loads(run.folder.run_file.read_text())
    # The segment head finds the guardrails from their shape alone.
    detection = evaluate_run(drive, run).detection
    assert detection.guardrail.f1 >= 0.95 and detection.other.f1 >= 0.97


def test_an_empty_drive_is_a_named_error(
    drive_path: Path, model_path: Path, tmp_path: Path
) -> None:
    drive = load_drive(drive_path)
    assert drive.truth is not None
    empty = np.zeros(0)
    copy = write_drive_copy(
        drive,
        tmp_path / "drive",
        points=PointCloud(
            np.zeros((0, 3)), empty, empty.astype(np.uint16), *[empty.astype(int)] * 2
        ),
        truth=dataclasses.replace(
            drive.truth, point_class=np.zeros(0, np.uint8), point_object=np.zeros(0, np.int32)
        ),
    )
    with pytest.raises(EmptyDriveError, match="no points"):
        process_drive(load_drive(copy), load_model(model_path), tmp_path / "run")
    assert not (tmp_path / "run").exists()
