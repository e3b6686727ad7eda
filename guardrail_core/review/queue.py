"""The review queue's order: which unreviewed segments are most worth an operator's look.

The review app's queue (``GET /api/queue``, the scene's "Next") and the review-loop benchmark
(``benchmarks/review_loop.py``) rank segments with these functions, so the benchmark measures the
queue operators get.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np


def uncertainty(probability: np.ndarray) -> np.ndarray:
    """(S,) 1 at p = 0.5, 0 at p = 0 or 1; segments without a probability count as 1."""
    p = np.asarray(probability, np.float64)
    return np.where(np.isnan(p), 1.0, 1.0 - np.abs(2.0 * p - 1.0))


#: Segments of fewer points are left out of the queue: a few points say too little to judge
#: (most have no crop), and a decision on them moves almost nothing.
MIN_QUEUE_POINTS = 10
#: Points at which a decision's weight stops growing (it grows with their logarithm).
FULL_WEIGHT_POINTS = 200
#: How much more a decision counts when it joins two guardrail stretches or removes a lone one.
RUN_CHANGE_WEIGHT = 0.5
#: The queue asks about a segment only when the model's :func:`uncertainty` is at least this
#: (P(guardrail) between 5 % and 95 %), unless the correction changed its label or it stands
#: for a run nobody has looked at: below it a look rarely changes a label, and the review is
#: done when nothing above it is left.
ASK_MIN_UNCERTAINTY = 0.1
#: A component labelled guardrail on at least this many segments (of ``MIN_QUEUE_POINTS`` points
#: or more) is a run an operator should see once (:func:`unchecked_runs`).
UNCHECKED_RUN_MIN_SEGMENTS = 5


def points_weight(n_points: np.ndarray) -> np.ndarray:
    """(S,) 0..1: how much of a run a decision on each segment moves, log1p(n) / log1p(200)
    capped at 1 (a 1-point segment 0.13, 10 points 0.45, 200 points and more 1)."""
    n = np.asarray(n_points, np.float64)
    return np.minimum(1.0, np.log1p(n) / np.log1p(FULL_WEIGHT_POINTS))


def odd_one_out(component: np.ndarray, slice_index: np.ndarray, label: np.ndarray) -> np.ndarray:
    """(S,) bool: segments whose label differs from both neighbours' along their connected run
    (the previous and the next slice of the same wireframe component, §3.1): flipping such a
    segment joins two guardrail stretches into one, or removes a lone guardrail piece."""
    component = np.asarray(component, np.int64)
    slice_index = np.asarray(slice_index, np.int64)
    label = np.asarray(label, bool)
    key = component * (1 << 32) + (slice_index - slice_index.min() if len(slice_index) else 0)
    order = np.argsort(key, kind="stable")
    k, lab = key[order], label[order]
    before = np.zeros(len(k), bool)
    after = np.zeros(len(k), bool)
    before[1:] = (k[1:] - k[:-1] == 1) & (lab[:-1] != lab[1:])
    after[:-1] = (k[1:] - k[:-1] == 1) & (lab[1:] != lab[:-1])
    out = np.zeros(len(k), bool)
    out[order] = before & after
    return out


def unchecked_runs(
    component: np.ndarray,
    label: np.ndarray,
    n_points: np.ndarray,
    reviewed: np.ndarray,
    score: np.ndarray,
    *,
    min_segments: int = UNCHECKED_RUN_MIN_SEGMENTS,
    min_points: int = MIN_QUEUE_POINTS,
) -> np.ndarray:
    """(S,) bool: one segment of every guardrail run no operator has looked at yet.

    A run here is a wireframe component (§3.1) labelled guardrail on ``min_segments`` or more
    segments of ``min_points`` points or more, with no reviewed segment. Of those segments, the
    one of the highest ``score`` is marked. A model sure of a mistake never offers
    it as uncertain: a bar fence a model that never saw a design calls guardrail at P 0.9999
    waits forever behind the doubtful slices of the real rails. One look at each run finds it,
    and the fine-tuning learns the whole fence from that one label. There are a few tens of
    such runs on a 300 m street.

    Parameters
    ----------
    component : (S,) int, each segment's wireframe component
    label : (S,) bool, the run's corrected labels
    n_points : (S,) int, points per segment
    reviewed : (S,) bool, an operator has labelled the segment
    score : (S,) float, :func:`queue_scores` (ties: the first along the drive)
    """
    label = np.asarray(label, bool)
    reviewed = np.asarray(reviewed, bool)
    big = label & (np.asarray(n_points) >= min_points)
    _, component = np.unique(np.asarray(component), return_inverse=True)
    n_components = int(component.max()) + 1 if len(component) else 0
    guardrail = np.bincount(component[big], minlength=n_components)
    seen = np.bincount(component[reviewed], minlength=n_components) > 0
    candidates = np.flatnonzero(big & ~seen[component] & (guardrail[component] >= min_segments))
    # Highest score first within each component; the first of each component is marked.
    order = candidates[np.lexsort((-np.asarray(score)[candidates], component[candidates]))]
    first = np.ones(len(order), bool)
    first[1:] = component[order][1:] != component[order][:-1]
    out = np.zeros(len(label), bool)
    out[order[first]] = True
    return out


def queue_scores(
    probability: np.ndarray,
    raw_label: np.ndarray,
    label: np.ndarray,
    *,
    n_points: np.ndarray | None = None,
    run_change: np.ndarray | None = None,
) -> np.ndarray:
    """(S,) float64: the change a decision is expected to make.

    The model's uncertainty (how likely the operator's label differs from its own), weighted
    by the points the decision moves (:func:`points_weight`, when ``n_points`` is given) and
    by half again where it would join or split a guardrail run (``run_change``,
    :func:`odd_one_out`); plus 1 where the raw prediction and the corrected label disagree
    (§3.3's correction changed it: such a segment comes first).
    """
    disagrees = np.asarray(raw_label, bool) != np.asarray(label, bool)
    expected = uncertainty(probability)
    if n_points is not None:
        expected = expected * points_weight(n_points)
    if run_change is not None:
        expected = expected * (1.0 + RUN_CHANGE_WEIGHT * np.asarray(run_change, bool))
    return expected + disagrees.astype(np.float64)


def segment_queue_scores(
    segments: Mapping[str, np.ndarray], reviewed: np.ndarray | None = None
) -> np.ndarray:
    """(S,) :func:`queue_scores` of a run's segments table (``segments.npz``), every term used:
    what the review app's queue and the review-loop benchmark rank by. With ``reviewed`` (S,)
    bool, plus 1 on one segment of every guardrail run no operator has looked at yet
    (:func:`unchecked_runs`)."""
    score = queue_scores(
        segments["probability"],
        segments["raw_label"],
        segments["label"],
        n_points=segments["n_points"],
        run_change=odd_one_out(segments["component"], segments["slice_index"], segments["label"]),
    )
    if reviewed is None:
        return score
    unchecked = unchecked_runs(
        segments["component"], segments["label"], segments["n_points"], reviewed, score
    )
    return score + unchecked.astype(np.float64)


def asked_segments(
    segments: Mapping[str, np.ndarray],
    reviewed: np.ndarray,
    *,
    unchecked: np.ndarray | None = None,
    min_uncertainty: float = ASK_MIN_UNCERTAINTY,
    min_points: int = MIN_QUEUE_POINTS,
) -> np.ndarray:
    """(S,) bool: the segments the review queue asks an operator about.

    Unreviewed (``reviewed`` (S,) bool False), of ``min_points`` points or more, and one of:
    the correction changed the model's label ("disagrees"), it stands for a guardrail run
    nobody has looked at (:func:`unchecked_runs`, "unchecked"; pass ``unchecked`` (S,) bool
    where the caller has it already), or the model's :func:`uncertainty` is at least
    ``min_uncertainty`` ("uncertain"). When none is left, the review of the run folder is done.
    """
    reviewed = np.asarray(reviewed, bool)
    disagrees = np.asarray(segments["raw_label"], bool) != np.asarray(segments["label"], bool)
    if unchecked is None:
        unchecked = unchecked_runs(
            segments["component"],
            segments["label"],
            segments["n_points"],
            reviewed,
            segment_queue_scores(segments),
        )
    doubtful = uncertainty(segments["probability"]) >= min_uncertainty
    big = np.asarray(segments["n_points"]) >= min_points
    return ~reviewed & big & (disagrees | unchecked | doubtful)


def queue_order(
    score: np.ndarray,
    reviewed: np.ndarray,
    *,
    n_points: np.ndarray | None = None,
    min_points: int = MIN_QUEUE_POINTS,
) -> np.ndarray:
    """(K,) int64 ids of the unreviewed segments (``reviewed`` (S,) bool False), highest
    :func:`queue_scores` ``score`` (S,) first; ties keep the segments' order along the drive.
    With ``n_points``, segments of fewer than ``min_points`` points are left out."""
    keep = ~np.asarray(reviewed, bool)
    if n_points is not None:
        keep &= np.asarray(n_points) >= min_points
    candidates = np.flatnonzero(keep)
    return candidates[np.argsort(-np.asarray(score)[candidates], kind="stable")].astype(np.int64)
