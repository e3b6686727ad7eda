"""Pole detection of one run (§4.1): stacks of section clusters fitted with vertical cylinders,
measured from the ground up and accepted as poles.

The order of the steps is :func:`detect_poles`; the sections and stacks are
:mod:`~guardrail_core.reconstruct.poles.stacks`, the circles
:mod:`~guardrail_core.reconstruct.poles.circles`, the ground under a pole
:mod:`~guardrail_core.reconstruct.poles.ground`.

References
----------
Matsumoto, Mori, Masuda (2019), "Extraction and shape reconstruction of guardrails using mobile
mapping data", ISPRS Archives, §4.1, Fig. 11.
Fukano, Masuda (2015), "Detection and classification of pole-like objects from mobile mapping
data", ISPRS Annals II-3/W5.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.reconstruct.model import Pole
from guardrail_core.reconstruct.poles.circles import fit_circles, fit_shared_radius, ransac_circle
from guardrail_core.reconstruct.poles.ground import (
    foot_bottom,
    ground_height,
    ground_tree,
    grounded_bottom,
)
from guardrail_core.reconstruct.poles.params import PoleParams
from guardrail_core.reconstruct.poles.stacks import in_line, section_clusters, stack_clusters
from guardrail_core.reconstruct.runs import check_points

#: Rounds of the batched geometric fit of the points near each RANSAC circle (the refined circle
#: may take in points the first missed; a third round changes nothing).
_REFIT_ROUNDS = 2


@dataclass(frozen=True)
class PoleDetection:
    """Poles of one run.

    Attributes
    ----------
    poles : the detected poles, in order along the run (by the run's principal xy direction)
    point_is_pole : (N,) bool, run points within ``radius + member_margin_m`` of a pole's axis
    """

    poles: list[Pole]
    point_is_pole: np.ndarray


@dataclass(frozen=True)
class AxisFit:
    """The vertical cylinder fitted to one stack: ``centre`` (2,) and ``radius``, metres, and
    ``members`` (n,) int64, the indices of the run points within ``ransac_tolerance_m`` of it."""

    centre: np.ndarray
    radius: float
    members: np.ndarray


@dataclass(frozen=True)
class MeasuredAxes:
    """Fitted axes measured from the ground up (see :func:`detect_poles`).

    Attributes
    ----------
    centre : (P, 2) float64, metres; radius : (P,) float64, metres
    ground_z : (P,) float64, metres: the ground at each axis (the poles' position)
    height : (P,) float64, metres: from that ground to the highest point on the axis
    accept : (P,) bool: the axis stands on the ground, is a pole's height and not a duplicate
    member_pole : (N,) int64: the axis each run point lies on (within radius + member margin),
        -1 for none
    """

    centre: np.ndarray
    radius: np.ndarray
    ground_z: np.ndarray
    height: np.ndarray
    accept: np.ndarray
    member_pole: np.ndarray

    def on_accepted(self, accept: np.ndarray) -> np.ndarray:
        """(N,) bool: run points on an axis where ``accept`` (P,) bool."""
        return (self.member_pole >= 0) & accept[np.maximum(self.member_pole, 0)]


def detect_poles(
    xyz: np.ndarray,
    ground: np.ndarray | None = None,
    params: PoleParams = PoleParams(),
    rng: np.random.Generator | int | None = 0,
) -> PoleDetection:
    """Poles of one guardrail run.

    Parameters
    ----------
    xyz : (N, 3) float64, metres, world: the points of ONE run (rails, beams and poles)
    ground : (G, 3) float64, metres, world: ground points near the run; may be empty or None
    params : the thresholds
    rng : the RANSAC circles' random triples (a seed gives reproducible poles)

    Returns
    -------
    PoleDetection: ``poles`` (``position`` = ground point of the axis: the axis' x, y and the
    ground height there, the median of the ``ground_k`` nearest ground points within
    ``ground_radius_m``, else the pole's lowest point; ``radius``; ``height`` from that ground
    to the highest pole point; ``n_points``) in order along the run, and ``point_is_pole``.

    References
    ----------
    Matsumoto et al. 2019, §4.1, Fig. 11; Fukano & Masuda 2015.
    """
    xyz = check_points(xyz)
    ground = np.zeros((0, 3)) if ground is None else check_points(ground, "ground")
    n = len(xyz)
    none = PoleDetection([], np.zeros(n, bool))
    if n < params.min_points:
        return none

    # §4.1: horizontal sections, their clusters, and the compact ones stacked into poles.
    clusters = section_clusters(xyz, params)
    stack, stack_centre = stack_clusters(clusters, params)
    n_stack = len(stack_centre)
    if n_stack == 0:
        return none

    # Cheap rejection first: a stack whose lowest point is far above the ground is a baluster,
    # a stay or a column of beam fragments (§4.1: poles stand on the ground).
    in_stack = stack >= 0
    z_min = np.full(n_stack, np.inf)
    np.minimum.at(z_min, stack[in_stack], xyz[in_stack, 2])
    tree = ground_tree(ground)
    ground_z, _ = ground_height(stack_centre, z_min, ground, xyz, params, tree)
    reach = np.full(n_stack, params.max_radius_m + params.member_margin_m)
    z_min = foot_bottom(stack_centre, reach, z_min, ground, params.foot_gap_m, tree)
    n_pts = np.bincount(stack[in_stack], minlength=n_stack)
    maybe = (z_min - ground_z <= params.max_base_height_m) & (n_pts >= params.min_points)

    # The axis: a robust circle fit (RANSAC, then geometric least squares with outlier
    # rejection) on all the stack's points projected to xy; the scanner sees the front half.
    rng = np.random.default_rng(rng)
    order = np.argsort(stack, kind="stable")
    bounds = np.searchsorted(stack[order], np.arange(n_stack + 1))
    stack_pts = [order[bounds[k] : bounds[k + 1]] for k in np.flatnonzero(maybe)]
    judge = [
        in_line(xyz[pts, 2], clusters.cluster[pts], clusters.centroid, params) for pts in stack_pts
    ]
    section = clusters.section
    found = _fit_stacks(xyz, stack_pts, judge, section, params, rng)
    if not found:
        return none
    measured = _measure(xyz, section, ground, tree, found, params)
    if params.shared_radius and measured.accept.any():
        # Poles of one run share a design: every stack is fitted again with the radius that
        # fits the run's posts together (a delineator off their line is another design, a
        # hedge's stems between them no post), fitting only the axis (a free radius on a
        # half-seen pole trades off against the axis' offset from the road, and can take in
        # a rail).
        posts = _posts(xyz, measured, found, params)
        use = posts if posts.any() else measured.accept
        shared = fit_shared_radius(
            xyz, [(found[k].centre, found[k].members) for k in np.flatnonzero(use)], params
        )
        found = _fit_stacks(xyz, stack_pts, judge, section, params, rng, shared)
        if not found:
            return none
        measured = _measure(xyz, section, ground, tree, found, params)
    centre = measured.centre
    accept = _posts(xyz, measured, found, params)
    is_pole = measured.on_accepted(accept)
    n_member = np.bincount(measured.member_pole[is_pole], minlength=len(centre))
    poles = [
        Pole(
            position=np.array([centre[k, 0], centre[k, 1], measured.ground_z[k]]),
            radius=float(measured.radius[k]),
            height=float(measured.height[k]),
            n_points=int(n_member[k]),
        )
        for k in _along_run_order(xyz, centre, params)
        if accept[k]
    ]
    return PoleDetection(poles, is_pole)


def _fit_stacks(
    xyz: np.ndarray,
    stack_pts: list[np.ndarray],
    judge: list[np.ndarray],
    section: np.ndarray,
    params: PoleParams,
    rng: np.random.Generator,
    shared_radius: float | None = None,
) -> list[AxisFit]:
    """Axes of stacks (point indices per stack), one :class:`AxisFit` per stack that fits one.

    RANSAC per stack, drawn from its lowest part (a pole reaches the ground there, while a
    beam's fragments can join the stack higher up) and judged by its points in line with that
    part (``judge``, per stack a bool mask of its points; see ``in_line_m``), then a batched
    geometric fit of the points near each circle at every height, twice (the refined circle
    may take in points the first missed). Stacks that fit no circle, or whose inliers span
    fewer than ``min_sections`` sections, are left out. With ``shared_radius`` (m) every circle
    has that radius.
    """
    guesses = []
    for pts, by in zip(stack_pts, judge, strict=True):  # per stack
        low = xyz[pts, 2] <= xyz[pts, 2].min() + params.base_fit_height_m
        guesses.append(ransac_circle(xyz[pts, :2], low, low | by, params, rng, shared_radius))
    ok = [i for i, g in enumerate(guesses) if g is not None]
    good_guesses = [g for g in guesses if g is not None]
    if not ok:
        return []
    pts = np.concatenate([stack_pts[i] for i in ok])
    label = np.repeat(np.arange(len(ok)), [len(stack_pts[i]) for i in ok])
    centre = np.array([g[0] for g in good_guesses])
    radius = np.array([g[1] for g in good_guesses])
    xy = xyz[pts, :2]
    fixed = None if shared_radius is None else np.full(len(ok), shared_radius)
    for _ in range(_REFIT_ROUNDS):
        near = np.abs(np.linalg.norm(xy - centre[label], axis=1) - radius[label])
        near = near <= params.ransac_tolerance_m
        c, r, _, _ = fit_circles(
            xy, np.where(near, label, -1), len(ok), params, refine=True, fixed_radius=fixed
        )
        good = np.isfinite(r) & np.isfinite(c).all(axis=1)
        centre[good], radius[good] = c[good], r[good]
    resid = np.abs(np.linalg.norm(xy - centre[label], axis=1) - radius[label])
    inlier = resid <= params.ransac_tolerance_m
    out = []
    for k in range(len(ok)):  # per stack
        members = pts[inlier & (label == k)]
        if not params.min_radius_m <= radius[k] <= params.max_radius_m:
            continue
        if len(np.unique(section[members])) < params.min_sections:
            continue
        out.append(AxisFit(centre[k], float(radius[k]), members))
    return out


def _measure(
    xyz: np.ndarray,
    section: np.ndarray,
    ground: np.ndarray,
    tree: cKDTree | None,
    fits: list[AxisFit],
    params: PoleParams,
) -> MeasuredAxes:
    """Ground, height, members and acceptance of fitted axes (see :func:`detect_poles`;
    ``tree``: the ground's :func:`~guardrail_core.reconstruct.poles.ground.ground_tree`)."""
    centre = np.array([f.centre for f in fits])
    radius = np.array([f.radius for f in fits])
    # The base is the bottom of the lowest two nearly consecutive sections holding inliers: a
    # stray point below (a ground point under a baluster that happens to lie on its circle,
    # 0.15 m below the baluster's end) is not.
    z_lo = np.array([grounded_bottom(xyz[f.members, 2], section[f.members], params) for f in fits])
    z_hi = np.array([xyz[f.members, 2].max() for f in fits])
    # Members: run points within radius + margin of an axis (every height); the highest one
    # is the pole's top.
    member_pole, _ = _nearest_axis(xyz[:, :2], centre, radius + params.member_margin_m)
    has = member_pole >= 0
    top = np.full(len(fits), -np.inf)
    low = np.full(len(fits), np.inf)
    np.maximum.at(top, member_pole[has], xyz[has, 2])
    np.minimum.at(low, member_pole[has], xyz[has, 2])
    top, low = np.maximum(top, z_hi), np.minimum(low, z_lo)
    # §4.1: the height of the pole is determined using the ground and the highest point.
    reach = radius + params.member_margin_m
    foot = foot_bottom(centre, reach, z_lo, ground, params.foot_gap_m, tree)
    base_ref, ground_z = ground_height(centre, np.minimum(low, foot), ground, xyz, params, tree)
    height = top - ground_z
    extent_share = (z_hi - z_lo) / np.maximum(height, 1e-9)  # 1e-9: no division by zero
    accept = (
        (foot - base_ref <= params.max_base_height_m)  # a pole stands on the ground
        & (height >= params.min_height_m)
        & (height <= params.max_height_m)
        & (extent_share >= params.min_extent_share)
    )
    # Two accepted axes closer than merge_distance_m are one pole: the one with more inlier
    # points stays.
    inliers = np.array([len(f.members) for f in fits])
    accept &= _suppress_close(centre, inliers, accept, params.merge_distance_m)
    return MeasuredAxes(centre, radius, ground_z, height, accept, member_pole)


def _posts(
    xyz: np.ndarray, measured: MeasuredAxes, fits: list[AxisFit], params: PoleParams
) -> np.ndarray:
    """(P,) bool: the accepted axes that are the run's posts.

    Posts stand metres apart, so of two accepted axes closer than ``min_spacing_m`` (a hedge's
    stems behind the rails, some 0.2 m apart, fit a post's circle too) the one with more
    points on its circle stays. The axes left so give the run's line (a hedge's stems, many
    more than the posts, would otherwise make it theirs), and every accepted axis off that
    line is left out (:func:`_consistent_offsets`) before the spacing is applied to the rest.
    """
    accept = measured.accept
    inliers = np.array([len(f.members) for f in fits])
    spaced = accept & _suppress_close(measured.centre, inliers, accept, params.min_spacing_m)
    on_pole = measured.on_accepted(accept)
    on_line = accept & _consistent_offsets(
        xyz[:, :2], on_pole, measured.centre, accept, params, reference=spaced
    )
    return on_line & _suppress_close(measured.centre, inliers, on_line, params.min_spacing_m)


def _nearest_axis(
    xy: np.ndarray, centre: np.ndarray, reach: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """For each point (N, 2): the nearest axis within its reach (P,), -1 if none; distance."""
    if len(centre) == 0:
        return np.full(len(xy), -1, np.int64), np.full(len(xy), np.inf)
    k = min(2, len(centre))
    d, i = cKDTree(centre).query(xy, k=k, distance_upper_bound=float(reach.max()))
    d, i = d.reshape(len(xy), k)[:, 0], i.reshape(len(xy), k)[:, 0]
    inside = np.isfinite(d)
    inside[inside] = d[inside] <= reach[i[inside]]
    return np.where(inside, i, -1), d


def _suppress_close(
    centre: np.ndarray, n_points: np.ndarray, accept: np.ndarray, distance_m: float
) -> np.ndarray:
    """(P,) bool: False for an accepted axis within ``distance_m`` of one with more points
    (``n_points`` (P,)); of axes equally strong, the first stays."""
    keep = np.ones(len(centre), bool)
    idx = np.flatnonzero(accept)
    pairs = cKDTree(centre[idx]).query_pairs(distance_m, output_type="ndarray")
    for a, b in pairs:  # per pair of axes too close (a few; dozens in a hedge)
        weaker = idx[a] if n_points[idx[a]] < n_points[idx[b]] else idx[b]
        keep[weaker] = False
    return keep


def _consistent_offsets(
    xy: np.ndarray,
    is_pole: np.ndarray,
    centre: np.ndarray,
    accept: np.ndarray,
    params: PoleParams,
    reference: np.ndarray,
) -> np.ndarray:
    """(P,) bool: False for an accepted axis that stands off the line of the run's poles.

    Each pole's offset is the median signed distance of the rail points (not pole points)
    within ``offset_window_m`` of its axis from the axis, across their principal direction
    (oriented along the run's, so the sign means the same side for every pole). The line is
    the median offset of the ``reference`` poles (P,) bool (some of the accepted ones). With
    fewer than ``offset_min_poles`` of them, or fewer than ``offset_min_points`` rail points
    near a pole, nothing is rejected; nor when most of them stand off their own median: the
    offsets then say no line, and rejecting every pole off the median would reject them all.
    """
    keep = np.ones(len(centre), bool)
    idx = np.flatnonzero(accept)
    rails = xy[~is_pole]
    if len(idx) < params.offset_min_poles or len(rails) < params.offset_min_points:
        return keep
    sub = rails[:: max(1, len(rails) // params.direction_points)]
    _, _, vt = np.linalg.svd(sub - sub.mean(axis=0), full_matrices=False)
    run_dir = vt[0]
    tree = cKDTree(rails)
    offset = np.full(len(idx), np.nan)
    for j, k in enumerate(idx):  # per pole (a few per run; dozens where a hedge stands)
        near = rails[tree.query_ball_point(centre[k], params.offset_window_m)]
        if len(near) < params.offset_min_points:
            continue
        _, _, v = np.linalg.svd(near - near.mean(axis=0), full_matrices=False)
        along = v[0] if v[0] @ run_dir >= 0 else -v[0]
        across = np.array([-along[1], along[0]])
        offset[j] = float(np.median((near - centre[k]) @ across))
    known = np.isfinite(offset)
    line = known & reference[idx]
    if line.sum() < params.offset_min_poles:
        return keep
    line_offset = np.median(offset[line])
    if 2 * (np.abs(offset[line] - line_offset) > params.max_offset_deviation_m).sum() >= line.sum():
        return keep
    keep[idx[known & (np.abs(offset - line_offset) > params.max_offset_deviation_m)]] = False
    return keep


def _along_run_order(xyz: np.ndarray, centre: np.ndarray, params: PoleParams) -> np.ndarray:
    """Indices of ``centre`` (P, 2) sorted along the run's principal xy direction."""
    xy = xyz[:, :2] - xyz[:, :2].mean(axis=0)
    _, _, vt = np.linalg.svd(xy[:: max(1, len(xy) // params.direction_points)], full_matrices=False)
    return np.argsort(centre @ vt[0], kind="stable")
