"""A run's crops, cut from its drive's images when asked (the run stores none)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from guardrail_core.errors import MissingDriveFileError, RunFolderError
from guardrail_core.extract.crops import CROP_OK, CropParams, crop_window, cut_crop
from guardrail_core.formats.drive import Drive
from guardrail_core.formats.run_folder import load_run
from guardrail_core.review.run_crops import RunCrops, read_crops


def test_a_crop_is_its_window_of_the_chosen_image_at_any_size(drive: Drive, run_path: Path) -> None:
    run = load_run(run_path)
    seg = run.segments
    ok = np.flatnonzero(seg["crop_status"] == CROP_OK)[::25]
    params = CropParams.from_json(run.info.params["crops"])
    for size in (128, 64):
        crops = read_crops(run, ok, size)
        assert crops.shape == (len(ok), size, size, 3) and crops.dtype == np.uint8
        for row, s in enumerate(ok):
            image = drive.read_image(drive.images[int(seg["image"][s])])
            top_left, side = crop_window(seg["rect"][s], params)
            np.testing.assert_array_equal(crops[row], cut_crop(image, top_left[0], side[0], size))


def test_segments_without_a_crop_are_refused_by_name(run_path: Path) -> None:
    run = load_run(run_path)
    crops = RunCrops(run)
    without = int(np.flatnonzero(run.segments["crop_status"] != CROP_OK)[0])
    assert not crops.has_crop(without) and not crops.has_crop(len(run)) and not crops.has_crop(-1)
    with pytest.raises(RunFolderError, match=f"segment {without} has no crop"):
        crops.cut(np.array([without]), 128)
    with pytest.raises(RunFolderError, match=f"segment {len(run)} is not one of the run's"):
        crops.cut(np.array([len(run)]), 128)


def test_crops_follow_a_moved_drive_and_a_missing_image_is_named(
    run_path: Path, drive_path: Path, tmp_path: Path
) -> None:
    run = load_run(run_path)
    ok = np.flatnonzero(run.segments["crop_status"] == CROP_OK)[:40]
    expected = read_crops(run, ok, 64)  # from run.json's drive path
    moved = tmp_path / "moved"
    shutil.copytree(drive_path / "images", moved / "images")
    crops = RunCrops(run, moved, keep_images=2)
    np.testing.assert_array_equal(crops.cut(ok, 64), expected)
    np.testing.assert_array_equal(crops.cut(ok, 64), expected)  # from the kept images too
    image = run.info.images[int(run.segments["image"][ok[0]])]
    (moved / image).unlink()
    with pytest.raises(MissingDriveFileError, match=f"{image}: image missing or unreadable"):
        RunCrops(run, moved).cut(ok[:1], 64)
