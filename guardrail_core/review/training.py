"""Training a new model from a run folder and the operators' labels (the review app's loop).

The operators label drive points (:mod:`guardrail_core.formats.label_store`); a segment of the run whose
points carry operator labels takes their majority, every other segment keeps the run's corrected
label (§3.3; :mod:`guardrail_core.review.training_labels`). A new model (crop classifier and
segment head, :func:`~guardrail_core.extract.classify.model_training.train_on_set`; the head
fine-tuned from the head of the model that made the run, where it is given) is trained on
these labels, compared with the run's current model on the same held-out blocks of segments
(against the operators' labels of the held-out segments they reviewed, when there are enough of
them), and can then re-predict the run and replace its predictions
(:mod:`guardrail_core.review.predictions`).

In fast mode the run's ``embeddings.npy`` stands in for the crops, so no image is decoded and the
backbone never runs, but once per run for the crops ``guardrail process`` did not ask the CNN
about (:func:`~guardrail_core.review.run_crops.complete_embeddings`). Crops are cut from the
drive's images (``drive_root``, by default ``run.json``'s drive path). Measured on the
development machine (2 shared CPU cores), fast mode, embeddings complete:
:func:`train_from_run` on the test run (267 segments, 231 crops) 1.0-1.6 s, on the demo run
(1,168 segments, 1,018 crops) 2-3 s, and ``train_on_set`` on the demo set doubled (2,336
segments, 2,036 crops) 3.2-3.6 s; ``predict_run`` plus ``write_predictions`` of the demo
run 0.1 s.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.errors import InvalidOptionError, TrainingDataError
from guardrail_core.extract.classify.crop_classifier import GuardrailClassifier
from guardrail_core.extract.classify.crop_classifier_params import ClassifierParams
from guardrail_core.extract.classify.crop_classifier_training import classification_metrics
from guardrail_core.extract.classify.model_training import (
    HOLD_OUT_BLOCK_SLICES,
    TrainingSet,
    train_on_set,
)
from guardrail_core.extract.classify.segment_head import SegmentHead, SegmentHeadParams
from guardrail_core.extract.crops import CROP_OK
from guardrail_core.formats.run_folder import Run
from guardrail_core.review.run_crops import complete_embeddings, read_crops
from guardrail_core.review.training_labels import operator_labels, training_rows

__all__ = ["ReviewTraining", "train_from_run", "training_set_from_run"]

MODES = ("fast", "full")
#: ``"against"`` of :func:`train_from_run`'s metrics: the held-out segments an operator reviewed,
#: their operator labels; or every held-out segment, the run's corrected label where not reviewed.
AGAINST_OPERATOR = "operator labels"
AGAINST_EFFECTIVE = "operator and corrected labels"


def training_set_from_run(
    run: Run,
    point_labels: np.ndarray | None = None,
    *,
    operator_label: np.ndarray | None = None,
    mode: str = "fast",
    include_unreviewed: bool = True,
    leave_out_contradicted: bool = True,
    input_size: int = 128,
    drive_root: str | Path | None = None,
) -> TrainingSet:
    """The run's segments as a training set, labelled by
    :func:`~guardrail_core.review.training_labels.effective_labels`.

    Parameters
    ----------
    run : the run folder
    point_labels : (N,) int8 operator labels of the drive's points
    operator_label : or, instead, (S,) int8 the operators' label of every segment (-1 none)
    mode : "fast": the crops' embeddings from ``embeddings.npy`` when the run has them (no image
        is read but for the rows the run lacks); "full" (or a run without embeddings): the crops
    include_unreviewed : False keeps only the segments the operators labelled
    leave_out_contradicted : leave out the unreviewed segments labelled otherwise than an
        operator labelled a segment of their component
        (:func:`~guardrail_core.review.training_labels.contradicted_labels`)
    input_size : px, the crops' size the model takes (that of the run's embeddings)
    drive_root : the drive folder the crops are cut from; None: ``run.json``'s drive path

    Returns
    -------
    TrainingSet
        features, labels, groups (``slice_index // HOLD_OUT_BLOCK_SLICES``, 10 m blocks),
        has_crop, crops (K, C, C, 3) uint8 RGB or None, embeddings (K, 1280) float32 or None,
        sources ``[{"run", "segments", "crops", "reviewed", "guardrail", "other",
        "left_out"}]`` (``left_out``: the contradicted segments not in the set).

    Raises
    ------
    InvalidOptionError
        Bad mode, point labels not of the run's drive, segment labels not of the run, or not
        exactly one of ``point_labels`` and ``operator_label``.
    MissingDriveFileError
        An image a crop is cut from is missing or unreadable.
    """
    if mode not in MODES:
        raise InvalidOptionError(f"mode: expected 'fast' or 'full', got {mode!r}")
    operator_label = operator_labels(run, point_labels, operator_label)
    rows, label, reviewed, n_left_out = training_rows(
        run, operator_label, include_unreviewed, leave_out_contradicted
    )
    segments = run.segments
    has_crop = segments["crop_status"][rows] == CROP_OK
    crop_segments = rows[has_crop]
    stored = complete_embeddings(run, input_size, drive_root=drive_root) if mode == "fast" else None
    crops = embeddings = None
    if stored is not None:
        embeddings = stored[crop_segments].astype(np.float32)
    else:
        crops = read_crops(run, crop_segments, input_size, drive_root=drive_root)
    labels = label[rows]
    return TrainingSet(
        features=np.asarray(segments["features"][rows], np.float32),
        labels=labels,
        groups=(segments["slice_index"][rows] // HOLD_OUT_BLOCK_SLICES).astype(np.int64),
        has_crop=has_crop,
        crops=crops,
        embeddings=embeddings,
        sources=[
            {
                "run": str(run.root),
                "segments": len(rows),
                "crops": len(crop_segments),
                "reviewed": int(reviewed[rows].sum()),
                "guardrail": int(labels.sum()),
                "other": int((~labels).sum()),
                "left_out": n_left_out,
            }
        ],
    )


@dataclass(frozen=True)
class ReviewTraining:
    """A model trained by :func:`train_from_run`, and how it compares with the run's model.

    Both metrics are measured on the same segments against the same labels: the held-out
    segments an operator reviewed, against the operators' labels, when at least
    ``min_reviewed_held_out`` of them were reviewed (or all of them, as with
    ``include_unreviewed`` False); else every held-out segment against the effective labels,
    where the unreviewed ones carry the current model's own corrected labels, which favours it.

    Attributes
    ----------
    model : the new model (crop classifier and segment head)
    metrics_new : :func:`classification_metrics` (without ``n``, with ``n_train``,
        ``n_held_out`` (the segments measured), ``n_groups_held_out``, ``n_reviewed_held_out``,
        ``threshold``, ``against``: :data:`AGAINST_OPERATOR` or :data:`AGAINST_EFFECTIVE`, and
        with the latter a ``note``) of a new model trained without the held-out segments, on them
        (= ``model.info["metrics"]["held_out"]``); None when nothing could be held out
    metrics_current : the same for the run's current predictions (``probability >= threshold``
        of the run's model, before correction), plus ``model``, its version
    held_out : (S,) bool over all the run's segments, the held-out ones (all of them, reviewed
        or not: the blocks the new model's segment head was measured without)
    seconds : wall time of the training
    """

    model: GuardrailClassifier
    metrics_new: dict[str, Any] | None
    metrics_current: dict[str, Any] | None
    held_out: np.ndarray
    seconds: float


def _reviewed_weight(reviewed: np.ndarray, reviewed_weight: float | None) -> float:
    """How many times each reviewed segment (``reviewed`` (S,) bool) counts in the segment
    head's loss against one the model labelled (see :func:`train_from_run`): 1 where none or
    all were reviewed."""
    n_reviewed = int(np.count_nonzero(reviewed))
    if n_reviewed in (0, len(reviewed)):
        return 1.0
    if reviewed_weight is None:
        return max(1.0, (len(reviewed) - n_reviewed) / n_reviewed)
    return float(reviewed_weight)


def train_from_run(
    run: Run,
    point_labels: np.ndarray | None = None,
    *,
    operator_label: np.ndarray | None = None,
    params: ClassifierParams = ClassifierParams(mode="fast"),
    head: SegmentHeadParams = SegmentHeadParams(),
    include_unreviewed: bool = True,
    leave_out_contradicted: bool = True,
    min_reviewed_held_out: int = 20,
    progress_fn: Callable[[float, str], None] | None = None,
    drive_root: str | Path | None = None,
    reviewed_weight: float | None = None,
    start_from: GuardrailClassifier | None = None,
) -> ReviewTraining:
    """Train a new model on a run's segments, labelled by the operators where they reviewed.

    Parameters
    ----------
    run : the run folder
    point_labels : (N,) int8 operator labels of the drive's points (-1 none, 0 other, 1 guardrail)
    operator_label : or, instead, (S,) int8 the operators' label of every segment (-1 none)
    params : crop classifier parameters; fast mode trains on the run's ``embeddings.npy`` in
        seconds, full mode fine-tunes on the crops (minutes)
    head : segment head parameters
    include_unreviewed : train on every segment (the run's corrected label where not reviewed);
        False: only on the reviewed segments
    leave_out_contradicted : but not on the unreviewed segments labelled otherwise than an
        operator labelled a segment of their wireframe component
        (:func:`~guardrail_core.review.training_labels.contradicted_labels`);
        False trains on them too (README, "The review loop's learning curve": on four streets
        of a design the model never saw, guardrail F after 100 labels in the queue's order was
        0.005-0.050 higher without them)
    min_reviewed_held_out : compare the models on the reviewed held-out segments, against the
        operators' labels, when there are at least this many (>= 1); else on every held-out
        segment against the effective labels (see :class:`ReviewTraining`)
    progress_fn : ``progress_fn(fraction 0..1, message)`` at each step
    drive_root : the drive folder the crops are cut from; None: ``run.json``'s drive path
    reviewed_weight : how many times an operator's label counts against a label the model gave
        itself, in the segment head's loss (the crop classifier counts every label once); None:
        the reviewed segments together weigh as much as the others (and each at least once).
        Counted once, a hundred labels drown in the thousands the current model gave itself,
        and the new model learns the old one's mistakes again
    start_from : the model to fine-tune, normally the one whose predictions the run holds: the
        new segment head starts from its head (its networks, the features it reads and their
        standardisation) for ``head.fine_tune_epochs``, so what its training drives taught it
        stays where the run's labels do not say otherwise; None, or a model without a segment
        head: a new head from fresh draws, taught by this run alone (README, "The review
        loop's learning curve": on four streets of designs the model never saw, F after 100
        labels 0.006-0.027 lower that way). The crop classifier is trained anew either way

    Returns
    -------
    ReviewTraining
        ``model.info["trained_on"]`` says which labels ("operator labels (R segments) +
        corrected labels"), the run and the counts; ``info["metrics"]["held_out"]`` holds
        ``metrics_new``, ``info["metrics"]["held_out_current"]`` ``metrics_current``, and, when
        they are measured against the operators' labels, ``info["metrics"]["held_out_all"]`` the
        new model's figures on every held-out segment against the effective labels.

    Raises
    ------
    InvalidOptionError
        ``min_reviewed_held_out`` not a whole number >= 1.
    TrainingDataError
        No reviewed segment (with ``include_unreviewed`` False), labels of one class only, or too
        few crops.
    """
    if (
        not isinstance(min_reviewed_held_out, int | np.integer)
        or isinstance(min_reviewed_held_out, bool)
        or min_reviewed_held_out < 1
    ):
        raise InvalidOptionError(
            f"min_reviewed_held_out: expected a whole number >= 1, got {min_reviewed_held_out!r}"
        )
    if reviewed_weight is not None and not (
        isinstance(reviewed_weight, int | float)
        and not isinstance(reviewed_weight, bool)
        and 1 <= reviewed_weight < float("inf")
    ):
        raise InvalidOptionError(
            f"reviewed_weight: expected a number >= 1 or None, got {reviewed_weight!r}"
        )
    clock = time.perf_counter()
    if progress_fn is not None:
        progress_fn(0.0, "reading the run")
    operator_label = operator_labels(run, point_labels, operator_label)  # worked out once
    data = training_set_from_run(
        run,
        operator_label=operator_label,
        mode=params.mode,
        include_unreviewed=include_unreviewed,
        leave_out_contradicted=leave_out_contradicted,
        input_size=params.input_size_px,
        drive_root=drive_root,
    )
    rows, _, reviewed_all, n_left_out = training_rows(
        run, operator_label, include_unreviewed, leave_out_contradicted
    )
    reviewed = reviewed_all[rows]
    weight = _reviewed_weight(reviewed, reviewed_weight)
    if weight != 1.0:
        data = dataclasses.replace(data, weights=np.where(reviewed, weight, 1.0).astype(np.float32))
    n_reviewed = data.sources[0]["reviewed"]
    n_guardrail = int(data.labels.sum())
    if not include_unreviewed and n_reviewed == 0:
        raise TrainingDataError(
            f"{run.root}: expected operator-labelled segments to train on, got none "
            "(label some segments, or include the unreviewed ones)"
        )
    if n_guardrail in (0, len(data.labels)):
        which = "operator-labelled" if not include_unreviewed else "labelled"
        raise TrainingDataError(
            f"{run.root}: expected {which} segments of both classes, got {n_guardrail} guardrail "
            f"and {len(data.labels) - n_guardrail} other"
        )
    labels_text = f"operator labels ({n_reviewed} segments)"
    if include_unreviewed:
        labels_text += " + corrected labels"
        if n_left_out:
            labels_text += (
                f" ({n_left_out} contradicted by an operator on their component left out)"
            )
    head, start_head = _fine_tuning_head(start_from, head)
    trained_on = {
        "labels": labels_text,
        "runs": data.sources,
        "run_model": run.info.model.version,
        "reviewed_segments": n_reviewed,
        "reviewed_weight": round(weight, 3),
        "segment_head_from": None
        if start_from is None or start_head is None
        else start_from.version,
    }
    trained = train_on_set(
        data,
        params=params,
        head=head,
        progress_fn=progress_fn,
        trained_on=trained_on,
        start_head=start_head,
        crops_from=start_from,
    )
    model, held = trained.model, trained.held_out
    metrics_new = metrics_current = None
    if held.any():
        # data.labels are the operators' labels where reviewed, so on ``measured`` both models
        # are scored against the operators alone; elsewhere the labels are the current model's.
        held_reviewed = held & reviewed
        n_reviewed_held = int(held_reviewed.sum())
        extra: dict[str, Any] = {"n_reviewed_held_out": n_reviewed_held}
        if n_reviewed_held >= min_reviewed_held_out or n_reviewed_held == int(held.sum()):
            measured = held_reviewed
            extra["against"] = AGAINST_OPERATOR
        else:
            measured = held
            extra["against"] = AGAINST_EFFECTIVE
            extra["note"] = (
                f"only {n_reviewed_held} of the {int(held.sum())} held-out segments were "
                f"reviewed (fewer than {min_reviewed_held_out}): the others are scored against "
                "the current model's own corrected labels, which favours the current model"
            )
        metrics_new = _held_out_metrics(
            data, held, measured, trained.held_out_predicted, params.threshold, extra
        )
        metrics_current = _held_out_metrics(
            data, held, measured, _current_raw_labels(run)[rows], _run_threshold(run), extra
        )
        metrics_current["model"] = run.info.model.version
        if n_reviewed_held < int(held.sum()) and measured is held_reviewed:
            model.info["metrics"]["held_out_all"] = model.info["metrics"]["held_out"]
    model.info["metrics"]["held_out"] = metrics_new
    model.info["metrics"]["held_out_current"] = metrics_current
    held_out = np.zeros(len(run), bool)
    held_out[rows[held]] = True
    return ReviewTraining(
        model=model,
        metrics_new=metrics_new,
        metrics_current=metrics_current,
        held_out=held_out,
        seconds=time.perf_counter() - clock,
    )


def _fine_tuning_head(
    start_from: GuardrailClassifier | None, head: SegmentHeadParams
) -> tuple[SegmentHeadParams, SegmentHead | None]:
    """The segment head's parameters and the head to start from: ``start_from``'s own shape
    (members, width, its ignored features as recorded) with ``head``'s training settings;
    ``head`` and None where there is no head to start from. The new head reads the columns the
    head to start from reads
    (:func:`~guardrail_core.extract.classify.model_training.train_on_set`), which for a model
    trained before chains are not those its ignored features would choose."""
    if start_from is None or start_from.segment_head is None:
        return head, None
    saved = SegmentHeadParams.from_json(start_from.info.get("segment_head", {}).get("params", {}))
    shaped = dataclasses.replace(
        head,
        members=saved.members,
        hidden_units=saved.hidden_units,
        ignored_features=saved.ignored_features,
    )
    return shaped, start_from.segment_head


def _held_out_metrics(
    data: TrainingSet,
    held: np.ndarray,
    measured: np.ndarray,
    predicted: np.ndarray,
    threshold: float,
    extra: dict[str, Any],
) -> dict[str, Any]:
    """:func:`classification_metrics` of ``predicted`` against ``data.labels`` on ``measured``
    (held-out segments), without ``n``, with the counts, ``threshold`` and ``extra``."""
    out = classification_metrics(data.labels[measured], predicted[measured])
    out.pop("n")
    out.update(
        n_train=int((~held).sum()),
        n_held_out=int(measured.sum()),
        n_groups_held_out=int(len(np.unique(data.groups[measured]))),
        threshold=threshold,
        **extra,
    )
    return out


def _run_threshold(run: Run) -> float:
    return run.info.model.threshold


def _current_raw_labels(run: Run) -> np.ndarray:
    """(S,) bool, the run's model's raw labels: ``probability >= threshold`` (NaN: other)."""
    probability = np.asarray(run.segments["probability"], np.float64)
    return np.nan_to_num(probability, nan=0.0) >= _run_threshold(run)
