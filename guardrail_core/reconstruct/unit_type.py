"""Pipes or beams (Matsumoto et al. 2019, §4.4): "a relatively large rectangle region is
filled by points" for beams, not for pipes.

Input: superimposed points of units in unit coordinates (:mod:`guardrail_core.reconstruct.unit_frame`:
x along the unit from its first pole's axis, y above the ground line, z toward the road; metres).
The thresholds are :class:`~guardrail_core.reconstruct.beams.BeamParams`'.
"""

from __future__ import annotations

import math

import numpy as np

from guardrail_core.reconstruct.beams import BeamParams, check_unit_length
from guardrail_core.reconstruct.pipes import check_unit_points


def _filled_height(points: np.ndarray, length: float, params: BeamParams) -> float:
    """Height (m) of the tallest region of rows filled by points (see :class:`BeamParams`)."""
    p = params
    x, y = points[:, 0], points[:, 1]
    keep = (x > p.type_margin_m) & (x < length - p.type_margin_m)
    x, y = x[keep], y[keep]
    if len(x) == 0:
        return 0.0
    nx = max(1, int(math.ceil((length - 2 * p.type_margin_m) / p.cell_m)))
    ix = np.minimum(((x - p.type_margin_m) / p.cell_m).astype(np.int64), nx - 1)
    y0 = float(y.min())
    iy = ((y - y0) / p.cell_m).astype(np.int64)
    ny = int(iy.max()) + 1
    grid = np.zeros((ny, nx), dtype=bool)
    grid[iy, ix] = True
    # Occupancy of each row over its band of rows.
    k = max(1, int(round(p.band_m / p.cell_m)))
    cum = np.vstack([np.zeros((1, nx)), np.cumsum(grid, axis=0)])
    lo = np.clip(np.arange(ny) - k // 2, 0, ny)
    hi = np.clip(lo + k, 0, ny)
    occupancy = ((cum[hi] - cum[lo]) > 0).mean(axis=1)
    occupied = np.flatnonzero(occupancy >= p.row_share)
    if len(occupied) == 0:
        return 0.0
    # Regions of occupied rows, bridging short gaps.
    breaks = np.flatnonzero(np.diff(occupied) * p.cell_m > p.max_gap_m + p.cell_m)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(occupied) - 1]])
    best = 0.0
    for a, b in zip(occupied[starts], occupied[ends], strict=True):
        if occupancy[a : b + 1].mean() >= p.filled_share:
            best = max(best, (b - a + 1) * p.cell_m)
    return best


def unit_type(points: np.ndarray, length: float, params: BeamParams = BeamParams()) -> str:
    """Tell a beam unit from a pipe unit (§4.4: beams fill a relatively large rectangle).

    Parameters
    ----------
    points : (N, 3) float64, unit coordinates, metres
        Superimposed unit points (pole points may be included: points within
        ``params.type_margin_m`` of the poles are ignored).
    length : float, metres
        Unit length.
    params : BeamParams

    Returns
    -------
    "beam" when a region of at least ``min_height_m`` is filled by points, no more than
    ``max_open_share`` of the x bins are open and the median x column leaves no gap in height
    taller than ``max_column_gap_m`` (a plate's); else "pipe".

    Raises
    ------
    ReconstructionError
        If points are not (N, 3) finite or length is not > 0.

    References
    ----------
    Matsumoto, Mori, Masuda (2019). Extraction and shape reconstruction of guardrails using
    mobile mapping data. ISPRS Archives XLII-2/W13, §4.4.
    """
    pts = check_unit_points(points)
    length = check_unit_length(length)
    if _filled_height(pts, length, params) < params.min_height_m:
        return "pipe"
    if _open_share(pts, length, params) > params.max_open_share:
        return "pipe"
    return "beam" if _column_gap(pts, length, params) <= params.max_column_gap_m else "pipe"


def _open_share(points: np.ndarray, length: float, params: BeamParams) -> float:
    """Share of the x bins (``cell_m / 2`` wide) between the margins that hold no point, among the
    points of the middle ``open_height_share`` of the heights (rails above and below would cover
    every x)."""
    p = params
    inside = (points[:, 0] > p.type_margin_m) & (points[:, 0] < length - p.type_margin_m)
    x, y = points[inside, 0], points[inside, 1]
    if len(y):
        half = 50 * p.open_height_share  # percent either side of the median
        low, high = np.percentile(y, [50 - half, 50 + half])
        x = x[(y >= low) & (y <= high)]
    width = p.cell_m / 2
    n_bins = max(1, int(math.floor((length - 2 * p.type_margin_m) / width)))
    if len(x) == 0:
        return 1.0
    counts = np.bincount(
        np.minimum(((x - p.type_margin_m) / width).astype(np.int64), n_bins - 1), minlength=n_bins
    )
    return float((counts == 0).mean())


def _column_gap(points: np.ndarray, length: float, params: BeamParams) -> float:
    """Metres: the tallest gap in height between the points of the median x column
    (``gap_column_m`` wide, between the margins), among the points near the unit's median depth
    and within its ``gap_height_share`` of heights (see :class:`BeamParams`).

    A beam's plate leaves gaps of its scan lines' spacing, or of a shadowed valley (under
    0.1 m); pipes leave the space between them in every column (0.12-0.35 m for a wave,
    crossing diagonals or a diamond lattice). 0.0 when no column holds ``gap_column_points``.
    """
    p = params
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    keep = (x > p.type_margin_m) & (x < length - p.type_margin_m)
    if keep.any():
        keep &= np.abs(z - np.median(z[keep])) <= p.gap_depth_m
    x, y = x[keep], y[keep]
    if len(x) == 0:
        return 0.0
    half = 50 * p.gap_height_share  # percent either side of the median
    low, high = np.percentile(y, [50 - half, 50 + half])
    within = (y >= low) & (y <= high)
    x, y = x[within], y[within]
    n_cols = max(1, int(math.ceil((length - 2 * p.type_margin_m) / p.gap_column_m)))
    col = np.minimum(((x - p.type_margin_m) / p.gap_column_m).astype(np.int64), n_cols - 1)
    order = np.lexsort((y, col))
    col, y = col[order], y[order]
    counts = np.bincount(col, minlength=n_cols)
    used = np.flatnonzero(counts >= p.gap_column_points)
    if len(used) == 0:
        return 0.0
    # Each point's gap to the point below it in its column (the lowest's: to ``low``), and
    # the gap from each column's highest point up to ``high``.
    first = np.cumsum(counts) - counts
    below = np.concatenate([[low], y[:-1]])
    below[first[counts > 0]] = low
    tallest = np.zeros(n_cols)
    np.maximum.at(tallest, col, y - below)
    top = high - y[first[used] + counts[used] - 1]
    return float(np.median(np.maximum(tallest[used], top)))
