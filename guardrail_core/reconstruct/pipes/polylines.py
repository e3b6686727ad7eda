"""Plane geometry of skeletons: polylines in unit (x, y), metres."""

from __future__ import annotations

import math

import numpy as np

from guardrail_core.reconstruct.pipes.params import PipeParams

#: Lengths (m) and squared lengths (m²) below these are zero: they guard divisions only.
TINY = 1e-12
TINY_SQUARED = 1e-18


def central_quantiles(values: np.ndarray, share: float) -> tuple[float, float]:
    """The bounds of the central ``share`` of ``values`` (N,)."""
    lo, hi = np.quantile(values, [(1.0 - share) / 2.0, (1.0 + share) / 2.0])
    return float(lo), float(hi)


def polyline_length(xy: np.ndarray) -> float:
    """Length (metres) of the polyline ``xy`` (K, 2)."""
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()) if len(xy) > 1 else 0.0


def resample(xy: np.ndarray, step: float) -> np.ndarray:
    """Vertices (M, 2) evenly along the polyline ``xy`` (K, 2), at most ``step`` metres apart."""
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if cum[-1] <= 0:
        return xy[:1].copy()
    u = np.linspace(0.0, cum[-1], max(2, int(math.ceil(cum[-1] / step)) + 1))
    return np.column_stack([np.interp(u, cum, xy[:, 0]), np.interp(u, cum, xy[:, 1])])


def fit_line(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total least squares line through ``xy`` (N, 2): (centroid (2,), unit direction (2,) with
    x >= 0)."""
    c = xy.mean(axis=0)
    _, _, vt = np.linalg.svd(xy - c, full_matrices=False)
    d = vt[0]
    if d[0] < 0 or (d[0] == 0 and d[1] < 0):
        d = -d
    return c, d


def distance_to_polyline(q: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (M,) of points ``q`` (M, 2) to the polyline ``xy`` (K, 2), and the signed offset
    (M,) (left of the polyline's direction positive)."""
    a, b = xy[:-1], xy[1:]
    ab = b - a
    L2 = np.maximum((ab**2).sum(1), TINY_SQUARED)
    t = np.clip(((q[:, None, :] - a[None]) * ab[None]).sum(-1) / L2[None], 0.0, 1.0)
    foot = a[None] + t[..., None] * ab[None]
    diff = q[:, None, :] - foot
    d2 = (diff**2).sum(-1)
    k = np.argmin(d2, axis=1)
    rows = np.arange(len(q))
    dist = np.sqrt(d2[rows, k])
    cross = ab[k, 0] * diff[rows, k, 1] - ab[k, 1] * diff[rows, k, 0]
    return dist, np.where(cross >= 0, dist, -dist)


def share_near(probe: np.ndarray, xy: np.ndarray, distance: float) -> float:
    """Share of the points ``probe`` (M, 2) within ``distance`` metres of the polyline ``xy``."""
    dist, _ = distance_to_polyline(probe, xy)
    return float(np.mean(dist <= distance))


def end_direction(xy: np.ndarray, p: PipeParams, *, end: bool) -> np.ndarray:
    """Unit direction (2,) leaving the polyline ``xy`` (K, 2) at its last (``end``) or first
    vertex: the step from the vertex ``end_direction_share`` of ``direction_window_m`` back
    (the farthest vertex, on a shorter polyline)."""
    outward = np.array([1.0, 0.0]) if end else np.array([-1.0, 0.0])
    q = xy if end else xy[::-1]
    if len(q) < 2:
        return outward
    tip = q[-1]
    d = np.linalg.norm(q - tip, axis=1)
    k = np.flatnonzero(d >= min(p.direction_window_m * p.end_direction_share, d.max()))
    base = q[k[-1]] if len(k) else q[0]
    v = tip - base
    nv = np.linalg.norm(v)
    return v / nv if nv > 0 else outward


def unit_vector(v: np.ndarray) -> np.ndarray:
    """``v`` (2,) scaled to length 1 (a zero vector stays about zero)."""
    return v / max(float(np.linalg.norm(v)), TINY)


def left_normals(xy: np.ndarray) -> np.ndarray:
    """Unit normals (K, 2) left of the polyline ``xy`` (K, 2), K >= 2, at its vertices."""
    tang = np.gradient(xy, axis=0)
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), TINY)
    return np.column_stack([-tang[:, 1], tang[:, 0]])
