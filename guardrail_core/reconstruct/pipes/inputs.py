"""Checks of what the pipe reconstruction is given (points, unit length, pole radius)."""

from __future__ import annotations

import math

import numpy as np

from guardrail_core.errors import ReconstructionError


def check_unit_points(points: np.ndarray, name: str = "points") -> np.ndarray:
    """Validate an (N, 3) array of finite unit coordinates; return it as float64.

    Raises
    ------
    ReconstructionError
        Not numbers, not of shape (N, 3), or NaN / infinite coordinates.
    """
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ReconstructionError(f"{name} must be an (N, 3) array of numbers: {exc}") from exc
    if p.ndim != 2 or p.shape[1] != 3:
        raise ReconstructionError(f"{name} must have shape (N, 3) (unit x, y, z), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ReconstructionError(f"{name} holds NaN or infinite coordinates")
    return p


def check_length(value: float, name: str, *, positive: bool) -> float:
    """``value`` as a finite float, > 0 (``positive``) or >= 0; else :class:`ReconstructionError`."""
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ReconstructionError(f"{name} must be a number, got {value!r}") from exc
    if not math.isfinite(v) or (v <= 0 if positive else v < 0):
        raise ReconstructionError(f"{name} must be {'> 0' if positive else '>= 0'}, got {value!r}")
    return v
