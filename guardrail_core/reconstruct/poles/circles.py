"""Circles of pole sections (§4.1): batched least-squares fits, RANSAC, and a run's one radius.

A pole seen by the scanner is the front half of a vertical cylinder with ~5 mm of range noise:
its horizontal sections are arcs. Circles are fitted to many groups of points at once (bincount
sums over the group labels, no loop over groups), by algebraic least squares (Kasa) and
Gauss-Newton steps of the geometric fit, with outlier rejection.

References
----------
Fukano, Masuda (2015), "Detection and classification of pole-like objects from mobile mapping
data", ISPRS Annals II-3/W5 (circle fits of section points).
Matsumoto, Mori, Masuda (2019), ISPRS Archives, §4.1.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.reconstruct.poles.params import PoleParams

#: Numerical guards of the batched solves (not thresholds): a smaller determinant is singular,
#: a smaller weight or distance is zero.
_SINGULAR = 1e-18
_TINY = 1e-12
#: Gauss-Newton steps per fit (the geometric fit converges from the algebraic one in a few).
_GAUSS_NEWTON_STEPS = 5
#: Points (radii times points) per batch of :func:`fit_shared_radius`'s fits, at most.
_BATCH_POINTS = 400_000


def fit_circles(
    xy: np.ndarray,
    label: np.ndarray,
    n_label: int,
    params: PoleParams = PoleParams(),
    *,
    refine: bool = True,
    fixed_radius: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Circles fitted to groups of 2-D points, all groups at once.

    Algebraic least squares (Kasa) then, with ``refine``, Gauss-Newton steps of the geometric
    fit; after each fit, points farther than ``circle_outlier_k`` x max(RMS,
    ``circle_noise_floor_m``) from the circle are dropped and the fit repeated,
    ``circle_iterations`` times (``params``).

    Parameters
    ----------
    xy : (N, 2) float64, metres
    label : (N,) int, group of each point, 0 .. n_label-1 (negative: ignored)
    n_label : number of groups
    params : the outlier rejection's thresholds
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
    for _ in range(params.circle_iterations + 1):
        centre, radius = _kasa(xy, lab, inlier, n_label)
        if fixed_radius is not None:
            radius = np.asarray(fixed_radius, np.float64).copy()
            centre, radius = gauss_newton(xy, lab, inlier, n_label, centre, radius, fixed=True)
        elif refine:
            centre, radius = gauss_newton(xy, lab, inlier, n_label, centre, radius)
        resid = np.linalg.norm(xy - centre[lab], axis=1) - radius[lab]
        w = inlier.astype(np.float64)
        n = np.bincount(lab, w, n_label)
        rms = np.sqrt(np.bincount(lab, w * np.nan_to_num(resid) ** 2, n_label) / np.maximum(n, 1))
        limit = params.circle_outlier_k * np.maximum(rms, params.circle_noise_floor_m)
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
    return np.bincount(lab, w * v, n) / np.maximum(s, _TINY)


def _kasa(
    xy: np.ndarray, lab: np.ndarray, inlier: np.ndarray, n_label: int
) -> tuple[np.ndarray, np.ndarray]:
    """Batched algebraic circle fit: x² + y² = a x + b y + c in each group's centred frame.

    ``xy`` (N, 2) metres, ``lab`` (N,) group 0 .. n_label-1, ``inlier`` (N,) bool (the points
    fitted); returns centres (L, 2) and radii (L,), metres (NaN where singular).
    """
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
    ok = np.abs(det) > _SINGULAR
    sol = np.full((n_label, 3), np.nan)
    if ok.any():
        sol[ok] = np.linalg.solve(m[ok], rhs[ok][..., None])[..., 0]
    cu, cv = sol[:, 0] / 2, sol[:, 1] / 2
    r2 = sol[:, 2] + cu**2 + cv**2
    radius = np.sqrt(np.where(r2 > 0, r2, np.nan))
    return np.stack([cu + mx, cv + my], 1), radius


def gauss_newton(
    xy: np.ndarray,
    lab: np.ndarray,
    inlier: np.ndarray,
    n_label: int,
    centre: np.ndarray,
    radius: np.ndarray,
    fixed: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Batched Gauss-Newton steps of the geometric circle fit from ``centre`` (L, 2) and
    ``radius`` (L,), metres, over the points ``xy`` (N, 2) of groups ``lab`` (N,) where
    ``inlier`` (N,); with ``fixed`` the radius stays (the Jacobian's radius column is zero,
    damped). Returns the new centres and radii."""
    w = inlier.astype(np.float64)
    for _ in range(_GAUSS_NEWTON_STEPS):
        d = xy - centre[lab]
        dist = np.maximum(np.linalg.norm(d, axis=1), _TINY)
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
            ok = np.isfinite(radius) & (np.abs(np.linalg.det(jtj)) > _SINGULAR)
        if not ok.any():
            break
        step = np.zeros((n_label, 3))
        step[ok] = np.linalg.solve(jtj[ok], -jtr[ok][..., None])[..., 0]
        centre = centre + step[:, :2]
        radius = radius + step[:, 2]
    return centre, radius


