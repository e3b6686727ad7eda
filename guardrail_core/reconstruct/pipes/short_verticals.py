"""Short vertical pipes between two pipes that run across them (an arch's king post, §4.3).

In the x histogram of all points a 0.15 m vertical barely rises above the rails; once the
straight pipes' points are out, it stands out in the histogram of the rest. It is one where
pipes run across both its ends: points on either side (:func:`crossed`, looked for as far
as one scan line's streak from the next), or a straight pipe found before it.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.reconstruct.pipes.histogram import bin_of, regions_above
from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.polylines import central_quantiles
from guardrail_core.reconstruct.pipes.skeleton import Skeleton
from guardrail_core.reconstruct.pipes.verticals import crossed, longest_chain


def short_verticals(
    pts: np.ndarray,
    rest_idx: np.ndarray,
    lines: list[Skeleton],
    edges: np.ndarray,
    p: PipeParams,
) -> tuple[list[Skeleton], np.ndarray]:
    """Short vertical pipes among the points ``rest_idx`` off the straight pipes ``lines``.

    The histogram of those points (bins ``edges``, (B + 1,) metres) is summed over
    ``short_window_m`` (the points are few) and its threshold is ``histogram_factor`` times its
    median over the filled bins (the level of the curved pipes); windows whose points stand
    tall are candidates too (:func:`_tall_windows`). A candidate is a short vertical
    when its points stand within ``short_drift_m`` of one x over at least
    ``vertical_min_length_m`` and pipes run across both its ends. The foot of an arch, as steep,
    fails that: at its top the arch goes on to one side only.

    Parameters
    ----------
    pts : (N, 3) float64, unit coordinates, metres: the points between the poles
    rest_idx : (M,) int64, indices into ``pts`` of the points left to search

    Returns
    -------
    The vertical skeletons (``idx`` into ``pts``) and a mask (M,) over ``rest_idx`` of their
    points.
    """
    mask = np.zeros(len(rest_idx), dtype=bool)
    on_line = np.zeros(len(pts), dtype=bool)
    for line in lines:
        on_line[line.idx] = True
    keep = ~on_line[rest_idx]
    off = rest_idx[keep]
    if len(off) < p.min_points:
        return [], mask
    n_bins = len(edges) - 1
    width = max(1, int(round(p.short_window_m / p.histogram_bin_m)))
    counts = np.convolve(
        np.bincount(bin_of(pts[off, 0], edges, p), minlength=n_bins), np.ones(width), mode="same"
    )
    threshold = max(
        p.histogram_factor * float(np.median(counts[counts > 0])), p.histogram_min_count
    )
    x, y = pts[off, 0], pts[off, 1]
    tall = _tall_windows(x, y, edges, width, p)
    starts, stops = regions_above(np.where(tall, np.inf, counts), threshold)
    skels: list[Skeleton] = []
    taken = np.zeros(len(off), dtype=bool)
    for a, b in zip(starts, stops, strict=True):
        centre = 0.5 * (edges[a] + edges[b])
        # The region holds the bins above the threshold, which may be off the pipe's centre:
        # the first window reaches a pipe's width beyond it.
        half = 0.5 * (edges[b] - edges[a]) + p.short_window_m
        found = None
        for _ in range(p.window_passes):  # the window follows the estimated pipe width
            sel = (np.abs(x - centre) <= half) & ~taken
            if sel.sum() < p.min_points:
                break
            y0, y1 = longest_chain(y[sel], p.vertical_gap_m)
            inner = sel & (y > y0 + p.slice_interval_m) & (y < y1 - p.slice_interval_m)
            if y1 - y0 < p.vertical_min_length_m or inner.sum() < p.short_min_inner_points:
                break
            qlo, qhi = central_quantiles(x[inner], p.radius_share)
            centre, radius = 0.5 * (qlo + qhi), 0.5 * (qhi - qlo) / p.radius_share
            half = radius + p.assign_margin_m
            found = (y0, y1, radius, _drift(x[inner], y[inner]))
        if found is None:
            continue
        y0, y1, radius, drift = found
        # The points of a pipe across an end come in streaks along x, one per scan line, as
        # far apart as vertical_sparse_gap_m where every unit was scanned at the same places:
        # an arch's crown under a king post may have none within crossing_reach, and, unlike
        # a rail, no straight line to stand for it.
        if drift > p.short_drift_m or not all(
            crossed(pts, centre, end, radius, p, reach=p.vertical_sparse_gap_m)
            or _line_across(lines, centre, end, p)
            for end in (y0, y1)
        ):
            continue
        band = (np.abs(x - centre) <= half) & (y >= y0) & (y <= y1) & ~taken
        taken |= band
        xy = np.array([[centre, y0], [centre, y1]])
        skels.append(Skeleton(xy=xy, kind="vertical", idx=off[band]))
    mask[np.flatnonzero(keep)[taken]] = True
    return skels, mask


def _tall_windows(
    x: np.ndarray, y: np.ndarray, edges: np.ndarray, width: int, p: PipeParams
) -> np.ndarray:
    """Mask (B,) of the bins whose window of ``width`` bins holds ``min_points`` or more points
    (x, y) standing ``vertical_min_length_m`` tall without a gap over ``vertical_gap_m``.

    Where an arch's crown passes under a king post, its points lift the histogram all around
    the post, and the post of a sparse run (the far side, a few units) stays under the
    threshold; standing tall in its window, it is a candidate still. An arch's feet stand tall
    too, and fail as before (their drift, or no pipe across their top on both sides).
    """
    n_bins = len(edges) - 1
    tall = np.zeros(n_bins, dtype=bool)
    order = np.argsort(x, kind="stable")
    xs, ys = x[order], y[order]
    half = 0.5 * width * (edges[1] - edges[0])
    centres = 0.5 * (edges[:-1] + edges[1:])
    lo = np.searchsorted(xs, centres - half)
    hi = np.searchsorted(xs, centres + half, side="right")
    for k in np.flatnonzero(hi - lo >= p.min_points):
        y0, y1 = longest_chain(ys[lo[k] : hi[k]], p.vertical_gap_m)
        tall[k] = y1 - y0 >= p.vertical_min_length_m
    return tall


def _drift(x: np.ndarray, y: np.ndarray) -> float:
    """Metres: how far the points (x, y) of a vertical candidate move in x from the lowest third
    of them to the highest (their medians). Measured, not extrapolated: the rails' and the
    arch's bands take the ends of a king post, and a line fitted to the few centimetres left
    between them, 1-2 cm wide with the units' misregistration, tilts at random."""
    order = np.argsort(y, kind="stable")
    third = max(1, len(order) // 3)
    return float(abs(np.median(x[order[-third:]]) - np.median(x[order[:third]])))


def _line_across(lines: list[Skeleton], x: float, y: float, p: PipeParams) -> bool:
    """Whether a straight pipe of ``lines`` runs across the end (x, y) of a short vertical
    (metres): it spans x (and ``short_window_m`` either side) and its axis passes within
    ``slice_interval_m`` plus its band's half-width ``line_band_m`` of y there. The points of
    a rail across a king post's top come in clumps along x (the scan lines), and a clump may
    miss the few centimetres beside the post that :func:`crossed` counts on."""
    for line in lines:
        (x0, y0), (x1, y1) = line.xy[0], line.xy[-1]
        lo, hi = min(x0, x1), max(x0, x1)
        if hi - lo <= 0 or not lo + p.short_window_m <= x <= hi - p.short_window_m:
            continue
        y_at = y0 + (y1 - y0) * (x - x0) / (x1 - x0)
        if abs(y_at - y) <= p.slice_interval_m + p.line_band_m:
            return True
    return False
