"""A copy of the test run as processed before chains (2026-11-29): 26 feature columns, the
whole-component features where the chain features are now."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from guardrail_core.extract.shape_features import NAMES_BEFORE_CHAINS, feature_columns

#: The feature columns a run folder held before chains, in order.
BEFORE = list(NAMES_BEFORE_CHAINS)


def copy_run_before_chains(run_path: Path, folder: Path) -> np.ndarray:
    """Copy the run to ``folder`` with its features as written before chains; return the
    (S, SEGMENT_FEATURE_DIM) features it had."""
    shutil.copytree(run_path, folder)
    path = folder / "segments.npz"
    with np.load(path) as saved:
        kept = {name: saved[name] for name in saved.files}
    today = kept["features"]
    kept["features"] = today[:, feature_columns(BEFORE)]
    assert kept["features"].shape[1] == 26
    np.savez(path, **kept)
    return today
