"""Taubin's lambda|mu filter (Taubin 1995; Matsumoto et al. 2019, §4.3)."""

import numpy as np
import pytest

from guardrail_core.errors import ReconstructionError
from guardrail_core.reconstruct.smoothing import taubin_smooth


def _roughness(p: np.ndarray) -> float:
    return float(np.abs(p[:-2] - 2 * p[1:-1] + p[2:]).mean())


def test_straight_line_stays_straight_and_ends_fixed():
    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0, 2, 50))
    line = np.column_stack([t, 0.3 + 0.25 * t, np.full_like(t, 0.01)])
    out = taubin_smooth(line, iterations=20)
    d = np.array([1.0, 0.25, 0.0]) / np.linalg.norm([1.0, 0.25, 0.0])
    rel = out - line[0]
    off_line = np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)
    assert off_line.max() < 1e-12
    np.testing.assert_array_equal(out[[0, -1]], line[[0, -1]])


def test_noisy_polyline_gets_smoother_without_shrinking():
    rng = np.random.default_rng(1)
    x = np.linspace(0, 2, 80)
    clean = np.column_stack([x, 0.5 + 0.2 * np.sin(2 * np.pi * x)])
    noisy = clean + rng.normal(0, 0.005, clean.shape)
    out = taubin_smooth(noisy, iterations=10)
    assert _roughness(out) < 0.35 * _roughness(noisy)
    assert np.abs(out - clean).mean() < np.abs(noisy - clean).mean()
    # the low-pass filter keeps the wave's amplitude (plain Laplacian smoothing would shrink it)
    assert np.ptp(out[:, 1]) > 0.95 * np.ptp(clean[:, 1])


def test_free_ends_move_and_input_is_not_modified():
    p = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 0.0], [3.0, 1.0]])
    keep = p.copy()
    out = taubin_smooth(p, fix_ends=False, iterations=3)
    np.testing.assert_array_equal(p, keep)
    assert not np.allclose(out[0], p[0])


def test_short_polylines_come_back_unchanged():
    p = np.array([[0.0, 1.0], [2.0, 3.0]])
    np.testing.assert_array_equal(taubin_smooth(p), p)


@pytest.mark.parametrize(
    ("poly", "kwargs"),
    [
        (np.array([[0.0, np.nan], [1.0, 1.0], [2.0, 2.0]]), {}),
        (np.zeros(5), {}),
        (np.zeros((5, 2)), {"lam": 0.0}),
        (np.zeros((5, 2)), {"mu": -0.1}),
        (np.zeros((5, 2)), {"iterations": -1}),
    ],
)
def test_bad_input_raises(poly, kwargs):
    with pytest.raises(ReconstructionError):
        taubin_smooth(poly, **kwargs)
