"""The radius and the axis of each pipe measured from its points (§4.3).

The scanner sees the +z face. Rays sample a pipe about uniformly in the offset across it, so the
signed in-plane offsets of its points from the axis are close to uniform on [-r, r] (slightly
squeezed on the far side when the scanner looks down on the pipe). The central ``radius_share``
of the offsets then spans about ``2 * radius_share * r``: the radius is that half-width divided
by the share, and the axis is the midpoint of the two quantiles (not the mean, which the
look-down angle biases toward the scanner by a few mm). A point at offset ``o`` lies
``sqrt(r**2 - o**2)`` in front of the axis, which gives the axis depth z.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.polylines import central_quantiles, left_normals, resample
from guardrail_core.reconstruct.pipes.skeleton import Skeleton


@dataclass(frozen=True)
class PipeMeasure:
    """What the points of one pipe say about it.

    Attributes
    ----------
    xy : (K, 2) float64, unit (x, y), metres: the skeleton moved onto the axis
    radius : float, metres
    z : float, metres: the axis depth (the median over the points)
    n_points : int, the points assigned to the pipe alone
    """

    xy: np.ndarray
    radius: float
    z: float
    n_points: int


def measure_pipes(pts: np.ndarray, skels: list[Skeleton], p: PipeParams) -> list[PipeMeasure]:
    """Radius, axis and depth of every pipe from the offsets of its points.

    A pipe's points are those of ``pts`` (N, 3), unit coordinates, metres, within
    ``r + assign_margin_m`` of its skeleton and not within ``r + assign_margin_m`` of another's
    (junctions and crossings count for neither). The central ``radius_share`` of their signed
    offsets gives the radius (half-width / share) and the axis (the midpoint: the skeleton is
    moved across by it), per stretch along the pipe and the median over the stretches,
    ``measure_passes`` times; each point then gives the axis depth ``z - sqrt(r**2 - o**2)``,
    and the median of these is taken.

    Returns one measure per skeleton, in order.
    """
    if not skels:
        return []
    xy = pts[:, :2]
    axes = [s.xy for s in skels]
    # First guess: the points the chain was built from.
    radius = np.zeros(len(skels))
    for i, s in enumerate(skels):
        if len(s.idx) >= p.measure_min_points:
            _, off, station = _offsets(xy[s.idx], s.xy, p)
            radius[i] = _width_and_centre(off, station, p)[0]
        else:
            radius[i] = p.assign_margin_m
    exclusive = np.zeros((len(skels), len(pts)), dtype=bool)
    for _ in range(p.measure_passes):
        exclusive, offs, stations = _assign(xy, axes, radius, p)
        for i in range(len(skels)):
            sel = exclusive[i]
            if sel.sum() < p.measure_min_points:
                continue
            radius[i], centre = _width_and_centre(offs[i, sel], stations[i, sel], p)
            axes[i] = _shifted(axes[i], centre)
    measures = []
    for i in range(len(skels)):
        sel = exclusive[i]
        n_points = int(sel.sum())
        r, z = float(radius[i]), 0.0
        if n_points:
            _, o, _ = _offsets(xy[sel], axes[i], p)
            depth = pts[sel, 2] - np.sqrt(np.clip(r**2 - o**2, 0.0, None))
            z = float(np.median(depth))
        measures.append(PipeMeasure(axes[i], r, z, n_points))
    return measures


def _assign(
    xy: np.ndarray, axes: list[np.ndarray], radius: np.ndarray, p: PipeParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points (P, N) bool of each pipe alone, and every point's offset and station (P, N)
    against every axis (metres; only those near an axis are computed)."""
    dist = np.full((len(axes), len(xy)), np.inf)
    offs = np.zeros((len(axes), len(xy)))
    stations = np.zeros((len(axes), len(xy)))
    for i, axis in enumerate(axes):
        lo = axis.min(axis=0) - radius[i] - p.assign_margin_m - p.measure_step_m
        hi = axis.max(axis=0) + radius[i] + p.assign_margin_m + p.measure_step_m
        cand = np.flatnonzero(np.all((xy >= lo) & (xy <= hi), axis=1))
        if len(cand):
            dist[i, cand], offs[i, cand], stations[i, cand] = _offsets(xy[cand], axis, p)
    inside = dist <= (radius + p.assign_margin_m)[:, None]
    exclusive = inside & (inside.sum(axis=0) == 1)[None, :]
    return exclusive, offs, stations


def _offsets(
    q: np.ndarray, xy: np.ndarray, p: PipeParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance (M,) of points ``q`` (M, 2) to the skeleton ``xy`` (K, 2), their signed offset
    across it (left +) and their station along it (M,), metres from its first vertex.

    Points whose nearest skeleton place is an end vertex beyond which they lie get an infinite
    distance (they are not beside the pipe).
    """
    v, nrm = _dense(xy, p.measure_step_m)
    dist, k = cKDTree(v).query(q, k=1)
    off = np.einsum("ij,ij->i", q - v[k], nrm[k])
    along = np.abs(np.einsum("ij,ij->i", q - v[k], nrm[k][:, ::-1] * [1.0, -1.0]))
    dist = np.where(along > p.measure_step_m, np.inf, dist)
    return dist, off, k * p.measure_step_m


def _dense(xy: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertices every ``step`` metres along a polyline and their left unit normals."""
    v = resample(xy, step)
    if len(v) < 2:
        return v, np.tile([0.0, 1.0], (len(v), 1))
    return v, left_normals(v)


def _width_and_centre(off: np.ndarray, station: np.ndarray, p: PipeParams) -> tuple[float, float]:
    """Half-width (the radius) and centre (metres) of a pipe's signed offsets ``off`` (M,) at
    ``station`` (M,) along it: the central ``radius_share`` of each ``measure_stretch_m``,
    medians over the stretches (all the offsets at once where fewer than
    ``measure_min_stretches`` stretches hold ``measure_stretch_points``)."""
    stretch = np.floor(station / p.measure_stretch_m).astype(np.int64)
    order = np.argsort(stretch, kind="stable")
    cuts = np.flatnonzero(np.diff(stretch[order])) + 1
    widths, centres = [], []
    for group in np.split(order, cuts):  # per stretch (~20 per pipe)
        if len(group) >= p.measure_stretch_points:
            lo, hi = central_quantiles(off[group], p.radius_share)
            widths.append(0.5 * (hi - lo) / p.radius_share)
            centres.append(0.5 * (lo + hi))
    if len(widths) < p.measure_min_stretches:
        lo, hi = central_quantiles(off, p.radius_share)
        return 0.5 * (hi - lo) / p.radius_share, 0.5 * (lo + hi)
    return float(np.median(widths)), float(np.median(centres))


def _shifted(xy: np.ndarray, shift: float) -> np.ndarray:
    """The polyline ``xy`` (K, 2) moved by ``shift`` metres along its left normal."""
    if len(xy) < 2 or shift == 0.0:
        return xy
    return xy + shift * left_normals(xy)
