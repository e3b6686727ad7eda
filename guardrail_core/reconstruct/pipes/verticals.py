"""Vertical pipes at the peaks of the x histogram (Matsumoto et al. 2019, §4.3, Fig. 14, 15).

A contiguous region of the histogram above its threshold is a candidate; the diameter is the
width holding ``radius_share`` of its points, the skeleton sits at the centre of that width and
spans the points' height.
"""

from __future__ import annotations

import math

import numpy as np

from guardrail_core.reconstruct.pipes.histogram import PipeHistogram, regions_above
from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.polylines import central_quantiles
from guardrail_core.reconstruct.pipes.skeleton import Skeleton


def vertical_pipes(
    pts: np.ndarray, histogram: PipeHistogram, p: PipeParams
) -> tuple[list[Skeleton], np.ndarray]:
    """Vertical pipes from the regions of the x histogram above its threshold.

    Parameters
    ----------
    pts : (N, 3) float64, unit coordinates, metres: the points between the poles
    histogram : their x histogram

    Returns
    -------
    The vertical skeletons (``idx`` into ``pts``) and a mask (N,) of their points.
    """
    starts, stops = regions_above(histogram.counts, histogram.threshold)
    edges = histogram.edges
    removed = np.zeros(len(pts), dtype=bool)
    skels: list[Skeleton] = []
    x, y = pts[:, 0], pts[:, 1]
    for a, b in zip(starts, stops, strict=True):
        found = _fit_region(x, y, edges[a], edges[b], removed, p)
        if found is None:
            continue
        sel, centre, radius = found
        y0, y1 = longest_chain(y[sel], p.vertical_sparse_gap_m)
        # A short one ends on pipes running across; the steep foot of an arch goes on aside.
        if y1 - y0 < p.short_vertical_factor * p.vertical_min_length_m and not all(
            crossed(pts, centre, end, radius, p) for end in (y0, y1)
        ):
            continue
        band = sel & (y >= y0) & (y <= y1)
        removed |= band
        xy = np.array([[centre, y0], [centre, y1]])
        skels.append(Skeleton(xy=xy, kind="vertical", idx=np.flatnonzero(band)))
    return skels, removed


def _fit_region(
    x: np.ndarray, y: np.ndarray, lo: float, hi: float, removed: np.ndarray, p: PipeParams
) -> tuple[np.ndarray, float, float] | None:
    """The points (mask), axis x and radius of the vertical pipe in the histogram region
    [lo, hi) metres, or None where its points are too few, too short or lean.

    A thin pipe is hit once per scan line: where every unit of a run was scanned at the same
    heights its points stand in streaks ``vertical_sparse_gap_m`` apart. That wider gap is tried
    only where ``vertical_gap_m`` finds nothing (its inner points, a gap in from either end,
    leave none on a 0.15 m king post).
    """
    tan_tol = math.tan(math.radians(p.vertical_angle_deg))
    for gap in (p.vertical_gap_m, p.vertical_sparse_gap_m):
        found = None
        centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo) + p.histogram_bin_m
        for _ in range(p.window_passes):  # the window follows the estimated pipe width
            found = None
            sel = (np.abs(x - centre) <= half) & ~removed  # a pipe split in two regions
            if sel.sum() < p.min_points:
                break
            y0, y1 = longest_chain(y[sel], gap)
            if y1 - y0 < p.vertical_min_length_m:
                break
            inner = sel & (y > y0 + gap) & (y < y1 - gap)
            inner &= ~_horizontal_bands(y, inner, p)
            if inner.sum() < p.min_points:
                break
            # A vertical pipe stands straight: x does not drift with y.
            slope = np.polyfit(y[inner], x[inner], 1)[0]
            if abs(slope) > tan_tol:
                break
            qlo, qhi = central_quantiles(x[inner], p.radius_share)
            centre = 0.5 * (qlo + qhi)
            radius = 0.5 * (qhi - qlo) / p.radius_share
            half = radius + p.assign_margin_m
            found = (sel, centre, radius)
        if found is not None:
            return found
    return None


def longest_chain(y: np.ndarray, gap: float) -> tuple[float, float]:
    """The extent (metres) of the longest run of ``y`` (N,), N >= 1, without a gap above ``gap``."""
    ys = np.sort(y)
    breaks = np.flatnonzero(np.diff(ys) > gap)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(ys) - 1]])
    k = int(np.argmax(ys[ends] - ys[starts]))
    return float(ys[starts[k]]), float(ys[ends[k]])


def crossed(
    pts: np.ndarray,
    x: float,
    y: float,
    radius: float,
    p: PipeParams,
    reach: float | None = None,
) -> bool:
    """Whether a pipe runs across the end (x, y) of a vertical pipe of ``radius`` (metres): at
    least ``crossing_min_points`` of ``pts`` (N, 3) on either side, within ``slice_interval_m``
    in y and from ``short_window_m`` beyond the radius to ``reach`` beyond it in x (metres;
    by default ``crossing_reach`` times ``short_window_m``)."""
    if reach is None:
        reach = p.crossing_reach * p.short_window_m
    near = np.abs(pts[:, 1] - y) <= p.slice_interval_m
    dx = pts[near, 0] - x
    lo, hi = radius + p.short_window_m, radius + reach
    left = int(((dx <= -lo) & (dx >= -hi)).sum())
    right = int(((dx >= lo) & (dx <= hi)).sum())
    return min(left, right) >= p.crossing_min_points


def _horizontal_bands(y: np.ndarray, sel: np.ndarray, p: PipeParams) -> np.ndarray:
    """Mask (N,) of the points of ``sel`` in ``slice_interval_m`` bands of y holding more than
    ``histogram_factor`` times the median of the filled bands (horizontal pipes crossing)."""
    ys = y[sel]
    out = np.zeros(len(y), dtype=bool)
    if len(ys) == 0:
        return out
    b = np.floor((y - ys.min()) / p.slice_interval_m).astype(np.int64)
    cnt = np.bincount(b[sel])
    dense = cnt > p.histogram_factor * np.median(cnt[cnt > 0])  # a median of at least 1
    out[sel] = dense[b[sel]]
    return out
