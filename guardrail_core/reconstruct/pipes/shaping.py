"""A chain of slice centres shaped into a skeleton (§4.3): Taubin's low-pass filter, a straight
line fitted when nearly straight, snapped horizontal or vertical when nearly so."""

from __future__ import annotations

import math

import numpy as np

from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.polylines import fit_line
from guardrail_core.reconstruct.pipes.skeleton import Chain, PipeKind, Skeleton
from guardrail_core.reconstruct.smoothing import taubin_smooth


def shape_chain(chain: Chain, idx: np.ndarray, pts: np.ndarray, p: PipeParams) -> Skeleton:
    """The skeleton of a chain of centres whose components hold the points ``idx`` (M,) of
    ``pts`` (N, 3), unit coordinates, metres.

    References
    ----------
    Taubin, G. (1995). A signal processing approach to fair surface design. SIGGRAPH '95.
    """
    smooth = taubin_smooth(
        chain.centres, lam=p.taubin_lambda, mu=p.taubin_mu, iterations=p.taubin_iterations
    )
    xy, kind = straight_or_curved(smooth, chain.shared, chain.own, idx, pts, p)
    return Skeleton(xy=xy, kind=kind, idx=idx, chain=chain)


def straight_or_curved(
    smooth: np.ndarray,
    shared: np.ndarray,
    own_idx: np.ndarray,
    idx: np.ndarray,
    pts: np.ndarray,
    p: PipeParams,
) -> tuple[np.ndarray, PipeKind]:
    """A smoothed polyline kept as it is ("curved"), or, when straight, the line fitted to its
    own points snapped horizontal or vertical when nearly so.

    Parameters
    ----------
    smooth : (K, 2) float64, unit (x, y), metres: the smoothed centres
    shared : (K,) bool, centres shared with another chain (they do not decide straightness)
    own_idx, idx : (M,) int64, indices into ``pts`` of the chain's own points and of all of
        its points (the line is fitted to the own ones where there are two)

    Returns
    -------
    The skeleton, (K, 2) curved or (2, 2) straight, and its kind.
    """
    fit_on = smooth[~shared] if (~shared).sum() >= 2 else smooth
    c, d = fit_line(fit_on)
    normal = np.array([-d[1], d[0]])
    dev = np.abs((smooth - c) @ normal)
    if np.quantile(dev, p.straight_share) > p.straight_tolerance_m:
        return smooth, "curved"
    # Straight: fit the line to the pipe's own points (components not shared at crossings),
    # then again to those near it (a joining pipe's points pull the first fit).
    pxy = pts[own_idx if len(own_idx) >= 2 else idx, :2]
    c2, d2 = fit_line(pxy)
    off = (pxy - c2) @ np.array([-d2[1], d2[0]])
    reach = np.quantile(np.abs(off), p.straight_fit_quantile)
    keep = np.abs(off) <= reach + p.link_distance_m * p.straight_fit_margin
    if keep.sum() >= 2:
        c2, d2 = fit_line(pxy[keep])
    angle = math.degrees(math.atan2(abs(d2[1]), abs(d2[0])))
    t = (smooth - c2) @ d2
    kind: PipeKind
    if angle <= p.horizontal_angle_deg:
        kind = "horizontal"
        d2 = np.array([1.0, 0.0])
        t = smooth[:, 0] - c2[0]
    elif angle >= 90.0 - p.vertical_angle_deg:
        kind = "vertical"
        d2 = np.array([0.0, 1.0])
        t = smooth[:, 1] - c2[1]
    else:
        kind = "diagonal"
    return c2 + np.outer([t.min(), t.max()], d2), kind
