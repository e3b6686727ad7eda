"""Straight non-vertical pipes by a sequential random line search (§4.3).

Line hypotheses through random pairs of points are scored by the points within ``line_band_m``;
the best is refitted to its band, cut to its longest gap-free run and kept when that run is
long, populated and straight (a curved pipe fails this). The kept line's points are removed and
the search starts again, most points first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.polylines import central_quantiles, fit_line
from guardrail_core.reconstruct.pipes.skeleton import Chain, PipeKind, Skeleton

#: Hypotheses through two points this close in x (metres) are vertical: no straight pipe here.
_VERTICAL_DX = 1e-6
#: The standard error of a median is about 1.25 standard deviations / sqrt(n) (sqrt(pi / 2)).
_MEDIAN_SE = 1.25


@dataclass(frozen=True)
class _Line:
    """A straight pipe's line: a point ``c`` (2,) and unit direction ``u`` (2,) in unit (x, y),
    its run from ``t0`` to ``t1`` metres along ``u`` and the half-width of its band."""

    c: np.ndarray
    u: np.ndarray
    t0: float
    t1: float
    half: float


def straight_pipes(
    pts: np.ndarray, rest_idx: np.ndarray, p: PipeParams, rng: np.random.Generator
) -> tuple[list[Skeleton], np.ndarray]:
    """Straight non-vertical pipes among the points ``rest_idx``, found one after another.

    Parameters
    ----------
    pts : (N, 3) float64, unit coordinates, metres: the points between the poles
    rest_idx : (M,) int64, indices into ``pts`` of the points off the vertical pipes
    rng : draws the samples and the hypotheses

    Returns
    -------
    The straight skeletons (``idx`` into ``pts``; horizontal ones exactly so) and a mask (M,)
    over ``rest_idx`` of the points the slices no longer see: a diagonal's band, and a
    horizontal rail's band but its core (the chains that touch a rail tangentially need it).
    """
    removed = np.zeros(len(rest_idx), dtype=bool)
    hidden = np.zeros(len(rest_idx), dtype=bool)
    skels: list[Skeleton] = []
    if len(rest_idx) < p.min_points:
        return skels, hidden
    xy = pts[rest_idx, :2]
    failed: list[tuple[np.ndarray, np.ndarray]] = []
    for _ in range(p.line_searches):
        live = np.flatnonzero(~removed)
        if len(live) < p.min_points:
            break
        line = _search(xy, live, failed, p, rng)
        if line is None:
            break
        nrm = np.array([-line.u[1], line.u[0]])
        rel = xy - line.c
        t_all, o_all = rel @ line.u, rel @ nrm
        angle = math.degrees(math.atan2(abs(line.u[1]), abs(line.u[0])))
        kind: PipeKind = "horizontal" if angle <= p.horizontal_angle_deg else "diagonal"
        half = line.half
        band = (np.abs(o_all) <= half) & (t_all >= line.t0 - half) & (t_all <= line.t1 + half)
        idx = rest_idx[band & ~removed]
        removed |= band
        core = np.abs(o_all) <= p.rail_core_share * half
        hidden |= band if kind == "diagonal" else band & ~core
        end = line.c + np.outer([line.t0, line.t1], line.u)
        if end[0, 0] > end[1, 0]:
            end = end[::-1]
        if kind == "horizontal":
            end[:, 1] = end[:, 1].mean()
        chain = Chain(centres=end.copy(), shared=np.zeros(2, bool), own=idx)
        skels.append(Skeleton(xy=end, kind=kind, idx=idx, chain=chain))
    return skels, hidden


def _search(
    xy: np.ndarray,
    live: np.ndarray,
    failed: list[tuple[np.ndarray, np.ndarray]],
    p: PipeParams,
    rng: np.random.Generator,
) -> _Line | None:
    """One search among the ``live`` points of ``xy`` (M, 2): the first of the best-scored
    hypotheses that refines to a straight pipe, or None. Hypotheses that failed (``failed``,
    (point, direction) pairs, grown here) are not refined again."""
    sub = live if len(live) <= p.line_sample else rng.choice(live, p.line_sample, replace=False)
    a = xy[rng.choice(sub, p.line_hypotheses)]
    b = xy[rng.choice(sub, p.line_hypotheses)]
    d = b - a
    n = np.linalg.norm(d, axis=1)
    ok = (n >= p.line_chunk_m) & (np.abs(d[:, 0]) > _VERTICAL_DX)
    if not ok.any():
        return None
    a, d = a[ok], d[ok] / n[ok, None]
    normal = np.column_stack([-d[:, 1], d[:, 0]])
    off = np.abs(
        (xy[sub, 0][None, :] - a[:, :1]) * normal[:, :1]
        + (xy[sub, 1][None, :] - a[:, 1:]) * normal[:, 1:]
    )
    score = (off <= p.line_band_m).sum(axis=1)
    for h in np.argsort(-score)[: p.line_candidates]:
        if score[h] < p.min_points:
            return None
        c, u = a[h], d[h]
        if any(
            abs(u[0] * fu[1] - u[1] * fu[0]) < p.line_same_sin
            and abs((c - fc) @ [-fu[1], fu[0]]) < p.line_band_m
            for fc, fu in failed
        ):
            continue
        line = _refine_line(xy, live, c, u, p)
        if line is not None:
            return line
        failed.append((c, u))
    return None


def _refine_line(
    xy: np.ndarray, live: np.ndarray, c: np.ndarray, u: np.ndarray, p: PipeParams
) -> _Line | None:
    """Refit the hypothesis (point ``c``, direction ``u``) to its band's points among the
    ``live`` points of ``xy`` (M, 2); its run, or None when it is no straight pipe.

    Straightness is judged on the refitted line only: a hypothesis through two points a few
    centimetres apart leans by several degrees, and its band's offsets drift along it."""
    for _ in range(p.line_refits):
        nrm = np.array([-u[1], u[0]])
        rel = xy[live] - c
        o = rel @ nrm
        inb = np.abs(o) <= p.line_band_m
        if inb.sum() < p.min_points:
            return None
        run = _line_run(rel[inb] @ u, o[inb], p, straight=False)
        if run is None:
            return None
        q = xy[live][inb][run[2]]
        c, u = fit_line(q)
    nrm = np.array([-u[1], u[0]])
    rel = xy[live] - c
    o = rel @ nrm
    inb = np.abs(o) <= p.line_band_m
    run = _line_run(rel[inb] @ u, o[inb], p)
    if run is None:
        return None
    t0, t1, sel = run
    lo, hi = central_quantiles(o[inb][sel], p.radius_share)
    radius = max(0.5 * (hi - lo) / p.radius_share, p.line_min_radius_m)
    half = min(radius + p.assign_margin_m, p.line_band_growth * p.line_band_m)
    return _Line(c + 0.5 * (lo + hi) * nrm, u, t0, t1, half)


