"""``guardrail reconstruct`` gathers only the points the reconstruction uses, a tile at a time,
and reconstructs exactly what the whole drive in memory gave."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from guardrail_core.errors import RunFolderError
from guardrail_core.formats.drive import load_drive, open_drive
from guardrail_core.formats.run_folder import POINT_ROAD
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.reconstruct.drive_input import gather_reconstruction_points
from guardrail_core.reconstruct.model_json import run_model_to_json
from guardrail_core.reconstruct.pipeline import (
    ReconstructionParams,
    guardrail_mask,
    reconstruct_guardrails,
)


def _models(xyz: np.ndarray, segment: np.ndarray, label: np.ndarray, trajectory) -> list[dict]:
    rec = reconstruct_guardrails(
        xyz, guardrail_mask(segment, label), segment == POINT_ROAD, trajectory
    )
    return [run_model_to_json(run) for run in rec.runs]


def test_the_gathered_points_reconstruct_exactly_what_the_whole_drive_does(
    drive_path: Path, run_path: Path
) -> None:
    run = RunFolder(run_path)
    label = run.segments()["label"]
    drive = load_drive(drive_path, with_truth=False)
    segment = run.point_segment()
    reach = ReconstructionParams().runs.ground_reach_m
    xyz, kept_segment = gather_reconstruction_points(open_drive(drive_path), run, label, reach)

    guardrail = guardrail_mask(segment, label)
    road = segment == POINT_ROAD
    # Every guardrail point, in drive order, and only the road near them.
    np.testing.assert_array_equal(xyz[kept_segment >= 0], drive.points.xyz[guardrail])
    assert 0 < (kept_segment == POINT_ROAD).sum() < road.sum() / 2
    trajectory = drive.trajectory.position
    assert _models(xyz, kept_segment, label, trajectory) == _models(
        drive.points.xyz, segment, label, trajectory
    )


def test_a_run_of_another_drive_is_refused(
    drive_path: Path, run_path: Path, tmp_path: Path
) -> None:
    from tests.drive_files import write_drive_copy

    other = write_drive_copy(load_drive(drive_path), tmp_path / "other", tile_m=5.0)
    run = RunFolder(run_path)
    with pytest.raises(RunFolderError, match="give the run's drive with --drive"):
        gather_reconstruction_points(open_drive(other), run, run.segments()["label"], 1.0)
