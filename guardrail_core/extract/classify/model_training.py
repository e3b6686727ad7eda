"""Training sets of labelled segments from drives, and training a model from them (§3.3)."""

from __future__ import annotations

import copy
import dataclasses
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.errors import InvalidOptionError, MissingDriveFileError, TrainingDataError
from guardrail_core.extract.classify.backbone import EMBEDDING_DIM, embed_crops
from guardrail_core.extract.classify.crop_classifier import GuardrailClassifier, model_version
from guardrail_core.extract.classify.crop_classifier_params import ClassifierParams
from guardrail_core.extract.classify.crop_classifier_training import (
    classification_metrics,
    held_out_mask,
    train_classifier,
)
from guardrail_core.extract.classify.segment_head import (
    SegmentHead,
    SegmentHeadParams,
    column_names,
    fit_segment_head,
)
from guardrail_core.extract.classify.shape_features import check_feature_layout
from guardrail_core.extract.crops import CROP_OK
from guardrail_core.extract.pipeline import ExtractionParams, extract, segment_crops
from guardrail_core.extract.segment_truth import segment_truth
from guardrail_core.formats.drive import load_drive
from guardrail_core.progress import progress_bar

# Held-out metrics are measured on whole blocks of this many slices (10 m), so that neighbouring
# slices of one guardrail never sit on both sides of the split.
HOLD_OUT_BLOCK_SLICES = 20


@dataclass(frozen=True)
class TrainingSet:
    """Labelled segments of drives (or of a run folder), with their crops or crop embeddings.

    Attributes
    ----------
    features : (S, SEGMENT_FEATURE_DIM) float32, shape and neighbour features of every segment
    labels : (S,) bool, True for guardrail
    groups : (S,) int64, spatial block of each segment (for held-out splits and folds)
    has_crop : (S,) bool, the segment has a crop
    crops : (K, C, C, 3) uint8 RGB, the crops of the K segments with one, in segment order; may
        be None when ``embeddings`` are given (fast mode only)
    sources : per drive (or run): its path and its counts
    embeddings : (K, 1280) float32 or None, frozen-backbone embeddings of the same K crops
        (:func:`~guardrail_core.extract.classify.backbone.embed_crops`); fast mode uses them
        instead of embedding the crops
    weights : (S,) float32 or None, how much each segment's label counts in the segment head's
        loss (None: all alike); a run's segments that operators labelled weigh more than those
        the model labelled itself (:func:`~guardrail_core.review.training.train_from_run`)
    """

    features: np.ndarray
    labels: np.ndarray
    groups: np.ndarray
    has_crop: np.ndarray
    crops: np.ndarray | None
    sources: list[dict[str, Any]]
    embeddings: np.ndarray | None = None
    weights: np.ndarray | None = None


@dataclass(frozen=True)
class SetTraining:
    """A model trained by :func:`train_on_set`, and what it was measured on.

    Attributes
    ----------
    model : GuardrailClassifier, with its segment head
    held_out : (S,) bool, the segments ``model.info["metrics"]["held_out"]`` was measured on (all
        False when nothing could be held out; the metrics are then None)
    held_out_predicted : (S,) bool, on the held-out segments the raw label (``proba >=
        threshold``, as the pipeline calls it) of the segment head trained without them; False
        elsewhere
    """

    model: GuardrailClassifier
    held_out: np.ndarray
    held_out_predicted: np.ndarray


