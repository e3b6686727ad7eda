"""The extraction's parameters as run.json stores them: round trip, older folders, bad values."""

from __future__ import annotations

import dataclasses

import pytest

from guardrail_core.extract.classify.label_correction_params import CorrectionParams
from guardrail_core.extract.crops import CropParams
from guardrail_core.extract.pipeline import ExtractionParams
from guardrail_core.extract.road import RoadParams
from guardrail_core.params import ParameterError, StageParams


def test_every_stage_of_the_extraction_is_a_stage_params() -> None:
    stages = {
        f.name: getattr(ExtractionParams(), f.name) for f in dataclasses.fields(ExtractionParams)
    }
    assert set(stages) == {"road", "segments", "crops", "classify", "correction"}
    assert all(isinstance(stage, StageParams) for stage in stages.values())


def test_run_json_params_round_trip() -> None:
    params = ExtractionParams(
        road=RoadParams(height_tolerance_m=0.05), crops=CropParams(time_window_s=1.5)
    )
    assert ExtractionParams.from_json(params.to_json()) == params


def test_params_of_an_older_run_folder_load_with_the_defaults_of_fields_added_since() -> None:
    stored = ExtractionParams().to_json()
    del stored["road"]["edge_min_points"], stored["correction"]["post_min_reach"]
    del stored["segments"]
    assert ExtractionParams.from_json(stored) == ExtractionParams()


@pytest.mark.parametrize(
    ("stored", "message"),
    [
        ({"roads": {}}, "unknown extraction stage roads"),
        ({"road": {"height_tolerance": 0.1}}, r"unknown parameter RoadParams.height_tolerance"),
        ({"crops": {"time_window_s": -1}}, r"CropParams.time_window_s must lie within \[0, 3600\]"),
        ({"correction": {"max_hole_slices": 3}}, "max_hole_slices must be one of 1, 2"),
        ({"crops": {"min_depth_m": 50.0}}, "min_depth_m .* must lie below max_range_m"),
        ([1, 2], "expected an object of stages"),
    ],
)
def test_bad_stored_params_are_named(stored: object, message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        ExtractionParams.from_json(stored)  # type: ignore[arg-type]


def test_a_post_must_reach_a_share_of_the_rails_height() -> None:
    with pytest.raises(ParameterError, match="post_min_reach"):
        CorrectionParams(post_min_reach=1.5)
