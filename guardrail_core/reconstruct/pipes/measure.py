"""The radius and the axis of each pipe measured from its points (§4.3).

The scanner sees the +z face. Rays sample a pipe about uniformly across their own direction,
so a pipe seen square on has its points' signed in-plane offsets from the axis about uniform on
[-r, r]: the central ``radius_share`` of them spans ``2 * radius_share * r``. A pipe the scanner
looks down on at an angle ``a`` (a rail 0.2 m above the ground, 2 m from a scanner 2 m up: 45
degrees) shows its upper side and hides its lower edge: a ray at ``t`` on [-r, r] meets it at
the offset ``r sin(asin(t / r) + a)``, so the offsets reach only about ``-r cos a`` below the
axis and crowd toward ``+r``. Where the median stands between the bounds of the central share
depends on ``a`` alone, which gives the angle; the bounds' span, divided by that of a pipe of
radius 1 seen at that angle, gives the radius, and the lower bound the axis. Square on this is
the half-width over the share and the midpoint, as before; taking the span alone made rails
looked down on 3-5 mm thin and set their axis up to 5 mm high. A point at offset ``o`` lies
``sqrt(r**2 - o**2)`` in front of the axis, which gives the axis depth z.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.polylines import left_normals, resample
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
    (junctions and crossings count for neither); ``r`` is first guessed from the points the
    chain was built from (:func:`_first_guess`). Their signed offsets give the radius and the
    axis (:func:`radius_and_axis`; the skeleton is moved across onto the axis), per stretch
    along the pipe and the median over the stretches,
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
        radius[i], centre = _first_guess(xy[s.idx], s.xy, p)
        axes[i] = _shifted(axes[i], centre)
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


def _first_guess(q: np.ndarray, xy: np.ndarray, p: PipeParams) -> tuple[float, float]:
    """A radius and an axis (metres across the chain) to start from, of the points ``q``
    (M, 2) a chain ``xy`` (K, 2) was built from: twice their median absolute offset (offsets
    uniform on [-r, r] have r / 2) and their median offset.

    A chain's slices may hold a few points of a pipe that joins it (an arch's king post at its
    crown, a rail at its foot), 0.1 m and more off it: the bounds of the central
    ``radius_share``, measured later, follow such a tail, and a first guess of 0.17 m for a
    14 mm arch then took the points of every pipe near it and moved its axis 5 cm off.
    """
    if len(q) < p.measure_min_points:
        return p.assign_margin_m, 0.0
    _, off, _ = _offsets(q, xy, p)
    centre = float(np.median(off))
    return float(2.0 * np.median(np.abs(off - centre))), centre


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
    """Radius and axis (metres) of a pipe from its signed offsets ``off`` (M,) at ``station``
    (M,) along it: :func:`radius_and_axis` of each ``measure_stretch_m``, medians over the
    stretches (all the offsets at once where fewer than ``measure_min_stretches`` stretches
    hold ``measure_stretch_points``)."""
    stretch = np.floor(station / p.measure_stretch_m).astype(np.int64)
    order = np.argsort(stretch, kind="stable")
    cuts = np.flatnonzero(np.diff(stretch[order])) + 1
    widths, centres = [], []
    for group in np.split(order, cuts):  # per stretch (~20 per pipe)
        if len(group) >= p.measure_stretch_points:
            width, centre = radius_and_axis(off[group], p.radius_share)
            widths.append(width)
            centres.append(centre)
    if len(widths) < p.measure_min_stretches:
        return radius_and_axis(off, p.radius_share)
    return float(np.median(widths)), float(np.median(centres))


def radius_and_axis(off: np.ndarray, share: float) -> tuple[float, float]:
    """Radius and axis (metres) of a pipe from its points' signed offsets ``off`` (M,) across
    it, seen square on or looked down on at up to :data:`MAX_LOOK_DOWN_DEG` (the module's
    notes): where the median stands between the bounds of the central ``share`` tells the
    angle, and the span of those bounds then the radius."""
    lo, median, hi = np.quantile(off, [(1.0 - share) / 2.0, 0.5, (1.0 + share) / 2.0])
    if hi <= lo:
        return 0.0, float(median)
    sign = 1.0
    if median - lo < hi - median:  # the visible side lies toward -offset: measure it mirrored
        sign, lo, median, hi = -1.0, -hi, -median, -lo
    rho, span, low = _look_down_table(share)
    at = (median - lo) / (hi - lo)
    r = (hi - lo) / np.interp(at, rho, span)
    return float(r), float(sign * (lo - r * np.interp(at, rho, low)))


#: Look-down angles beyond this (degrees) are taken as this one: beyond some 70 degrees where
#: the median stands no longer tells the angle (the crowded top folds back over itself).
MAX_LOOK_DOWN_DEG = 65.0


@functools.cache
def _look_down_table(share: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For look-down angles 0 .. :data:`MAX_LOOK_DOWN_DEG` (0.25 degree steps), the offsets of
    a pipe of radius 1 about its axis: where the median stands between the central ``share``'s
    bounds (0.5 square on, rising with the angle), their span and the lower bound (each (A,))."""
    t = np.linspace(-1.0, 1.0, 8001)  # rays uniform across their direction
    rho, span, low = [], [], []
    for angle in np.radians(np.arange(0.0, MAX_LOOK_DOWN_DEG + 0.125, 0.25)):
        offsets = np.sin(np.arcsin(t) + angle)
        lo, median, hi = np.quantile(offsets, [(1.0 - share) / 2.0, 0.5, (1.0 + share) / 2.0])
        rho.append((median - lo) / (hi - lo))
        span.append(hi - lo)
        low.append(lo)
    return np.array(rho), np.array(span), np.array(low)


def _shifted(xy: np.ndarray, shift: float) -> np.ndarray:
    """The polyline ``xy`` (K, 2) moved by ``shift`` metres along its left normal."""
    if len(xy) < 2 or shift == 0.0:
        return xy
    return xy + shift * left_normals(xy)