def labelled_segments(
    drive_paths: Sequence[Path],
    crop_size: int,
    params: ExtractionParams = ExtractionParams(),
    *,
    progress: bool = False,
) -> TrainingSet:
    """Extract every drive's segments and label them from ``truth/``.

    A segment is guardrail when most of its points are (the same rule as the evaluation).

    Raises
    ------
    MissingDriveFileError
        A drive has no truth/ folder.
    """
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("features", "labels", "groups", "crop")}
    crops, sources = [], []
    for index, path in enumerate(drive_paths):
        drive = load_drive(path)
        if drive.truth is None:
            raise MissingDriveFileError(
                f"{path}: no truth/ folder; training needs labelled drives (synthetic ones)"
            )
        result = extract(drive, params, progress=progress)
        truth = segment_truth(drive.truth.point_class, result.point_segment, len(result.segments))
        has_crop = result.choice.status == CROP_OK
        block = result.segments.slice_index // HOLD_OUT_BLOCK_SLICES
        parts["features"].append(result.features)
        parts["labels"].append(truth)
        parts["groups"].append(index * 1_000_000 + block - block.min(initial=0))
        parts["crop"].append(has_crop)
        crops.append(
            segment_crops(
                drive,
                result.choice,
                np.flatnonzero(has_crop),
                crop_size,
                params.crops,
                progress=progress,
            )
        )
        sources.append(
            {
                "drive": str(Path(path).resolve()),
                "segments": len(result.segments),
                "crops": int(has_crop.sum()),
                "guardrail": int(truth.sum()),
                "other": int((~truth).sum()),
            }
        )
    if not sources:
        raise TrainingDataError("no drives given to train on")
    return TrainingSet(
        features=np.concatenate(parts["features"]),
        labels=np.concatenate(parts["labels"]),
        groups=np.concatenate(parts["groups"]).astype(np.int64),
        has_crop=np.concatenate(parts["crop"]),
        crops=np.concatenate(crops),
        sources=sources,
    )


def train_from_drives(
    drive_paths: Sequence[Path],
    *,
    params: ClassifierParams = ClassifierParams(),
    head: SegmentHeadParams = SegmentHeadParams(),
    extraction: ExtractionParams = ExtractionParams(),
    progress: bool = False,
) -> GuardrailClassifier:
    """Train the crop classifier and the segment head on labelled drives.

    Extracts the drives' segments and labels them from ``truth/`` (:func:`labelled_segments`),
    then trains on them with :func:`train_on_set`.

    Raises
    ------
    TrainingDataError
        The drives yield too few crops, or segments or crops of one class only.
    """
    if not drive_paths:
        raise TrainingDataError("no drives given to train on")
    data = labelled_segments(drive_paths, params.input_size_px, extraction, progress=progress)
    return train_on_set(
        data,
        params=params,
        head=head,
        progress=progress,
        trained_on={"drives": data.sources, "labels": "truth"},
    ).model


