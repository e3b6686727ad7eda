"""Copies of a run folder changed as another version of guardrail would have written them."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

#: The columns of segment features an unreleased version wrote (before chains, 2026-11-29).
OTHER_LAYOUT_COLUMNS = 26


def copy_run_with_features_of_another_layout(run_path: Path, folder: Path) -> np.ndarray:
    """Copy the run to ``folder`` with :data:`OTHER_LAYOUT_COLUMNS` columns of segment features
    (S, 26) instead of this version's; return the (S, SEGMENT_FEATURE_DIM) features it had."""
    shutil.copytree(run_path, folder)
    path = folder / "segments.npz"
    with np.load(path) as saved:
        kept = {name: saved[name] for name in saved.files}
    today = kept["features"]
    kept["features"] = np.ascontiguousarray(today[:, :OTHER_LAYOUT_COLUMNS])
    np.savez(path, **kept)
    return today
