"""A pole's foot and the ground under it (§4.1: a pole's height runs from the ground).

Poles reach the ground; balusters and ladder stays stop at the lowest rail. Telling them apart
needs the ground height at each axis, measured outside the pole's own footprint, and the pole's
lowest point, followed down along road points where the road mask took in the pole's foot.

References
----------
Matsumoto, Mori, Masuda (2019), ISPRS Archives, §4.1.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.reconstruct.poles.params import PoleParams

#: The nearest ground points asked for per axis, as a multiple of ``ground_k``: enough to skip
#: those on the footprint (an axis short of ``ground_k`` after that searches its whole radius,
#: with the same result; speed only, not a threshold).
_GROUND_CANDIDATES = 4
#: Points by height are searched for the lowest near each axis in chunks of about this many
#: (memory only, not a threshold).
_CHUNK_POINTS = 2048


def grounded_bottom(z: np.ndarray, sec: np.ndarray, params: PoleParams) -> float:
    """Lowest z (metres) of a pole's inlier points ``z`` (n,) in the lowest of their sections
    ``sec`` (n,) that is followed by another occupied one at most ``base_section_gap`` empty
    sections higher (sparse poles skip a section now and then); inf when none is."""
    occupied = np.unique(sec)
    first = occupied[:-1][np.diff(occupied) <= params.base_section_gap + 1]
    if len(first) == 0:
        return float("inf")
    return float(z[sec == first[0]].min())


def ground_tree(ground: np.ndarray) -> cKDTree | None:
    """The 2D search tree of road points ``ground`` (G, 3) that :func:`foot_bottom` and
    :func:`ground_height` look points up in (None for no points): built once per run, as a run's
    ground holds up to some 1e5 points and the poles ask about it several times."""
    return cKDTree(ground[:, :2]) if len(ground) else None


def foot_bottom(
    centre: np.ndarray,
    reach: np.ndarray,
    bottom: np.ndarray,
    ground: np.ndarray,
    gap: float,
    tree: cKDTree | None = None,
) -> np.ndarray:
    """Bottoms (P,) of axes, metres, lowered along road points on their footprints.

    Parameters
    ----------
    centre : (P, 2) axes; reach : (P,) footprint radii; bottom : (P,) lowest pole points
    ground : (G, 3) road points; gap : the largest step (m) from one foot point to the next
    tree : :func:`ground_tree` of ``ground`` (None: built here)

    Starting at ``bottom``, the road points within ``reach`` of the axis, from the highest
    down, continue the pole while each lies at most ``gap`` below the previous one.
    """
    out = np.asarray(bottom, np.float64).copy()
    if len(ground) == 0 or len(centre) == 0:
        return out
    if tree is None:
        tree = cKDTree(ground[:, :2])
    for k, near in enumerate(tree.query_ball_point(centre, reach)):  # per axis (a few)
        if not np.isfinite(out[k]) or not near:
            continue
        z = np.sort(ground[near, 2])[::-1]
        z = z[z < out[k]]
        steps = -np.diff(np.concatenate([[out[k]], z]))
        reached = np.flatnonzero(np.cumsum(steps > gap) == 0)
        if len(reached):
            out[k] = z[reached[-1]]
    return out


def ground_height(
    centre: np.ndarray,
    low: np.ndarray,
    ground: np.ndarray,
    xyz: np.ndarray,
    params: PoleParams,
    tree: cKDTree | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Ground heights (P,) at each axis, metres: (for the base test, for the position).

    From the ``ground_k`` nearest ground points within ``ground_radius_m`` outside the widest
    pole's footprint (median z): both the same. Without ground points there: the base is
    tested against the lowest run or road point within ``no_ground_window_m`` (the
    neighbouring pole's base for a baluster), and the position takes the pole's own lowest
    point ``low`` (P,) (a pole reaches the ground). ``tree``: :func:`ground_tree` of
    ``ground`` (None: built here).
    """
    out = np.full(len(centre), np.nan)
    if len(ground):
        # Ground points on a footprint are a pole's foot (a sparse scanner's road mask takes
        # some in), not the ground around it: not for this pole, nor for a baluster beside it.
        foot = params.max_radius_m + params.member_margin_m
        if tree is None:
            tree = cKDTree(ground[:, :2])
        # Closer than ``foot`` to an axis: looked up from the (few) axes, not from every point.
        on_foot = np.zeros(len(ground), bool)
        for near in tree.query_ball_point(centre, np.nextafter(foot, 0.0)):
            on_foot[near] = True
        k = min(_GROUND_CANDIDATES * params.ground_k, len(ground))
        d, i = tree.query(centre, k=k, distance_upper_bound=params.ground_radius_m)
        d, i = d.reshape(len(centre), k), i.reshape(len(centre), k)
        valid = np.isfinite(d) & ~on_foot[np.minimum(i, len(ground) - 1)]
        valid &= np.cumsum(valid, axis=1) <= params.ground_k
        z = np.where(valid, ground[np.minimum(i, len(ground) - 1), 2], np.nan)
        enough = (valid.sum(axis=1) == params.ground_k) | ~np.isfinite(d[:, -1])
        has = valid.any(axis=1) & enough
        out[has] = np.nanmedian(z[has], axis=1)
        # Dense ground can fill the nearest k with footprint points: search the whole radius.
        for a in np.flatnonzero(~enough):  # rare
            near = np.asarray(tree.query_ball_point(centre[a], params.ground_radius_m), np.int64)
            near = near[~on_foot[near]]
            dist = np.linalg.norm(ground[near, :2] - centre[a], axis=1)
            if len(near):
                nearest = near[np.argsort(dist, kind="stable")[: params.ground_k]]
                out[a] = float(np.median(ground[nearest, 2]))
    position = np.where(np.isfinite(out), out, low)
    missing = np.flatnonzero(~np.isfinite(out))
    if len(missing):
        # The lowest run or road point within the window (road points there stand on a pole's
        # foot): points by height, the first within reach of each axis (chunks of the lowest
        # points first; usually one chunk does).
        xyz = np.vstack([xyz, ground]) if len(ground) else xyz
        order = np.argsort(xyz[:, 2], kind="stable")
        lowest = np.full(len(missing), np.inf)
        todo = np.arange(len(missing))
        for chunk in np.array_split(order, max(1, len(order) // _CHUNK_POINTS)):
            if len(todo) == 0:
                break
            d = np.linalg.norm(xyz[chunk, None, :2] - centre[missing[todo]][None], axis=2)
            hit = d <= params.no_ground_window_m
            found = hit.any(axis=0)
            lowest[todo[found]] = xyz[chunk[hit[:, found].argmax(axis=0)], 2]
            todo = todo[~found]
        out[missing] = np.minimum(lowest, low[missing])
    return out, position