def train_on_set(
    data: TrainingSet,
    *,
    params: ClassifierParams,
    head: SegmentHeadParams,
    progress: bool = False,
    progress_fn: Callable[[float, str], None] | None = None,
    trained_on: dict[str, Any] | None = None,
    start_head: SegmentHead | None = None,
    crops_from: GuardrailClassifier | None = None,
) -> SetTraining:
    """Train the crop classifier and the segment head on a training set.

    1. The crop classifier on every crop (:func:`train_classifier`; its held-out figures go to
       ``info["metrics"]["held_out_crops"]``).
    2. Out-of-fold crop probabilities: the blocks are dealt into ``head.folds`` folds and each
       fold's crops are classified by a crop classifier trained on the other folds (in full mode
       that is ``head.folds`` more fine-tunings).
    3. The segment head on every segment, from its features and its out-of-fold crop
       probability; measured first on held-out blocks (``info["metrics"]["held_out"]``, every
       segment, with or without a crop, called guardrail at ``proba >= threshold`` like the
       pipeline), then refit on all; each segment's label counts ``data.weights`` times.

    Parameters
    ----------
    data : the labelled segments; fast mode uses ``data.embeddings`` when given (``data.crops``
        may then be None), else embeds ``data.crops``; full mode needs ``data.crops``
    params : crop classifier parameters (mode, seed, held-out fraction, threshold)
    head : segment head parameters
    progress : show progress bars (on a terminal)
    progress_fn : called as ``progress_fn(fraction, message)`` with fraction 0..1 before each
        step (embedding, crop classifier, each fold, segment head) and with 1.0 at the end
    trained_on : description of the data stored in ``info["trained_on"]``; the counts
        ``segments``, ``crops``, ``guardrail`` and ``other`` are added
    start_head : a trained segment head to fine-tune rather than draw a new one (see
        :func:`~guardrail_core.extract.classify.segment_head.fit_segment_head`): the new head
        reads the features it reads (``head``'s ignored features then choose nothing); the crop
        classifier is trained anew either way
    crops_from : the model whose crop classifier is kept, unchanged, when the set holds no crop
        at all (a drive without images: there is nothing to learn it from); the segment head
        alone is then trained, with every crop probability missing

    Returns
    -------
    SetTraining
        The model, the held-out segments and the held-out segment head's raw labels on them (for
        measuring against other labels, as :func:`~guardrail_core.review.training.train_from_run`
        does).

    Raises
    ------
    TrainingDataError
        Too few crops, or segments or crops of one class only.
    InvalidOptionError
        Full mode without crops, or embeddings of the wrong shape.
    IncompatibleModelError
        Segment features laid out by another version of guardrail (a run processed by it).
    """
    check_feature_layout(data.features)  # before minutes of training, not after
    crop_rows = np.flatnonzero(data.has_crop)
    trained_on = {
        **(trained_on or {}),
        "segments": len(data.labels),
        "crops": len(crop_rows),
        "guardrail": int(data.labels.sum()),
        "other": int((~data.labels).sum()),
    }
    embeddings = None
    if params.mode == "fast" and data.embeddings is not None:
        embeddings = np.asarray(data.embeddings, np.float32)
        if embeddings.shape != (len(crop_rows), EMBEDDING_DIM):
            raise InvalidOptionError(
                f"training set: expected ({len(crop_rows)}, {EMBEDDING_DIM}) embeddings (one per "
                f"crop), got {embeddings.shape}"
            )
    elif data.crops is None:
        raise InvalidOptionError(
            f"training set: {params.mode} mode needs the crops"
            + ("" if params.mode == "full" else " or their embeddings")
            + ", got neither"
        )
    steps = 1 + head.folds + 2 + (embeddings is None and params.mode == "fast")
    done = 0

    def report(message: str) -> None:
        nonlocal done
        if progress_fn is not None:
            progress_fn(min(done / steps, 1.0), message)
        done += 1

    if params.mode == "fast" and embeddings is None and len(crop_rows):
        report(f"embedding {len(crop_rows)} crops")
        assert data.crops is not None
        embeddings = embed_crops(data.crops, progress=progress)
    if len(crop_rows) == 0 and crops_from is not None:
        report("keeping the crop classifier (no crops to train it on)")
        model = _kept_crop_classifier(crops_from, trained_on)
    else:
        report("training the crop classifier")
        model = train_classifier(
            None if embeddings is not None else data.crops,
            data.labels[crop_rows],
            groups=data.groups[crop_rows],
            embeddings=embeddings,
            params=params,
            trained_on=trained_on,
            progress=progress,
        )
    clock = time.perf_counter()
    crop_proba, missing_folds = _out_of_fold_crop_proba(
        data,
        embeddings,
        params,
        head.folds,
        progress=progress,
        on_fold=lambda k: report(f"crop classifier of fold {k + 1}/{head.folds}"),
    )
    # A fine-tuned head keeps the inputs it was trained on: the features the head to start from
    # reads, whatever ``head`` would choose for a new one (the shipped model reads the whole
    # component's features, which no new head reads).
    columns = head.columns() if start_head is None else start_head.columns
    rng = np.random.default_rng(params.seed)
    held = held_out_mask(
        data.labels, data.groups, params.held_out_fraction, rng, draws=params.held_out_draws
    )
    held_out = None
    held_predicted = np.zeros(len(data.labels), bool)
    report("segment head: measuring on held-out blocks")
    if held.any():
        measured = fit_segment_head(
            data.features[~held],
            crop_proba[~held],
            data.labels[~held],
            head,
            seed=params.seed,
            columns=columns,
            sample_weight=None if data.weights is None else data.weights[~held],
            start=start_head,
        )
        proba = measured.proba(data.features[held], crop_proba[held])
        # ">=" as the pipeline calls a segment guardrail (process_drive, predict_run).
        predicted = np.nan_to_num(proba, nan=0.0) >= params.threshold
        held_predicted[held] = predicted
        held_out = classification_metrics(data.labels[held], predicted)
        held_out.pop("n")
        held_out.update(
            n_train=int((~held).sum()),
            n_held_out=int(held.sum()),
            n_groups_held_out=int(len(np.unique(data.groups[held]))),
            threshold=params.threshold,
        )
    report("segment head: training on all segments")
    model.segment_head = fit_segment_head(
        data.features,
        crop_proba,
        data.labels,
        head,
        seed=params.seed,
        columns=columns,
        sample_weight=data.weights,
        start=start_head,
    )
    info = model.info
    info["metrics"] = {"held_out": held_out, "held_out_crops": info["metrics"]["held_out"]}
    info["segment_head"] = {
        "features": list(column_names(columns)),
        "params": head.to_json(),
        "folds_without_crop_classifier": missing_folds,
        "seconds": round(time.perf_counter() - clock, 2),
    }
    info["version"] = model_version(datetime.fromisoformat(info["created"]), model.weights())
    if progress_fn is not None:
        progress_fn(1.0, "done")
    return SetTraining(model=model, held_out=held, held_out_predicted=held_predicted)