def _line_run(
    t: np.ndarray, off: np.ndarray, p: PipeParams, *, straight: bool = True
) -> tuple[float, float, np.ndarray] | None:
    """The longest gap-free run of the projections ``t`` (N,) metres, when it is a straight
    pipe: at least ``line_min_length_m`` long and ``min_points`` strong, its ``line_chunk_m``
    pieces populated (``line_occupancy``) and, with ``straight``, the median offsets ``off``
    (N,) of its pieces on one line. Returns (t0, t1, mask (N,) of the run) or None."""
    if len(t) < p.min_points:
        return None
    order = np.argsort(t)
    ts = t[order]
    breaks = np.flatnonzero(np.diff(ts) > p.link_gap_m)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(ts) - 1]])
    k = int(np.argmax(ends - starts))
    t0, t1 = float(ts[starts[k]]), float(ts[ends[k]])
    if t1 - t0 < p.line_min_length_m or ends[k] - starts[k] + 1 < p.min_points:
        return None
    sel = (t >= t0) & (t <= t1)
    n_chunks = max(2, int(round((t1 - t0) / p.line_chunk_m)))  # two pieces at least to compare
    chunk = np.minimum(((t[sel] - t0) / (t1 - t0) * n_chunks).astype(np.int64), n_chunks - 1)
    cnt = np.bincount(chunk, minlength=n_chunks)
    if np.mean(cnt >= p.line_piece_min_points) < p.line_occupancy:
        return None
    if straight and _bent(off[sel], chunk, cnt, p):
        return None
    return t0, t1, sel


def _bent(o: np.ndarray, chunk: np.ndarray, cnt: np.ndarray, p: PipeParams) -> bool:
    """Whether more than ``line_bent_share`` of the full pieces have their median offset off
    the run's: by more than ``line_straightness_m`` and by more than ``line_straightness_se``
    of its standard errors (a sparse rail's few points scatter).

    ``o`` (N,) offsets, ``chunk`` (N,) their piece, ``cnt`` (P,) points per piece."""
    n_chunks = len(cnt)
    med = float(np.median(o))
    full = cnt >= p.line_piece_full_points
    by_piece = np.lexsort((o, chunk))
    first = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    sorted_o = o[by_piece]
    last = len(o) - 1  # empty pieces index anywhere; only full pieces are read
    lower = np.clip(first + (cnt - 1) // 2, 0, last)
    upper = np.clip(first + cnt // 2, 0, last)
    piece_median = 0.5 * (sorted_o[lower] + sorted_o[upper])
    mean = np.bincount(chunk, o, n_chunks) / np.maximum(cnt, 1)
    var = np.bincount(chunk, o * o, n_chunks) / np.maximum(cnt, 1) - mean**2
    se = _MEDIAN_SE * np.sqrt(np.maximum(var, 0.0) / np.maximum(cnt, 1))
    off_line = np.abs(piece_median - med) > np.maximum(
        p.line_straightness_m, p.line_straightness_se * se
    )
    return bool((off_line & full).sum() > p.line_bent_share * full.sum())
