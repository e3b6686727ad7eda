"""Superimposition of unit shapes (§4.2): ICP recovers a known offset, rejects noise."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.errors import ReconstructionError
from guardrail_core.reconstruct.model import Pole
from guardrail_core.reconstruct.register import RegisterParams, superimpose
from guardrail_core.reconstruct.units import split_units, unit_points
from tests.reconstruct_fixtures import make_run


def _units(n_units=6, seed=0, **kw):
    run = make_run(n_units, rails=(0.15, 0.5, 0.86), balusters=True, seed=seed, **kw)
    poles = [Pole(p, run.pole_radius, run.pole_height, 80) for p in run.poles]
    pts, _ = unit_points(run.xyz, split_units(run.xyz, poles))
    return pts


def _moved(points, shift, angle_deg=0.0):
    a = np.radians(angle_deg)
    r = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return points @ r.T + shift


def test_icp_recovers_a_known_small_offset():
    units = _units()
    shift = np.array([0.012, -0.008, 0.01])
    units[2] = _moved(units[2], shift, angle_deg=0.3)
    # 1.8 cm is beyond the default bound of a pipe unit (5 mm) but within a beam unit's.
    sup = superimpose(units, RegisterParams(max_translation_m=0.03))
    assert sup.registered.all()
    # The correction maps the moved unit back: a unit point goes back to where it was.
    back = units[2] @ sup.transforms[2][:3, :3].T + sup.transforms[2][:3, 3]
    original = _moved(units[2] - shift, np.zeros(3), 0.0)
    a = np.radians(0.3)
    r = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    original = (units[2] - shift) @ r  # inverse rotation
    assert np.linalg.norm(back - original, axis=1).max() < 0.004
    # The other units needed (almost) nothing.
    others = np.delete(sup.transforms, 2, axis=0)
    assert np.abs(others[:, :3, 3]).max() < 0.006
    assert sup.points.shape == (sum(len(u) for u in units), 3)
    assert (np.bincount(sup.unit_of_point) == [len(u) for u in units]).all()


def test_reference_unit_mode():
    units = _units(seed=1)
    units[4] = units[4] + [0.0, 0.01, -0.01]
    sup = superimpose(units, RegisterParams(max_translation_m=0.03), reference=0)
    np.testing.assert_allclose(sup.transforms[0], np.eye(4))
    np.testing.assert_allclose(sup.transforms[4][:3, 3], [0.0, -0.01, 0.01], atol=0.004)


def test_unit_of_pure_noise_is_not_registered():
    units = _units(seed=2)
    rng = np.random.default_rng(0)
    units.append(rng.uniform([0, 0, -0.5], [2, 1, 0.5], (500, 3)))
    sup = superimpose(units)
    assert not sup.registered[-1]
    np.testing.assert_allclose(sup.transforms[-1], np.eye(4))
    assert sup.fitness[-1] < RegisterParams().min_fitness


def test_a_correction_beyond_the_bound_is_rejected():
    units = _units(seed=3)
    units[1] = units[1] + [0.025, 0.0, 0.0]  # 25 mm along the rails
    sup = superimpose(units, RegisterParams(max_translation_m=0.01))
    assert not sup.registered[1]
    np.testing.assert_allclose(sup.transforms[1], np.eye(4))


def test_one_unit_empty_units_and_tiny_units():
    units = _units(n_units=1, seed=4)
    sup = superimpose(units)
    assert sup.registered.tolist() == [False] and len(sup.points) == len(units[0])
    units = _units(n_units=3, seed=5) + [np.zeros((0, 3)), np.ones((3, 3))]
    sup = superimpose(units)
    assert sup.registered[:3].all() and not sup.registered[3:].any()
    assert len(sup.points) == sum(len(u) for u in units)
    assert superimpose([]).points.shape == (0, 3)


@pytest.mark.parametrize(
    ("units", "kwargs", "match"),
    [
        ([np.zeros((5, 2))], {}, r"unit_points\[0\] must have shape"),
        ([np.full((5, 3), np.nan)], {}, "NaN"),
        ([np.zeros((5, 3))], {"reference": 3}, "reference"),
    ],
)
def test_bad_input_raises(units, kwargs, match):
    with pytest.raises(ReconstructionError, match=match):
        superimpose(units, **kwargs)


def _beam_units(n_units=4, seed=0, n=3000):
    """Thrie-beam units as seen from above the road: upward-facing flanks and crest tops, with
    range noise along a downward ray. (n_units,) list of (N, 3) unit coordinates."""
    from guardrail_core.synth.designs import thrie_beam_section

    rng = np.random.default_rng(seed)
    s = thrie_beam_section()
    section = np.column_stack([0.1 + s[:, 0], 0.55 + s[:, 1]])  # (z, y)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(section, axis=0), axis=1))])
    units = []
    for _ in range(n_units):
        u = rng.uniform(0, cum[-1], n)
        z, y = np.interp(u, cum, section[:, 0]), np.interp(u, cum, section[:, 1])
        rising = np.interp(u + 1e-4, cum, section[:, 0]) > np.interp(u - 1e-4, cum, section[:, 0])
        seen = ~rising | (z > section[:, 0].max() - 0.01)
        pts = np.column_stack([rng.uniform(0.15, 1.85, n), y, z])[seen]
        units.append(pts + rng.normal(0, 0.005, (len(pts), 1)) * [0.0, -0.7, -0.7])
    return units


def test_a_beam_unit_keeps_its_x_and_is_corrected_across_only():
    units = _beam_units()
    units[2] = units[2] + [0.025, 0.003, -0.002]  # 25 mm along the beam, 3.6 mm across
    sup = superimpose(units, beam=True)
    assert sup.registered.all()
    # the slide along the beam is not undone (the section is the same all along), nor is any
    # other unit slid along it; across, the offset is
    assert np.all(sup.transforms[:, 0, 3] == 0.0)
    np.testing.assert_allclose(sup.transforms[2][1:3, 3], [-0.003, 0.002], atol=0.0015)


def test_a_beam_unit_further_off_across_than_the_bound_keeps_its_rough_alignment():
    units = _beam_units(seed=1)
    units[1] = units[1] + [0.0, 0.012, 0.0]
    sup = superimpose(units, beam=True)
    assert not sup.registered[1]
    np.testing.assert_allclose(sup.transforms[1], np.eye(4))
    wide = superimpose(units, RegisterParams(beam_max_translation_m=0.03), beam=True)
    assert wide.registered[1]
    assert abs(wide.transforms[1][1, 3] + 0.012) < 0.003