def _kept_crop_classifier(start: GuardrailClassifier, trained_on: dict) -> GuardrailClassifier:
    """A copy of ``start`` (its crop classifier shared, unchanged) with a new record of what it
    was trained on; its segment head is replaced by the caller."""
    model = copy.copy(start)
    created = datetime.now(UTC).replace(microsecond=0)
    model.info = {
        **copy.deepcopy(start.info),
        "created": created.isoformat(),
        "trained_on": json.loads(json.dumps(trained_on)),
        "metrics": {"held_out": None},
        "training": {"crop_classifier": f"kept from {start.version} (no crops)"},
    }
    return model


def _out_of_fold_crop_proba(
    data: TrainingSet,
    embeddings: np.ndarray | None,
    params: ClassifierParams,
    folds: int,
    *,
    progress: bool,
    on_fold: Callable[[int], None] | None = None,
) -> tuple[np.ndarray, int]:
    """(S,) crop P(guardrail) of every segment from a classifier that did not see its block's
    crops (NaN without a crop), and the number of folds whose other folds held too few crops of
    each class to train on (their crops count as without a crop)."""
    proba = np.full(len(data.labels), np.nan)
    crop_rows = np.flatnonzero(data.has_crop)
    blocks = np.unique(data.groups)
    fold_of_block = np.random.default_rng(params.seed).permutation(len(blocks)) % folds
    fold = fold_of_block[np.searchsorted(blocks, data.groups[crop_rows])]
    fold_params = dataclasses.replace(params, held_out_fraction=0.0)
    labels = data.labels[crop_rows]
    missing = 0
    for k in progress_bar(range(folds), desc="crop folds", unit="fold", enabled=progress):
        if on_fold is not None:
            on_fold(k)
        train, test = np.flatnonzero(fold != k), np.flatnonzero(fold == k)
        if len(test) == 0:
            continue
        # fast: the embeddings, no copy of the crops (train_on_set made sure one is there)
        crops = None if embeddings is not None or data.crops is None else data.crops[train]
        try:
            model = train_classifier(
                crops,
                labels[train],
                embeddings=None if embeddings is None else embeddings[train],
                params=fold_params,
            )
        except TrainingDataError:
            missing += 1
            continue
        if embeddings is not None:
            proba[crop_rows[test]] = model.predict_proba(embeddings=embeddings[test])
        elif data.crops is not None:
            proba[crop_rows[test]] = model.predict_proba(data.crops[test])
    return proba, missing
