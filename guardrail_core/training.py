"""Training sets of labelled crops from drives, and training a classifier from them (§3.3)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.drive import load_drive
from guardrail_core.errors import MissingDriveFileError, TrainingDataError
from guardrail_core.evaluate import segment_truth
from guardrail_core.extract.classify import ClassifierParams, GuardrailClassifier, train_classifier
from guardrail_core.extract.crops import CROP_OK
from guardrail_core.pipeline import ExtractionParams, extract

# Held-out metrics are measured on whole blocks of this many slices (10 m), so that neighbouring
# slices of one guardrail never sit on both sides of the split.
HOLD_OUT_BLOCK_SLICES = 20


@dataclass(frozen=True)
class TrainingSet:
    """Labelled crops.

    Attributes
    ----------
    crops : (K, S, S, 3) uint8 RGB
    labels : (K,) bool, True for guardrail
    groups : (K,) int64, spatial block of each crop (for a held-out split)
    sources : per drive: its path and its counts
    """

    crops: np.ndarray
    labels: np.ndarray
    groups: np.ndarray
    sources: list[dict[str, Any]]


def labelled_crops(
    drive_paths: Sequence[Path],
    crop_size: int,
    params: ExtractionParams = ExtractionParams(),
    *,
    progress: bool = False,
) -> TrainingSet:
    """Extract every drive's segments and label their crops from ``truth/``.

    A segment is guardrail when most of its points are (the same rule as the evaluation).

    Raises
    ------
    MissingDriveFileError
        A drive has no truth/ folder.
    """
    crops, labels, groups, sources = [], [], [], []
    for index, path in enumerate(drive_paths):
        drive = load_drive(path)
        if drive.truth is None:
            raise MissingDriveFileError(
                f"{path}: no truth/ folder; training needs labelled drives (synthetic ones)"
            )
        result = extract(drive, crop_size, params, progress=progress)
        truth = segment_truth(drive.truth.point_class, result.point_segment, len(result.segments))
        ok = np.flatnonzero(result.choice.status == CROP_OK)
        crops.append(result.crops[ok])
        labels.append(truth[ok])
        block = result.segments.slice_index[ok] // HOLD_OUT_BLOCK_SLICES
        groups.append(index * 1_000_000 + block - block.min(initial=0))
        sources.append(
            {
                "drive": str(Path(path).resolve()),
                "segments": len(result.segments),
                "crops": len(ok),
                "guardrail": int(truth[ok].sum()),
                "other": int((~truth[ok]).sum()),
            }
        )
    return TrainingSet(
        crops=np.concatenate(crops) if crops else np.zeros((0, crop_size, crop_size, 3), np.uint8),
        labels=np.concatenate(labels) if labels else np.zeros(0, bool),
        groups=np.concatenate(groups).astype(np.int64) if groups else np.zeros(0, np.int64),
        sources=sources,
    )


def train_from_drives(
    drive_paths: Sequence[Path],
    *,
    params: ClassifierParams = ClassifierParams(),
    extraction: ExtractionParams = ExtractionParams(),
    progress: bool = False,
) -> GuardrailClassifier:
    """Train a classifier on the crops of labelled drives.

    Raises
    ------
    TrainingDataError
        The drives yield too few crops, or crops of one class only.
    """
    if not drive_paths:
        raise TrainingDataError("no drives given to train on")
    data = labelled_crops(drive_paths, params.input_size, extraction, progress=progress)
    trained_on = {
        "drives": data.sources,
        "crops": len(data.labels),
        "guardrail": int(data.labels.sum()),
        "other": int((~data.labels).sum()),
        "labels": "truth",
    }
    return train_classifier(
        data.crops,
        data.labels,
        groups=data.groups,
        params=params,
        trained_on=trained_on,
        progress=progress,
    )