def ransac_circle(
    xy: np.ndarray,
    sample: np.ndarray,
    judge: np.ndarray,
    params: PoleParams,
    rng: np.random.Generator,
    near_radius: float | None = None,
) -> tuple[np.ndarray, float] | None:
    """RANSAC (MSAC) circle of radius min_radius_m .. max_radius_m through three of the (n, 2)
    points where ``sample`` (n,) bool, judged by the points where ``judge`` (n,) bool: (centre
    (2,), radius), metres, or None when no hypothesis fits. With ``near_radius`` (the run's
    shared radius) the hypotheses must be within shared_radius_tolerance of it."""
    lo_r, hi_r = params.min_radius_m, params.max_radius_m
    if near_radius is not None:
        lo_r = near_radius * (1 - params.shared_radius_tolerance)
        hi_r = near_radius * (1 + params.shared_radius_tolerance)
    if sample.sum() < 3:  # a circle needs three points
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


def fit_shared_radius(
    xyz: np.ndarray, stacks: list[tuple[np.ndarray, np.ndarray]], params: PoleParams
) -> float:
    """The one radius (m) of a run's poles that fits all their points best, each pole's centre
    fitted for it: the minimum over radii ``shared_radius_step_m`` apart (refined by a
    parabola) of the sum of squared circle residuals, each capped at ``ransac_tolerance_m``.

    ``xyz`` (N, 3) the run's points, metres; ``stacks``: per accepted pole, (centre (2,),
    member point indices into ``xyz``). A pole seen over a wide
    arc pins the radius down; one seen over a narrow arc (a beam's post behind its beam) fits
    many radii as well with its centre moved, and barely weighs. The median of the poles' own
    radii gave 52-87 mm for 70 mm posts, and moved the axes by up to 10 mm.
    """
    pts = np.concatenate([m for _, m in stacks])
    lab = np.repeat(np.arange(len(stacks)), [len(m) for _, m in stacks])
    xy = xyz[pts, :2]
    inlier = np.ones(len(pts), bool)
    centre0 = np.array([c for c, _ in stacks], np.float64)
    step = params.shared_radius_step_m
    # The last radius is max_radius_m itself, not a rounding error short of it.
    radii = np.arange(params.min_radius_m, params.max_radius_m + 1e-9, step)
    cap = params.ransac_tolerance_m**2
    cost = np.empty(len(radii))
    n_poles = len(stacks)
    # Every pole's centre at many radii in one batch of Gauss-Newton fits (the group of a
    # point at radius k is k * n_poles + its pole): the same sums, far fewer calls.
    batch = max(1, _BATCH_POINTS // max(len(xy), 1))
    for start in range(0, len(radii), batch):
        rs = radii[start : start + batch]
        k = len(rs)
        group = (np.arange(k)[:, None] * n_poles + lab[None, :]).ravel()
        xy_k = np.tile(xy, (k, 1))
        centre, _ = gauss_newton(
            xy_k,
            group,
            np.tile(inlier, k),
            k * n_poles,
            np.tile(centre0, (k, 1)),
            np.repeat(rs, n_poles),
            fixed=True,
        )
        res = np.linalg.norm(xy_k - centre[group], axis=1).reshape(k, -1) - rs[:, None]
        cost[start : start + k] = np.minimum(np.nan_to_num(res, nan=np.inf) ** 2, cap).sum(axis=1)
    i = int(np.argmin(cost))
    if 0 < i < len(radii) - 1:  # the parabola through the minimum and its neighbours
        curvature = cost[i - 1] - 2 * cost[i] + cost[i + 1]
        if curvature > 0:
            return float(radii[i] + 0.5 * step * (cost[i - 1] - cost[i + 1]) / curvature)
    return float(radii[i])
