"""The review queue's order: which unreviewed segments are most worth an operator's look.

The review app's queue (``GET /api/queue``, the scene's "Next") and the review-loop benchmark
(``benchmarks/review_loop.py``) rank segments with these functions, so the benchmark measures the
queue operators get.
"""

from __future__ import annotations

import numpy as np


def uncertainty(probability: np.ndarray) -> np.ndarray:
    """(S,) 1 at p = 0.5, 0 at p = 0 or 1; segments without a probability count as 1."""
    p = np.asarray(probability, np.float64)
    return np.where(np.isnan(p), 1.0, 1.0 - np.abs(2.0 * p - 1.0))


def queue_scores(probability: np.ndarray, raw_label: np.ndarray, label: np.ndarray) -> np.ndarray:
    """(S,) float64: the model's uncertainty, plus 1 where the raw prediction and the corrected
    label disagree (§3.3's correction changed it: such a segment comes first)."""
    disagrees = np.asarray(raw_label, bool) != np.asarray(label, bool)
    return uncertainty(probability) + disagrees.astype(np.float64)


def queue_order(score: np.ndarray, reviewed: np.ndarray) -> np.ndarray:
    """(K,) int64 ids of the unreviewed segments (``reviewed`` (S,) bool False), highest
    :func:`queue_scores` ``score`` (S,) first; ties keep the segments' order along the drive."""
    candidates = np.flatnonzero(~np.asarray(reviewed, bool))
    return candidates[np.argsort(-np.asarray(score)[candidates], kind="stable")].astype(np.int64)
