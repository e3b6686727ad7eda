"""Which drive points the 3D scene shows: a window along the trajectory, within a point budget."""

from __future__ import annotations

import numpy as np


def window_points(
    station: np.ndarray,
    point_segment: np.ndarray,
    start_m: float,
    length_m: float,
    budget: int,
) -> np.ndarray:
    """Points of the drive between two stations, at most ``budget`` of them.

    Segment points (what operators label) are kept first; road and off-road points fill what
    the budget leaves, evenly thinned.

    Parameters
    ----------
    station : (N,) float64, metres along the trajectory of every point
    point_segment : (N,) int, segment of every point (negative: road or off-road)
    start_m, length_m : the window, metres along the trajectory
    budget : the most points to return

    Returns
    -------
    (K,) int64 sorted drive point indices, K <= budget.
    """
    inside = np.flatnonzero((station >= start_m) & (station < start_m + length_m))
    in_segment = point_segment[inside] >= 0
    labelled, context = inside[in_segment], inside[~in_segment]
    labelled = _thin(labelled, budget)
    context = _thin(context, budget - len(labelled))
    return np.sort(np.concatenate([labelled, context])).astype(np.int64)


def _thin(indices: np.ndarray, budget: int) -> np.ndarray:
    """At most ``budget`` of ``indices``, evenly spaced (deterministic)."""
    if budget <= 0:
        return indices[:0]
    if len(indices) <= budget:
        return indices
    keep = np.linspace(0, len(indices) - 1, budget).round().astype(np.int64)
    return indices[np.unique(keep)]
