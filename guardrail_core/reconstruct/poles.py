"""Pole detection (§4.1): vertical cylinders found in horizontal sections of a guardrail run.

Following Fukano & Masuda (2015) as the paper describes it (Fig. 11): the run's points are cut by
horizontal section planes; in each section the points fall into clusters along the run; compact
clusters (a pole's cross-section, not a rail) get a circle by algebraic least squares with
iterative outlier rejection; circles that are vertically aligned are joined into a vertical
cylinder, and the pole's height runs from the ground to its highest point.

What tells a pole from the other vertical things of a guardrail:

- a pole reaches the ground; balusters and ladder stays stop at the lowest rail, 0.15-0.25 m
  above it (``max_base_height_m``);
- a pole is a straight vertical cylinder of radius ``min_radius_m`` .. ``max_radius_m``; the
  pieces of diagonal or curved pipes cut by sections drift sideways with height
  (they fit no vertical circle);
- rails cut by a section give long clusters (``max_cluster_width_m``).

Beam posts stand behind the beam and are seen only below (and on top of) it: sections through
the beam hold only long beam clusters, the cylinder is found from the sections below, which is
why only ``min_extent_share`` of the height must hold circles.

The scanner sees the front half of a pole with about 5 mm of range noise, so a single section's
circle is poor; the axis and radius come from a final geometric circle fit on all the cylinder's
inlier points projected to xy.

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
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from guardrail_core.errors import ReconstructionError
from guardrail_core.reconstruct.model import Pole
from guardrail_core.reconstruct.runs import check_points


@dataclass(frozen=True)
class PoleParams:
    """Thresholds of pole detection. Lengths in metres."""

    section_step_m: float = 0.05
    """Metres. Height step of the horizontal section planes (Fukano & Masuda cut at a fixed
    step; the paper gives no value). Sections are contiguous: thickness = step."""
    cluster_gap_m: float = 0.05
    """Metres. Within a section, points closer than this (horizontally) are one cluster. Below
    the 83 mm gap between a pole and the nearest baluster (125 mm spacing) and above the point
    spacing on a sparse pole."""
    max_cluster_width_m: float = 0.17
    """Metres. A cluster wider than this (xy bounding-box diagonal) is a rail or a beam, not a
    pole section: the widest pole (phi 139.8 mm) plus noise."""
    min_circle_points: int = 4
    """Points. A section cluster with fewer points keeps its centroid but gets no circle fit."""
    stack_radius_m: float = 0.08
    """Metres. Compact clusters whose centres lie within this of each other support each other
    as sections of one pole, and a stack takes the clusters within this of its median centre:
    the widest pole's clusters (phi 139.8 mm, cut by sparse scan lines) lie within it, the
    nearest baluster (125 mm from a pole's axis) does not."""
    max_section_gap: int = 2
    """Sections. A stack's sections may skip at most this many sections (where a rail through
    the pole makes the section's cluster long); farther sections belong to another run of
    sections (the fragments of a sparse rail line up under the same rail's fragments above)."""
    min_sections: int = 4
    """Sections. A pole has compact clusters, within ``stack_radius_m`` of each other, in at
    least this many nearly consecutive sections (a thrie-beam post shows 5 below the beam)."""
    min_points: int = 8
    """Points. A pole has at least this many points in its stack."""
    min_extent_share: float = 0.2
    """Share of the pole height (ground to top) that the stack's compact sections must span;
    beam posts are seen only below the beam (0.25 m of 0.82 m for a thrie beam)."""
    max_base_height_m: float = 0.1
    """Metres. The lowest stack point must be at most this far above the ground: poles reach
    the ground, balusters and stays stop at the lowest rail, 0.15-0.25 m above it."""
    foot_gap_m: float = 0.06
    """Metres. Road points on a stack's footprint continue it downward while each lies at most
    this far below the one above: seen from across the road, a pole's lowest 0.15 m is taken
    for road (its normals tilt up), yet it still reaches the ground; a baluster's end hangs
    0.15 m or more above the ground points under it."""
    min_radius_m: float = 0.02
    """Metres. Smallest accepted pole radius (data: 30.5 mm; balusters are 11-14 mm)."""
    max_radius_m: float = 0.09
    """Metres. Largest accepted pole radius (data: 70 mm)."""
    min_height_m: float = 0.3
    """Metres. A pole stands at least this tall above the ground (the lowest guardrail, a
    W-beam's post, stands 0.6 m); shorter stacks are clutter at the run's foot."""
    max_height_m: float = 1.6
    """Metres. Taller stacks are sign or lamp posts, not guardrail poles (data: 0.78-1.1 m)."""
    ransac_trials: int = 256
    """Random point triples tried for a stack's circle (seeded: results are reproducible)."""
    ransac_tolerance_m: float = 0.01
    """Metres. Points within this of a circle are its inliers (2x the ~5 mm range noise)."""
    base_fit_height_m: float = 0.3
    """Metres. The RANSAC circle of a stack is drawn from its points up to this height above
    its lowest point (a thrie-beam post shows 0.3 m below the beam); the fit then takes the
    points near that circle at every height."""
    in_line_m: float = 0.04
    """Metres. A stack's RANSAC circles are judged by the points of its sections whose cluster
    centroid lies within this of the median centroid of its lowest sections (those within
    ``base_fit_height_m``): a pole's sections stand in line above its foot, a beam's fragments
    in front of a post and rail ends beside a pole do not. Judged by the lowest 0.3 m alone
    (some 25 points where the road took a pole's lowest 0.15 m), circles 12 mm too big and
    14 mm off the axes won on a whole run."""
    merge_distance_m: float = 0.15
    """Metres. Two accepted axes closer than this are the same pole (the one with fewer points
    goes); poles stand 2 m or 4 m apart. Rail ends stacked beside a pole, 0.10-0.12 m from its
    axis and reaching the ground through a stray ground point, fit a pole's circle too."""
    shared_radius: bool = True
    """Poles of one run share a design: after a first pass, every pole is refitted with the
    radius that fits all the run's poles together (only its axis is fitted), and that is its
    radius (see ``_shared_radius``)."""
    shared_radius_tolerance: float = 0.15
    """Relative. In the refit, RANSAC hypotheses must be within this of the shared radius."""
    circle_iterations: int = 4
    """Rounds of outlier rejection of the circle fits."""
    circle_outlier_k: float = 2.5
    """A point farther than this many RMS residuals from the fitted circle is an outlier."""
    circle_noise_floor_m: float = 0.004
    """Metres. The RMS used for outlier rejection is at least this (the range noise, ~5 mm),
    so a near-perfect fit does not reject good points."""
    member_margin_m: float = 0.015
    """Metres. Points within radius + this of the axis belong to the pole (``point_is_pole``,
    height); beam points, 0.09 m in front of a 70 mm post's axis, stay out."""
    ground_radius_m: float = 0.5
    """Metres. Ground points within this horizontal distance of the axis give the ground height."""
    ground_k: int = 16
    """Points. The ground height is the median z of the nearest this-many ground points."""
    max_offset_deviation_m: float = 0.1
    """Metres. The poles of a run stand at one offset from its rails (one design): with at least
    three poles, one whose offset from the rail points near it differs from the poles' median
    offset by more than this is not one of them (a delineator post before a beam)."""
    offset_window_m: float = 1.5
    """Metres. The rail points within this horizontal distance of a pole's axis give its offset
    from the rails (their median distance across the local run direction)."""
    no_ground_window_m: float = 2.5
    """Metres. Without ground points, a stack's base is tested against the lowest run point
    within this horizontal distance of the axis: it covers the nearest pole (poles stand at
    most 4 m apart), whose base is then the ground of a baluster or of a beam's fragments (on
    a grade that reference is low by up to grade x window). The pole's ground point is then
    its own lowest point."""


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


def fit_circles(
    xy: np.ndarray,
    label: np.ndarray,
    n_label: int,
    *,
    iterations: int = 4,
    outlier_k: float = 2.5,
    noise_floor: float = 0.004,
    refine: bool = True,
    fixed_radius: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Circles fitted to groups of 2-D points, all groups at once.

    Algebraic least squares (Kasa) then, with ``refine``, Gauss-Newton steps of the geometric
    fit; after each fit, points farther than ``outlier_k`` x max(RMS, ``noise_floor``) from the
    circle are dropped and the fit repeated, ``iterations`` times.

    Parameters
    ----------
    xy : (N, 2) float64, metres
    label : (N,) int, group of each point, 0 .. n_label-1 (negative: ignored)
    n_label : number of groups
    fixed_radius : (L,) float64, metres, optional: fit only the centres, for these radii

    Returns
    -------
    centre : (L, 2) float64, metres (NaN where a group has fewer than 3 inliers or is degenerate)
    radius : (L,) float64, metres
    rms : (L,) float64, metres, RMS geometric residual of the inliers
    inlier : (N,) bool

    References
    ----------
    Fukano & Masuda 2015 (circle fits of section points); Matsumoto et al. 2019, §4.1.
    """
    xy = np.asarray(xy, np.float64)
    label = np.asarray(label, np.int64)
    inlier = label >= 0
    lab = np.where(inlier, label, 0)
    centre = np.full((n_label, 2), np.nan)
    radius = np.full(n_label, np.nan)
    rms = np.full(n_label, np.nan)
    if n_label == 0 or len(xy) == 0:
        return centre, radius, rms, inlier
    for _ in range(max(iterations, 0) + 1):
        centre, radius = _kasa(xy, lab, inlier, n_label)
        if fixed_radius is not None:
            radius = np.asarray(fixed_radius, np.float64).copy()
            centre, radius = _gauss_newton(xy, lab, inlier, n_label, centre, radius, fixed=True)
        elif refine:
            centre, radius = _gauss_newton(xy, lab, inlier, n_label, centre, radius)
        resid = np.linalg.norm(xy - centre[lab], axis=1) - radius[lab]
        w = inlier.astype(np.float64)
        n = np.bincount(lab, w, n_label)
        rms = np.sqrt(np.bincount(lab, w * np.nan_to_num(resid) ** 2, n_label) / np.maximum(n, 1))
        limit = outlier_k * np.maximum(rms, noise_floor)
        keep = inlier & (np.abs(np.nan_to_num(resid, nan=np.inf)) <= limit[lab])
        # A group never drops below 3 points: then it keeps its previous inliers.
        n_keep = np.bincount(lab, keep.astype(np.float64), n_label)
        keep = np.where(n_keep[lab] >= 3, keep, inlier)
        if np.array_equal(keep, inlier):
            break
        inlier = keep
    bad = np.bincount(lab, inlier.astype(np.float64), n_label) < 3
    centre[bad] = np.nan
    radius[bad] = np.nan
    rms[bad] = np.nan
    return centre, radius, rms, inlier & (label >= 0)


def _group_mean(v: np.ndarray, lab: np.ndarray, w: np.ndarray, n: int) -> np.ndarray:
    s = np.bincount(lab, w, n)
    return np.bincount(lab, w * v, n) / np.maximum(s, 1e-12)


def _kasa(xy, lab, inlier, n_label):
    """Batched algebraic circle fit: x² + y² = a x + b y + c in each group's centred frame."""
    w = inlier.astype(np.float64)
    mx = _group_mean(xy[:, 0], lab, w, n_label)
    my = _group_mean(xy[:, 1], lab, w, n_label)
    u = xy[:, 0] - mx[lab]
    v = xy[:, 1] - my[lab]
    q = u * u + v * v
    cols = (u, v, np.ones_like(u))
    m = np.empty((n_label, 3, 3))
    rhs = np.empty((n_label, 3))
    for i in range(3):
        rhs[:, i] = np.bincount(lab, w * cols[i] * q, n_label)
        for j in range(i, 3):
            m[:, i, j] = m[:, j, i] = np.bincount(lab, w * cols[i] * cols[j], n_label)
    with np.errstate(invalid="ignore"):
        det = np.linalg.det(m)
    ok = np.abs(det) > 1e-18
    sol = np.full((n_label, 3), np.nan)
    if ok.any():
        sol[ok] = np.linalg.solve(m[ok], rhs[ok][..., None])[..., 0]
    cu, cv = sol[:, 0] / 2, sol[:, 1] / 2
    r2 = sol[:, 2] + cu**2 + cv**2
    radius = np.sqrt(np.where(r2 > 0, r2, np.nan))
    return np.stack([cu + mx, cv + my], 1), radius


def _gauss_newton(xy, lab, inlier, n_label, centre, radius, steps: int = 5, fixed: bool = False):
    """Batched Gauss-Newton steps of the geometric circle fit from (centre, radius); with
    ``fixed`` the radius stays (the Jacobian's radius column is zero, damped)."""
    w = inlier.astype(np.float64)
    for _ in range(steps):
        d = xy - centre[lab]
        dist = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        res = np.nan_to_num(dist - radius[lab])
        jac = (-d[:, 0] / dist, -d[:, 1] / dist, -np.ones_like(dist))
        if fixed:
            jac = (jac[0], jac[1], np.zeros_like(dist))
        jtj = np.empty((n_label, 3, 3))
        jtr = np.empty((n_label, 3))
        for i in range(3):
            jtr[:, i] = np.bincount(lab, w * jac[i] * res, n_label)
            for j in range(i, 3):
                jtj[:, i, j] = jtj[:, j, i] = np.bincount(lab, w * jac[i] * jac[j], n_label)
        if fixed:
            jtj[:, 2, 2] = 1.0
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(radius) & (np.abs(np.linalg.det(jtj)) > 1e-18)
        if not ok.any():
            break
        step = np.zeros((n_label, 3))
        step[ok] = np.linalg.solve(jtj[ok], -jtr[ok][..., None])[..., 0]
        centre = centre + step[:, :2]
        radius = radius + step[:, 2]
    return centre, radius


def detect_poles(
    xyz: np.ndarray, ground: np.ndarray | None = None, params: PoleParams = PoleParams()
) -> PoleDetection:
    """Poles of one guardrail run.

    Parameters
    ----------
    xyz : (N, 3) float64, metres, world: the points of ONE run (rails, beams and poles)
    ground : (G, 3) float64, metres, world: ground points near the run; may be empty or None
    params : the thresholds

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
    if params.section_step_m <= 0 or params.cluster_gap_m <= 0:
        raise ReconstructionError("section_step_m and cluster_gap_m must be > 0")
    n = len(xyz)
    none = PoleDetection([], np.zeros(n, bool))
    if n < params.min_points:
        return none

    # §4.1: horizontal section planes, every section_step_m.
    section = np.floor((xyz[:, 2] - xyz[:, 2].min()) / params.section_step_m).astype(np.int64)
    # §4.1: in each section, points split into clusters along the run (gaps between them).
    # Sections are kept apart by lifting them far from each other in a 3-D search.
    lifted = np.column_stack([xyz[:, :2], section * (10.0 * params.cluster_gap_m)])
    pairs = cKDTree(lifted).query_pairs(params.cluster_gap_m, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    n_cluster, cluster = connected_components(graph, directed=False)
    count = np.bincount(cluster, minlength=n_cluster)
    lo = np.full((n_cluster, 2), np.inf)
    hi = np.full((n_cluster, 2), -np.inf)
    np.minimum.at(lo, cluster, xyz[:, :2])
    np.maximum.at(hi, cluster, xyz[:, :2])
    width = np.linalg.norm(hi - lo, axis=1)
    compact = width <= params.max_cluster_width_m

    # §4.1: circles fitted to the compact clusters with enough points (algebraic LSQ,
    # outlier rejection); a circle far too big for a pole marks a flat piece (a cap seen from
    # above, a beam end), not a pole's section.
    fit_label = np.where(
        compact[cluster] & (count[cluster] >= params.min_circle_points), cluster, -1
    )
    _, c_radius, _, _ = fit_circles(
        xyz[:, :2], fit_label, n_cluster,
        iterations=params.circle_iterations, outlier_k=params.circle_outlier_k,
        noise_floor=params.circle_noise_floor_m, refine=False,
    )  # fmt: skip
    compact &= ~(np.isfinite(c_radius) & (c_radius > 2 * params.max_radius_m))
    centroid: np.ndarray = np.stack(
        [np.bincount(cluster, xyz[:, k], n_cluster) for k in range(2)], 1
    ).astype(np.float64)
    centroid = centroid / np.maximum(count, 1)[:, None]
    cand = np.flatnonzero(compact)
    if len(cand) == 0:
        return none
    first_pt = np.full(n_cluster, n, np.int64)
    np.minimum.at(first_pt, cluster, np.arange(n))
    sec_of_cand = section[first_pt[cand]]
    n_sec = int(section.max()) + 1

    # §4.1: vertically aligned circles are joined. A cluster is a seed when compact clusters of
    # at least min_sections nearly consecutive sections lie within stack_radius_m of it: a
    # pole's sections support each other; the fragments of a sparse rail (one or two sections
    # per rail) do not.
    cpairs = cKDTree(centroid[cand]).query_pairs(params.stack_radius_m, output_type="ndarray")
    i_all = np.concatenate([cpairs[:, 0], cpairs[:, 1], np.arange(len(cand))])
    j_all = np.concatenate([cpairs[:, 1], cpairs[:, 0], np.arange(len(cand))])
    support_key = np.unique(i_all * n_sec + sec_of_cand[j_all])
    owner, sec = support_key // n_sec, support_key % n_sec
    brk = np.ones(len(support_key), bool)
    brk[1:] = (owner[1:] != owner[:-1]) | (np.diff(sec) > params.max_section_gap + 1)
    run = np.cumsum(brk) - 1
    own = np.searchsorted(support_key, np.arange(len(cand)) * n_sec + sec_of_cand)
    support = np.bincount(run)[run[own]]
    stack_of_cand, stack_centre = _group_stacks(
        centroid[cand], support, support >= params.min_sections, params.stack_radius_m
    )
    n_stack = len(stack_centre)
    if n_stack == 0:
        return none
    stack_of_cluster = np.full(n_cluster, -1, np.int64)
    stack_of_cluster[cand] = stack_of_cand
    stack = stack_of_cluster[cluster]

    # Cheap rejection first: a stack whose lowest point is far above the ground is a baluster,
    # a stay or a column of beam fragments (§4.1: poles stand on the ground).
    in_stack = stack >= 0
    z_min = np.full(n_stack, np.inf)
    np.minimum.at(z_min, stack[in_stack], xyz[in_stack, 2])
    ground_z, _ = _ground_height(stack_centre, z_min, ground, xyz, params)
    reach = np.full(n_stack, params.max_radius_m + params.member_margin_m)
    z_min = _foot_bottom(stack_centre, reach, z_min, ground, params.foot_gap_m)
    n_pts = np.bincount(stack[in_stack], minlength=n_stack)
    maybe = (z_min - ground_z <= params.max_base_height_m) & (n_pts >= params.min_points)

    # The axis: a robust circle fit (RANSAC, then geometric least squares with outlier
    # rejection) on all the stack's points projected to xy; the scanner sees the front half.
    rng = np.random.default_rng(0)
    order = np.argsort(stack, kind="stable")
    bounds = np.searchsorted(stack[order], np.arange(n_stack + 1))
    stack_pts = [order[bounds[k] : bounds[k + 1]] for k in np.flatnonzero(maybe)]
    judge = [_in_line(xyz[pts, 2], cluster[pts], centroid, params) for pts in stack_pts]
    found = _fit_stacks(xyz, stack_pts, judge, section, params, rng)
    if not found:
        return none
    measured = _measure(xyz, section, ground, found, params)
    accept = measured["accept"]
    if params.shared_radius and accept.any():
        # Poles of one run share a design: every stack is fitted again with the radius that
        # fits the accepted poles on the run's line together (a delineator off it is another
        # design), fitting only the axis (a free radius on a half-seen pole trades off against
        # the axis' offset from the road, and can take in a rail).
        member = measured["member_pole"]
        on_pole = (member >= 0) & accept[np.maximum(member, 0)]
        inline = accept & _consistent_offsets(
            xyz[:, :2], on_pole, measured["centre"], accept, params
        )
        use = inline if inline.any() else accept
        stacks = [(found[k][0], found[k][2]) for k in np.flatnonzero(use)]
        shared = _shared_radius(xyz, stacks, params)
        found = _fit_stacks(xyz, stack_pts, judge, section, params, rng, shared)
        if not found:
            return none
        measured = _measure(xyz, section, ground, found, params)
        accept = measured["accept"]
    centre, ground_z = measured["centre"], measured["ground_z"]
    member_pole = measured["member_pole"]
    is_pole = (member_pole >= 0) & accept[np.maximum(member_pole, 0)]
    accept = accept & _consistent_offsets(xyz[:, :2], is_pole, centre, accept, params)
    is_pole = (member_pole >= 0) & accept[np.maximum(member_pole, 0)]
    n_member = np.bincount(member_pole[is_pole], minlength=len(centre))
    poles = [
        Pole(
            position=np.array([centre[k, 0], centre[k, 1], ground_z[k]]),
            radius=float(measured["radius"][k]),
            height=float(measured["height"][k]),
            n_points=int(n_member[k]),
        )
        for k in _along_run_order(xyz, centre)
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
) -> list[tuple[np.ndarray, float, np.ndarray]]:
    """Axes of stacks (point indices per stack): (centre (2,), radius, inlier indices) each.

    RANSAC per stack, drawn from its lowest part (a pole reaches the ground there, while a
    beam's fragments can join the stack higher up) and judged by its points in line with that
    part (``judge``, per stack a bool mask of its points; see ``in_line_m``), then a batched
    geometric fit of the points near each circle at every height, twice (the refined circle
    may take in points the first missed). Stacks that fit no circle, or whose inliers span
    fewer than ``min_sections`` sections, are left out.
    """
    guesses = []
    for pts, by in zip(stack_pts, judge, strict=True):  # per stack
        low = xyz[pts, 2] <= xyz[pts, 2].min() + params.base_fit_height_m
        guesses.append(_ransac_circle(xyz[pts, :2], low, low | by, params, rng, shared_radius))
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
    for _ in range(2):
        near = np.abs(np.linalg.norm(xy - centre[label], axis=1) - radius[label])
        near = near <= params.ransac_tolerance_m
        c, r, _, _ = fit_circles(
            xy, np.where(near, label, -1), len(ok),
            iterations=params.circle_iterations, outlier_k=params.circle_outlier_k,
            noise_floor=params.circle_noise_floor_m, refine=True, fixed_radius=fixed,
        )  # fmt: skip
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
        out.append((centre[k], float(radius[k]), members))
    return out


def _grounded_bottom(z: np.ndarray, sec: np.ndarray) -> float:
    """Lowest z (metres) of the lowest section followed by another occupied one at most one
    empty section higher (sparse poles skip a section now and then)."""
    occupied = np.unique(sec)
    first = occupied[:-1][np.diff(occupied) <= 2]
    if len(first) == 0:
        return float("inf")
    return float(z[sec == first[0]].min())


def _measure(
    xyz: np.ndarray,
    section: np.ndarray,
    ground: np.ndarray,
    fits: list[tuple[np.ndarray, float, np.ndarray]],
    params: PoleParams,
) -> dict[str, np.ndarray]:
    """Ground, height, members and acceptance of fitted axes (see :func:`detect_poles`)."""
    centre = np.array([f[0] for f in fits])
    radius = np.array([f[1] for f in fits])
    # The base is the bottom of the lowest two nearly consecutive sections holding inliers: a
    # stray point below (a ground point under a baluster that happens to lie on its circle,
    # 0.15 m below the baluster's end) is not.
    z_lo = np.array([_grounded_bottom(xyz[f[2], 2], section[f[2]]) for f in fits])
    z_hi = np.array([xyz[f[2], 2].max() for f in fits])
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
    foot = _foot_bottom(centre, radius + params.member_margin_m, z_lo, ground, params.foot_gap_m)
    base_ref, ground_z = _ground_height(centre, np.minimum(low, foot), ground, xyz, params)
    height = top - ground_z
    extent_share = (z_hi - z_lo) / np.maximum(height, 1e-9)
    accept = (
        (foot - base_ref <= params.max_base_height_m)  # a pole stands on the ground
        & (height >= params.min_height_m)
        & (height <= params.max_height_m)
        & (extent_share >= params.min_extent_share)
    )
    # Two accepted axes closer than merge_distance_m are one pole: the one with more inlier
    # points stays.
    accept &= _suppress_duplicates(centre, np.array([len(f[2]) for f in fits]), accept, params)
    return dict(
        centre=centre, radius=radius, ground_z=ground_z, height=height, accept=accept,
        member_pole=member_pole,
    )  # fmt: skip


def _foot_bottom(
    centre: np.ndarray, reach: np.ndarray, bottom: np.ndarray, ground: np.ndarray, gap: float
) -> np.ndarray:
    """Bottoms (P,) of axes, metres, lowered along road points on their footprints.

    Parameters
    ----------
    centre : (P, 2) axes; reach : (P,) footprint radii; bottom : (P,) lowest pole points
    ground : (G, 3) road points; gap : the largest step (m) from one foot point to the next

    Starting at ``bottom``, the road points within ``reach`` of the axis, from the highest
    down, continue the pole while each lies at most ``gap`` below the previous one.
    """
    out = np.asarray(bottom, np.float64).copy()
    if len(ground) == 0 or len(centre) == 0:
        return out
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


def _group_stacks(
    centres: np.ndarray, support: np.ndarray, seed: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Greedy grouping of seed clusters into stacks, strongest support first.

    Each stack takes the unassigned seeds within ``radius`` of the median centre of the seeds
    around its strongest one, so stacks never chain along a rail. Returns the stack of each
    cluster (K,) int64 (-1: none) and the stack centres (S, 2).
    """
    stack_of = np.full(len(centres), -1, np.int64)
    out: list[np.ndarray] = []
    idx = np.flatnonzero(seed)
    if len(idx) == 0:
        return stack_of, np.zeros((0, 2))
    tree = cKDTree(centres[idx])
    free = np.ones(len(idx), bool)
    for i in np.lexsort((np.arange(len(idx)), -support[idx])):  # per stack
        if not free[i]:
            continue
        near = np.asarray(tree.query_ball_point(centres[idx[i]], radius), np.int64)
        near = near[free[near]]
        centre = np.median(centres[idx[near]], axis=0)
        near = np.asarray(tree.query_ball_point(centre, radius), np.int64)
        near = near[free[near]]
        if len(near) == 0:
            near = np.array([i])
        free[near] = False
        stack_of[idx[near]] = len(out)
        out.append(np.median(centres[idx[near]], axis=0))
    return stack_of, np.array(out).reshape(-1, 2)


def _ransac_circle(
    xy: np.ndarray,
    sample: np.ndarray,
    judge: np.ndarray,
    params: PoleParams,
    rng: np.random.Generator,
    shared_radius: float | None = None,
) -> tuple[np.ndarray, float] | None:
    """RANSAC (MSAC) circle of radius min_radius_m .. max_radius_m through three of the (n, 2)
    points where ``sample`` (n,) bool, judged by the points where ``judge`` (n,) bool: (centre
    (2,), radius), or None when no hypothesis fits. With ``shared_radius`` the hypotheses must
    be within shared_radius_tolerance of it."""
    lo_r, hi_r = params.min_radius_m, params.max_radius_m
    if shared_radius is not None:
        lo_r = shared_radius * (1 - params.shared_radius_tolerance)
        hi_r = shared_radius * (1 + params.shared_radius_tolerance)
    if sample.sum() < 3:
        return None
    mean = xy.mean(axis=0)
    p = xy[sample] - mean
    n = len(p)
    t = rng.integers(0, n, size=(params.ransac_trials, 3))
    a, b, c = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    d = 2 * (
        a[:, 0] * (b[:, 1] - c[:, 1])
        + b[:, 0] * (c[:, 1] - a[:, 1])
        + c[:, 0] * (a[:, 1] - b[:, 1])
    )
    a2, b2, c2 = (a**2).sum(1), (b**2).sum(1), (c**2).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (a2 * (b[:, 1] - c[:, 1]) + b2 * (c[:, 1] - a[:, 1]) + c2 * (a[:, 1] - b[:, 1])) / d
        uy = (a2 * (c[:, 0] - b[:, 0]) + b2 * (a[:, 0] - c[:, 0]) + c2 * (b[:, 0] - a[:, 0])) / d
    r = np.hypot(a[:, 0] - ux, a[:, 1] - uy)
    ok = np.isfinite(r) & (r >= lo_r) & (r <= hi_r)
    if not ok.any():
        return None
    ux, uy, r = ux[ok], uy[ok], r[ok]
    q = xy[judge] - mean
    dist = np.hypot(q[None, :, 0] - ux[:, None], q[None, :, 1] - uy[:, None])
    # MSAC: truncated squared residuals, so the tightest circle wins, not the widest annulus.
    cost = np.minimum((dist - r[:, None]) ** 2, params.ransac_tolerance_m**2).sum(axis=1)
    best = int(np.argmin(cost))
    return np.array([ux[best], uy[best]]) + mean, float(r[best])


def _in_line(
    z: np.ndarray, cluster: np.ndarray, centroid: np.ndarray, params: PoleParams
) -> np.ndarray:
    """(n,) bool: the points of one stack (heights ``z`` (n,), their section clusters
    ``cluster`` (n,), indexing ``centroid`` (C, 2)) whose cluster centroid lies within
    ``in_line_m`` of the median centroid of the stack's lowest clusters."""
    low = z <= z.min() + params.base_fit_height_m
    foot = np.median(centroid[np.unique(cluster[low])], axis=0)
    return np.linalg.norm(centroid[cluster] - foot, axis=1) <= params.in_line_m


def _nearest_axis(xy: np.ndarray, centre: np.ndarray, reach: np.ndarray):
    """For each point (N, 2): the nearest axis within its reach (P,), -1 if none; distance."""
    if len(centre) == 0:
        return np.full(len(xy), -1, np.int64), np.full(len(xy), np.inf)
    k = min(2, len(centre))
    d, i = cKDTree(centre).query(xy, k=k, distance_upper_bound=float(reach.max()))
    d, i = d.reshape(len(xy), k)[:, 0], i.reshape(len(xy), k)[:, 0]
    inside = np.isfinite(d)
    inside[inside] = d[inside] <= reach[i[inside]]
    return np.where(inside, i, -1), d


def _suppress_duplicates(
    centre: np.ndarray, n_points: np.ndarray, accept: np.ndarray, params: PoleParams
) -> np.ndarray:
    """(P,) bool: False for an accepted axis within merge_distance_m of a stronger one."""
    keep = np.ones(len(centre), bool)
    idx = np.flatnonzero(accept)
    pairs = cKDTree(centre[idx]).query_pairs(params.merge_distance_m, output_type="ndarray")
    for a, b in pairs:  # per pair of duplicate poles (rare)
        weaker = idx[a] if n_points[idx[a]] < n_points[idx[b]] else idx[b]
        keep[weaker] = False
    return keep


def _ground_height(
    centre: np.ndarray, low: np.ndarray, ground: np.ndarray, xyz: np.ndarray, params: PoleParams
) -> tuple[np.ndarray, np.ndarray]:
    """Ground heights (P,) at each axis, metres: (for the base test, for the position).

    From the ``ground_k`` nearest ground points within ``ground_radius_m`` outside the widest
    pole's footprint (median z): both the same. Without ground points there: the base is
    tested against the lowest run or road point within ``no_ground_window_m`` (the
    neighbouring pole's base for a baluster), and the position takes the pole's own lowest
    point ``low`` (P,) (a pole reaches the ground).
    """
    out = np.full(len(centre), np.nan)
    if len(ground):
        # Ground points on a footprint are a pole's foot (a sparse scanner's road mask takes
        # some in), not the ground around it: not for this pole, nor for a baluster beside it.
        foot = params.max_radius_m + params.member_margin_m
        on_foot = cKDTree(centre).query(ground[:, :2], distance_upper_bound=foot)[0] <= foot
        tree = cKDTree(ground[:, :2])
        k = min(4 * params.ground_k, len(ground))
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
        for chunk in np.array_split(order, max(1, len(order) // 2048)):
            if len(todo) == 0:
                break
            d = np.linalg.norm(xyz[chunk, None, :2] - centre[missing[todo]][None], axis=2)
            hit = d <= params.no_ground_window_m
            found = hit.any(axis=0)
            lowest[todo[found]] = xyz[chunk[hit[:, found].argmax(axis=0)], 2]
            todo = todo[~found]
        out[missing] = np.minimum(lowest, low[missing])
    return out, position


def _consistent_offsets(
    xy: np.ndarray, is_pole: np.ndarray, centre: np.ndarray, accept: np.ndarray, params: PoleParams
) -> np.ndarray:
    """(P,) bool: False for an accepted axis that stands off the line of the run's other poles.

    Each pole's offset is the median signed distance of the rail points (not pole points)
    within ``offset_window_m`` of its axis from the axis, across their principal direction
    (oriented along the run's, so the sign means the same side for every pole). With fewer
    than three accepted poles, or fewer than 10 rail points near a pole, nothing is rejected.
    """
    keep = np.ones(len(centre), bool)
    idx = np.flatnonzero(accept)
    rails = xy[~is_pole]
    if len(idx) < 3 or len(rails) < 10:
        return keep
    sub = rails[:: max(1, len(rails) // 5000)]
    _, _, vt = np.linalg.svd(sub - sub.mean(axis=0), full_matrices=False)
    run_dir = vt[0]
    tree = cKDTree(rails)
    offset = np.full(len(idx), np.nan)
    for j, k in enumerate(idx):  # per pole (a few per run)
        near = rails[tree.query_ball_point(centre[k], params.offset_window_m)]
        if len(near) < 10:
            continue
        _, _, v = np.linalg.svd(near - near.mean(axis=0), full_matrices=False)
        along = v[0] if v[0] @ run_dir >= 0 else -v[0]
        across = np.array([-along[1], along[0]])
        offset[j] = float(np.median((near - centre[k]) @ across))
    known = np.isfinite(offset)
    if known.sum() < 3:
        return keep
    deviation = np.abs(offset - np.median(offset[known]))
    keep[idx[known & (deviation > params.max_offset_deviation_m)]] = False
    return keep


def _along_run_order(xyz: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Indices of ``centre`` (P, 2) sorted along the run's principal xy direction."""
    xy = xyz[:, :2] - xyz[:, :2].mean(axis=0)
    _, _, vt = np.linalg.svd(xy[:: max(1, len(xy) // 5000)], full_matrices=False)
    return np.argsort(centre @ vt[0], kind="stable")


def _shared_radius(
    xyz: np.ndarray, stacks: list[tuple[np.ndarray, np.ndarray]], params: PoleParams
) -> float:
    """The one radius (m) of a run's poles that fits all their points best, each pole's centre
    fitted for it: the minimum over radii in 1 mm steps (refined by a parabola) of the sum of
    squared circle residuals, each capped at ``ransac_tolerance_m``.

    ``stacks``: per accepted pole, (centre (2,), member point indices). A pole seen over a wide
    arc pins the radius down; one seen over a narrow arc (a beam's post behind its beam) fits
    many radii as well with its centre moved, and barely weighs. The median of the poles' own
    radii gave 52-87 mm for 70 mm posts, and moved the axes by up to 10 mm.
    """
    pts = np.concatenate([m for _, m in stacks])
    lab = np.repeat(np.arange(len(stacks)), [len(m) for _, m in stacks])
    xy = xyz[pts, :2]
    inlier = np.ones(len(pts), bool)
    centre0 = np.array([c for c, _ in stacks], np.float64)
    radii = np.arange(params.min_radius_m, params.max_radius_m + 1e-9, 0.001)
    cap = params.ransac_tolerance_m**2
    cost = np.empty(len(radii))
    for i, r in enumerate(radii):  # per radius, every pole's centre at once
        rr = np.full(len(stacks), r)
        centre, _ = _gauss_newton(xy, lab, inlier, len(stacks), centre0.copy(), rr, fixed=True)
        res = np.linalg.norm(xy - centre[lab], axis=1) - r
        cost[i] = np.minimum(np.nan_to_num(res, nan=np.inf) ** 2, cap).sum()
    i = int(np.argmin(cost))
    if 0 < i < len(radii) - 1:  # the parabola through the minimum and its neighbours
        curvature = cost[i - 1] - 2 * cost[i] + cost[i + 1]
        if curvature > 0:
            return float(radii[i] + 0.0005 * (cost[i - 1] - cost[i + 1]) / curvature)
    return float(radii[i])
