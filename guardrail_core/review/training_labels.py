"""The labels a run's segments are trained on: the operators' where they reviewed, the run's
corrected labels (§3.3) elsewhere, less those an operator contradicted on the same wireframe
component (the review app's loop; :mod:`guardrail_core.review.training` trains on them).
"""

from __future__ import annotations

import numpy as np

from guardrail_core.errors import InvalidOptionError
from guardrail_core.formats.run_folder import Run

__all__ = [
    "contradicted_labels",
    "effective_labels",
    "operator_labels",
    "segment_labels",
    "training_rows",
]


def segment_labels(
    point_segment: np.ndarray, n_segments: int, point_labels: np.ndarray
) -> np.ndarray:
    """Operator label of each segment from the labels of its points.

    Parameters
    ----------
    point_segment : (N,) int, segment of every drive point; negative (road, off road) for none
    n_segments : S, the number of segments
    point_labels : (N,) int, operator label of every point: -1 none, 0 other, 1 guardrail

    Returns
    -------
    (S,) int8 : -1 where none of the segment's points is labelled, else the majority of its
        labelled points (1 when at least half of them are guardrail)
    """
    point_segment = np.asarray(point_segment)
    point_labels = np.asarray(point_labels)
    if not isinstance(n_segments, int | np.integer) or n_segments < 0:
        raise InvalidOptionError(f"n_segments: expected a whole number >= 0, got {n_segments!r}")
    if (
        point_segment.ndim != 1
        or point_labels.shape != point_segment.shape
        or point_segment.dtype.kind not in "iu"
        or point_labels.dtype.kind not in "iu"
    ):
        raise InvalidOptionError(
            f"segment_labels: expected (N,) integer point_segment and point_labels of the same "
            f"length, got {point_segment.shape} {point_segment.dtype} and {point_labels.shape} "
            f"{point_labels.dtype} (a label store for another drive?)"
        )
    if len(point_segment) and point_segment.max() >= n_segments:
        raise InvalidOptionError(
            f"point_segment: expected segments below {n_segments}, got {point_segment.max()}"
        )
    if len(point_labels) and (point_labels.min() < -1 or point_labels.max() > 1):
        raise InvalidOptionError(
            f"point_labels: expected -1, 0 or 1, got values from {point_labels.min()} to "
            f"{point_labels.max()}"
        )
    labelled = (point_segment >= 0) & (point_labels >= 0)
    segment = point_segment[labelled]
    n_labelled = np.bincount(segment, minlength=n_segments)
    n_guardrail = np.bincount(segment, weights=point_labels[labelled] == 1, minlength=n_segments)
    out = np.full(n_segments, -1, np.int8)
    has = n_labelled > 0
    out[has] = 2 * n_guardrail[has] >= n_labelled[has]
    return out


def effective_labels(
    run: Run, point_labels: np.ndarray | None = None, *, operator_label: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Labels to train on: the operators' where they reviewed, the run's corrected ones elsewhere.

    Parameters
    ----------
    run : the run folder
    point_labels : (N,) int8, operator label of every drive point (-1 none, 0 other, 1 guardrail),
        :meth:`guardrail_core.formats.label_store.LabelStore.point_labels`
    operator_label : or, instead, (S,) int8 the operators' label of every segment (-1 none;
        :func:`segment_labels`), as the review app keeps them (it holds nothing per point)

    Returns
    -------
    label : (S,) bool, True for guardrail
    reviewed : (S,) bool, the segment has operator-labelled points
    """
    operator = operator_labels(run, point_labels, operator_label)
    reviewed = operator >= 0
    label = np.where(reviewed, operator == 1, np.asarray(run.segments["label"], bool))
    return label, reviewed


def contradicted_labels(
    component: np.ndarray, label: np.ndarray, reviewed: np.ndarray
) -> np.ndarray:
    """(S,) bool: the unreviewed segments labelled otherwise than an operator labelled a segment
    of their wireframe component.

    An operator's labels are the only ones known right; the run's model labelled everything
    else itself. Where its label of a slice disagrees with an operator's label on the same
    component (§3.1: the same rail, fence or hedge, sliced), it is in doubt: a bar fence the
    model called guardrail is guardrail on all its slices, and a rail it half missed is other on
    the slices it missed. Trained on, those labels outvote the operator's few and the new model
    learns the old one's mistakes again. They are left out of training, not relabelled: a
    component can hold a rail and the hedge pressed against it.

    Parameters
    ----------
    component : (S,) int, each segment's wireframe component (``segments.npz`` ``component``)
    label, reviewed : (S,) bool, :func:`effective_labels` (the operators' label where reviewed,
        the run's corrected label elsewhere)
    """
    label = np.asarray(label, bool)
    reviewed = np.asarray(reviewed, bool)
    _, component = np.unique(np.asarray(component), return_inverse=True)
    n_components = int(component.max()) + 1 if len(component) else 0
    said_guardrail = np.bincount(component[reviewed & label], minlength=n_components) > 0
    said_other = np.bincount(component[reviewed & ~label], minlength=n_components) > 0
    return ~reviewed & np.where(label, said_other[component], said_guardrail[component])


def training_rows(
    run: Run, operator_label: np.ndarray, include_unreviewed: bool, leave_out_contradicted: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The segments to train on (K,) int64, the (S,) labels and reviewed flags of all of them
    (:func:`effective_labels`), and how many unreviewed ones were left out as contradicted."""
    label, reviewed = effective_labels(run, operator_label=operator_label)
    if not include_unreviewed:
        return np.flatnonzero(reviewed), label, reviewed, 0
    left_out = np.zeros(len(run), bool)
    if leave_out_contradicted:
        left_out = contradicted_labels(run.segments["component"], label, reviewed)
    return np.flatnonzero(~left_out), label, reviewed, int(left_out.sum())


def operator_labels(
    run: Run, point_labels: np.ndarray | None, operator_label: np.ndarray | None
) -> np.ndarray:
    """(S,) int8 the operators' label of every segment, from labels per point or per segment."""
    if (point_labels is None) == (operator_label is None):
        raise InvalidOptionError(
            "expected the operators' labels per point (point_labels) or per segment "
            "(operator_label), one of the two"
        )
    if point_labels is not None:
        _check_point_labels(run, point_labels)
        return segment_labels(run.point_segment, len(run), point_labels)
    operator = np.asarray(operator_label)
    if operator.shape != (len(run),) or operator.dtype.kind not in "iu":
        raise InvalidOptionError(
            f"operator_label: expected ({len(run)},) integer labels, one per segment of the run, "
            f"got shape {operator.shape} dtype {operator.dtype} (labels of another run?)"
        )
    if len(operator) and (operator.min() < -1 or operator.max() > 1):
        raise InvalidOptionError(
            f"operator_label: expected -1, 0 or 1, got values from {operator.min()} to "
            f"{operator.max()}"
        )
    return operator.astype(np.int8)


def _check_point_labels(run: Run, point_labels: np.ndarray) -> None:
    shape = np.shape(point_labels)
    if shape != (len(run.point_segment),):
        raise InvalidOptionError(
            f"point_labels: expected ({len(run.point_segment)},) labels, one per point of the "
            f"run's drive, got shape {shape} (labels of another drive?)"
        )
