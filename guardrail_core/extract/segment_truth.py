"""The true class of each segment, from the drive's per-point truth (training and evaluation)."""

from __future__ import annotations

import numpy as np

from guardrail_core.classes import GUARDRAIL_CLASSES


def segment_truth(
    point_class: np.ndarray, point_segment: np.ndarray, n_segments: int
) -> np.ndarray:
    """True class (S,) bool of every segment: guardrail when most of its points are guardrail.

    Parameters
    ----------
    point_class : (N,) truth class of every point (:class:`guardrail_core.classes.TruthClass`)
    point_segment : (N,) segment of every point, negative for points in no segment
    n_segments : S
    """
    in_segment = point_segment >= 0
    segment = point_segment[in_segment]
    guardrail = np.isin(point_class[in_segment], list(GUARDRAIL_CLASSES))
    n_guardrail = np.bincount(segment, weights=guardrail, minlength=n_segments)
    n_points = np.bincount(segment, minlength=n_segments)
    return 2 * n_guardrail > n_points
