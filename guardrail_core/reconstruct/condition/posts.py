"""Posts of a reconstructed run: each post's lean from its fitted axis, and the posts missing
where the spacing breaks.

Lean: pole detection fits vertical cylinders (:mod:`guardrail_core.reconstruct.poles`), so a
post's tilt is measured here on its points: a cylinder of the post's radius whose axis may lean
is fitted to all of them at once (the scanner sees the front half, which a fixed radius places
right). The axis' angle from vertical is the lean; its horizontal direction is split into along
the run and toward the road (the x and z of the unit frames either side,
:mod:`guardrail_core.reconstruct.unit_frame`).

Missing posts: the reconstruction marks the poles it saw (``n_points > 0``; inserted and
extrapolated poles have none). Between two consecutive seen posts a gap of about k spacings
(k >= 2) holds k - 1 missing posts, evenly spaced, as :mod:`guardrail_core.reconstruct.units`
inserts them. The spacing is the run's own (:func:`~guardrail_core.reconstruct.units.run_spacing`
of the seen posts' gaps) where it is known, else the standard's; the run's spacing is checked
against the standard's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.reconstruct.condition.params import ConditionParams
from guardrail_core.reconstruct.condition.standards import Standard
from guardrail_core.reconstruct.model import Pole, RunModel
from guardrail_core.reconstruct.runs import check_points
from guardrail_core.reconstruct.units import run_spacing

#: Rounds of selecting the post's points around the current axis and refitting the axis (the
#: first starts from the vertical axis of pole detection; a lean of a few degrees moves the
#: top a few centimetres, which the next round follows).
_AXIS_ROUNDS = 3
#: Gauss-Newton steps of the leaning-cylinder fit (it converges from the vertical axis in a few).
_GAUSS_NEWTON_STEPS = 8
#: A point off the fitted surface by more than this many RMS residuals, and by more than the
#: floor (metres: the scanner's few millimetres of range noise), is a stray (a bolt, a blockout).
_OUTLIER_K = 3.0
_NOISE_FLOOR_M = 0.005
#: The step (metres, or metres per metre) of the fit's numerical derivatives.
_JACOBIAN_STEP = 1e-7


@dataclass(frozen=True)
class PostLean:
    """The lean of one seen post.

    Attributes
    ----------
    index : int, the pole's index in ``RunModel.poles``
    position : (3,) float64, metres, world: the pole's ground point
    lean_deg : float, degrees from vertical (NaN: too few points to fit an axis)
    along_deg : float, degrees: the lean's component along the run (positive: toward the next
        pole), NaN where unknown
    toward_road_deg : float, degrees: its component across the run (positive: toward the road)
    n_points : int, the post's points the axis was fitted to (0: too few, no lean)
    limit_deg : float, the lean allowed (the standard's, else ``ConditionParams.max_lean_deg``)
    flagged : bool, ``lean_deg`` exceeds ``limit_deg``
    """

    index: int
    position: np.ndarray
    lean_deg: float
    along_deg: float
    toward_road_deg: float
    n_points: int
    limit_deg: float
    flagged: bool


@dataclass(frozen=True)
class MissingPost:
    """A post missing between two seen ones.

    Attributes
    ----------
    station_m : float, metres along the run (the seen posts' chord line) from its first seen post
    position : (3,) float64, metres, world: where it should stand (on the chord, ground height
        interpolated)
    after_pole : int, index in ``RunModel.poles`` of the seen post before the gap
    gap_m : float, metres, the gap it lies in
    """

    station_m: float
    position: np.ndarray
    after_pole: int
    gap_m: float


@dataclass(frozen=True)
class SpacingCheck:
    """The run's post spacing against the standard's, and its missing posts.

    Attributes
    ----------
    spacing_m : float, metres: the spacing used (the run's, else the standard's)
    run_spacing_m : float, metres: the run's own spacing, 0.0 where unknown (fewer than two gaps)
    standard_spacing_m, tolerance_m : float, metres
    compliant : bool | None: the run's spacing lies within tolerance of the standard's (None:
        unknown)
    missing : the missing posts, in order along the run
    """

    spacing_m: float
    run_spacing_m: float
    standard_spacing_m: float
    tolerance_m: float
    compliant: bool | None
    missing: tuple[MissingPost, ...]


def post_leans(
    xyz: np.ndarray,
    run: RunModel,
    standard: Standard | None = None,
    params: ConditionParams = ConditionParams(),
) -> list[PostLean]:
    """The lean of every seen post of a run.

    Parameters
    ----------
    xyz : (N, 3) float64, metres, world: the run's guardrail points (posts and rails)
    run : the run's reconstruction (poles in order, unit frames between them)
    standard : the lean limit (``max_post_lean_deg``); None or an unstated limit: ``params``'
    params : the reach, the points a fit needs and the fallback limit

    Returns
    -------
    One :class:`PostLean` per pole with points (``n_points > 0``), in order along the run.
    """
    xyz = check_points(xyz)
    limit = params.max_lean_deg
    if standard is not None and standard.max_post_lean_deg is not None:
        limit = standard.max_post_lean_deg
    tree = cKDTree(xyz[:, :2]) if len(xyz) else None
    out = []
    for k, pole in enumerate(run.poles):  # per pole (tens per run)
        if pole.n_points <= 0:
            continue
        # Twice the first fit's reach: the later fits follow the lean a little beyond it.
        reach = pole.radius + 2 * params.lean_reach_m
        near = tree.query_ball_point(pole.position[:2], reach) if tree is not None else []
        slope, n_points = _axis_slope(xyz[np.asarray(near, np.int64)], pole, params)
        along, normal = _run_axes(run, k)
        lean = float(np.degrees(np.arctan(np.linalg.norm(slope))))
        if along is None or normal is None or not np.isfinite(lean):
            along_deg = toward_deg = float("nan")
        else:
            along_deg = float(np.degrees(np.arctan(slope @ along)))
            toward_deg = float(np.degrees(np.arctan(slope @ normal)))
        out.append(
            PostLean(
                index=k,
                position=np.asarray(pole.position, np.float64).copy(),
                lean_deg=lean,
                along_deg=along_deg,
                toward_road_deg=toward_deg,
                n_points=n_points,
                limit_deg=limit,
                flagged=bool(np.isfinite(lean) and lean > limit),
            )
        )
    return out


def _axis_slope(xyz: np.ndarray, pole: Pole, params: ConditionParams) -> tuple[np.ndarray, int]:
    """(2,) horizontal drift of the post's axis per metre of height (NaN: no fit), and the
    number of points the fit kept.

    One fit of a leaning cylinder of the post's radius to all its points at once: each point's
    distance from the axis through (c, ground) along (t, 1) should be the radius; Gauss-Newton
    on (c, t). A circle per section, with a few noisy points on a half-seen arc each, drifts by
    degrees; all the points together do not. ``xyz`` (N, 3): the points near the post.
    """
    base = np.asarray(pole.position, np.float64)
    nan = np.full(2, np.nan)
    low, top = base[2] + params.lean_base_m, base[2] + pole.height
    pts = xyz[(xyz[:, 2] >= low) & (xyz[:, 2] <= top)]
    if len(pts) == 0:
        return nan, 0
    h = pts[:, 2] - base[2]
    params_ct = np.array([base[0], base[1], 0.0, 0.0])  # centre at the ground, drift per metre
    keep = np.zeros(len(pts), bool)
    for round_ in range(_AXIS_ROUNDS):  # follow the lean up the post
        d = pts[:, :2] - params_ct[:2] - np.outer(h, params_ct[2:])
        # The first round searches around the vertical axis; later ones keep only the points on
        # the post's surface about the fitted axis (a blockout on it lies beyond).
        dist = np.linalg.norm(d, axis=1)
        if round_ == 0:
            keep = dist <= pole.radius + params.lean_reach_m
        else:  # a shell about the surface: a rail running through the post lies inside it
            keep = np.abs(dist - pole.radius) <= params.lean_surface_margin_m
        if keep.sum() < params.lean_min_points or np.ptp(h[keep]) < params.lean_min_span_m:
            return nan, 0
        params_ct = _fit_leaning_cylinder(pts[keep, :2], h[keep], pole.radius, params_ct)
        if not np.isfinite(params_ct).all():
            return nan, 0
    return params_ct[2:], int(keep.sum())


def _fit_leaning_cylinder(
    xy: np.ndarray, h: np.ndarray, radius: float, start: np.ndarray
) -> np.ndarray:
    """(4,) (cx, cy, tx, ty): the axis through (c, 0) along (t, 1) of a cylinder of ``radius``
    (metres) through points ``xy`` (K, 2) at heights ``h`` (K,) above the post's ground, by
    Gauss-Newton (a numerical Jacobian of four columns) from ``start`` (4,); points off the
    surface by more than ``_OUTLIER_K`` RMS are left out once the fit has settled."""
    pts = np.column_stack([xy, h])
    x = start.copy()
    use = np.ones(len(xy), bool)
    for step in range(_GAUSS_NEWTON_STEPS):
        resid = _surface_distance(pts, x, radius)
        if step == _GAUSS_NEWTON_STEPS // 2:  # once, from a settled fit: drop the strays
            rms = float(np.sqrt(np.mean(resid[use] ** 2)))
            use &= np.abs(resid) <= _OUTLIER_K * max(rms, _NOISE_FLOOR_M)
        jac = np.empty((len(pts), 4))
        for j in range(4):  # four parameters
            dx = np.zeros(4)
            dx[j] = _JACOBIAN_STEP
            jac[:, j] = (_surface_distance(pts, x + dx, radius) - resid) / _JACOBIAN_STEP
        delta, *_ = np.linalg.lstsq(jac[use], -resid[use], rcond=None)
        x += delta
    return x


def _surface_distance(pts: np.ndarray, x: np.ndarray, radius: float) -> np.ndarray:
    """(K,) metres: signed distance of points ``pts`` (K, 3) (heights above the ground) from
    the cylinder of ``radius`` about the axis through (x[0], x[1], 0) along (x[2], x[3], 1)."""
    axis = np.array([x[2], x[3], 1.0])
    axis /= np.linalg.norm(axis)
    d = pts - np.array([x[0], x[1], 0.0])
    return np.linalg.norm(d - np.outer(d @ axis, axis), axis=1) - radius


def _run_axes(run: RunModel, k: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(2,) horizontal unit vectors along the run and toward the road at pole ``k``: the mean of
    the directions of the unit frames either side (one at an end; a post's own offset turns
    each of them a little, their mean hardly); None without frames."""
    if not run.units:
        return None, None
    frames = run.units[max(k - 1, 0) : k + 1] or run.units[-1:]
    along = np.sum([f.along[:2] for f in frames], axis=0)
    along /= np.linalg.norm(along)
    return along, np.array([along[1], -along[0]])  # toward the road: along x up


def missing_posts(
    run: RunModel, standard: Standard, params: ConditionParams = ConditionParams()
) -> SpacingCheck:
    """The posts missing between the seen posts of a run, and its spacing against the standard.

    Parameters
    ----------
    run : the run's reconstruction; poles with ``n_points > 0`` are the seen posts
    standard : the post spacing and its tolerance (``params.spacing_tolerance`` of the spacing
        where it states none)
    params : the gap rule (``missing_post_ratio``, ``spacing_tolerance``)

    Returns
    -------
    :class:`SpacingCheck`; a gap of g metres longer than ``missing_post_ratio`` spacings holds
    round(g / spacing) - 1 missing posts, evenly spaced on the chord between its seen posts.
    """
    seen = [k for k, p in enumerate(run.poles) if p.n_points > 0]
    nominal = standard.post_spacing_m
    tolerance = standard.post_spacing_tolerance_m
    if tolerance is None:
        tolerance = params.spacing_tolerance * nominal
    pos = np.array([run.poles[k].position for k in seen], np.float64).reshape(-1, 3)
    gaps = np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1)
    own = (
        run_spacing(gaps, params.spacing_tolerance, params.min_spacing_m) if len(gaps) >= 2 else 0.0
    )
    spacing = own if own > 0 else nominal
    compliant = None if own <= 0 else bool(abs(own - nominal) <= tolerance)
    station = np.concatenate([[0.0], np.cumsum(gaps)])
    missing = []
    for i, gap in enumerate(gaps):  # per gap between seen posts
        if gap <= params.missing_post_ratio * spacing:
            continue
        n = int(round(gap / spacing))
        for j in range(1, n):
            t = j / n
            missing.append(
                MissingPost(
                    station_m=float(station[i] + t * gap),
                    position=(1 - t) * pos[i] + t * pos[i + 1],
                    after_pole=seen[i],
                    gap_m=float(gap),
                )
            )
    return SpacingCheck(spacing, own, nominal, float(tolerance), compliant, tuple(missing))
