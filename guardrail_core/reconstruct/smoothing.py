"""Taubin's lambda|mu low-pass filter for polylines (Matsumoto et al. 2019, §4.3).

The skeletons of §4.3 (slice centres joined into polylines) and the section curves of §4.4 are
noisy; the paper smooths them with the low-pass filter of Taubin (1995). One iteration is two
Laplacian steps, a shrinking one with ``lam > 0`` and an inflating one with ``mu < -lam``, so
that low frequencies pass and the curve does not shrink the way plain Laplacian smoothing does.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.errors import ReconstructionError


def taubin_smooth(
    polyline: np.ndarray,
    *,
    lam: float = 0.5,
    mu: float = -0.53,
    iterations: int = 10,
    fix_ends: bool = True,
) -> np.ndarray:
    """Smooth an open polyline with Taubin's lambda|mu filter.

    Parameters
    ----------
    polyline : (K, D) float64
        Vertices in order, any units (metres here).
    lam : float
        Positive (shrinking) step factor, 0 < lam < 1.
    mu : float
        Negative (inflating) step factor, mu < -lam.
    iterations : int
        Number of lambda|mu pairs, >= 0.
    fix_ends : bool
        Keep the first and the last vertex where they are (otherwise an end vertex moves toward
        its single neighbour, with the umbrella operator of a path end).

    Returns
    -------
    (K, D) float64
        The smoothed polyline; a copy (polylines of fewer than 3 vertices come back unchanged).

    Raises
    ------
    ReconstructionError
        If the polyline is not 2-D or holds NaN/inf, or the factors are out of range.

    References
    ----------
    Taubin, G. (1995). A signal processing approach to fair surface design. SIGGRAPH '95, 351-358.
    Matsumoto, Mori, Masuda (2019). Extraction and shape reconstruction of guardrails using
    mobile mapping data. ISPRS Archives XLII-2/W13, §4.3 (low-pass filter of skeletons).
    """
    p = np.array(polyline, dtype=np.float64, copy=True)
    if p.ndim != 2:
        raise ReconstructionError(f"polyline must be a (K, D) array, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ReconstructionError("polyline holds NaN or infinite coordinates")
    if not 0.0 < lam < 1.0:
        raise ReconstructionError(f"lam must be in (0, 1), got {lam}")
    if not mu < -lam:
        raise ReconstructionError(f"mu must be below -lam = {-lam}, got {mu}")
    if iterations < 0:
        raise ReconstructionError(f"iterations must be >= 0, got {iterations}")
    if len(p) < 3:
        return p
    for _ in range(int(iterations)):
        for factor in (lam, mu):
            lap = np.zeros_like(p)
            # Umbrella operator: mean of the neighbours minus the vertex.
            lap[1:-1] = 0.5 * (p[:-2] + p[2:]) - p[1:-1]
            if not fix_ends:
                lap[0] = p[1] - p[0]
                lap[-1] = p[-2] - p[-1]
            p = p + factor * lap
    return p
