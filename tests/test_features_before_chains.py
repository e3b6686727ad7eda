"""A run processed before chains holds its features in the layout of then: a model trained
before chains reads them as it did, one that reads the chain features refuses them by name."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from guardrail_core.errors import IncompatibleModelError
from guardrail_core.extract.model_folder import DEFAULT_MODEL_DIR, load_model
from guardrail_core.extract.segment_head import fit_segment_head
from guardrail_core.extract.shape_features import (
    NEIGHBOUR_FEATURE_NAMES,
    SEGMENT_FEATURE_DIM,
    SHAPE_FEATURE_NAMES,
    WHOLE_COMPONENT_FEATURE_NAMES,
    feature_columns,
    features_before_chains,
)
from guardrail_core.formats.run_folder import load_run
from tests.run_before_chains import BEFORE, copy_run_before_chains

CHAINS = [name for name in SHAPE_FEATURE_NAMES + NEIGHBOUR_FEATURE_NAMES if "chain" in name]


def test_a_table_before_chains_is_laid_out_as_now(run_path: Path, tmp_path: Path) -> None:
    today = copy_run_before_chains(run_path, tmp_path / "run")
    stored = load_run(tmp_path / "run").segments["features"]
    assert stored.shape == (len(today), 26)
    features = features_before_chains(stored)
    assert features.shape == (len(today), SEGMENT_FEATURE_DIM)
    kept = feature_columns(BEFORE)
    np.testing.assert_array_equal(features[:, kept], today[:, kept])
    assert np.isnan(features[:, feature_columns(CHAINS)]).all()
    assert len(BEFORE) + len(CHAINS) == SEGMENT_FEATURE_DIM
    assert set(WHOLE_COMPONENT_FEATURE_NAMES) <= set(BEFORE)
    # A table in today's layout is left as it is.
    assert features_before_chains(today) is today


def test_models_before_chains_read_it_as_before_and_chain_models_refuse_it(
    run_path: Path, model_path: Path, tmp_path: Path
) -> None:
    today = copy_run_before_chains(run_path, tmp_path / "run")
    features = load_run(tmp_path / "run").segments["features"]  # 26 columns, as written then
    crop = np.full(len(features), np.nan)
    shipped = load_model(DEFAULT_MODEL_DIR)  # trained before chains: reads the whole components
    assert shipped.segment_head is not None
    np.testing.assert_array_equal(
        shipped.segment_head.proba(features, crop), shipped.segment_head.proba(today, crop)
    )
    trained_now = load_model(model_path)  # reads the chain features
    assert trained_now.segment_head is not None
    trained_now.segment_head.proba(today, crop)
    with pytest.raises(IncompatibleModelError, match="processed before chains"):
        trained_now.segment_head.proba(features, crop)
    with pytest.raises(IncompatibleModelError, match="processed before chains"):  # nor learns
        fit_segment_head(
            features, crop, np.arange(len(features)) % 2 == 0, columns=feature_columns(CHAINS)
        )
