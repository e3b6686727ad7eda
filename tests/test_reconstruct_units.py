"""Runs (grouping) and units (§4.1): ordering, one unit, missing poles, curved runs, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.errors import ReconstructionError
from guardrail_core.reconstruct.model import Pole
from guardrail_core.reconstruct.poles import detect_poles
from guardrail_core.reconstruct.runs import RunParams, group_runs
from guardrail_core.reconstruct.units import order_poles, split_units, unit_points
from tests.reconstruct_fixtures import make_run


def _poles(run):
    return [Pole(p.copy(), run.pole_radius, run.pole_height, 80) for p in run.poles]


def test_group_runs_separates_runs_and_drops_specks():
    a = make_run(3, seed=1).xyz
    b = make_run(2, seed=2).xyz + [0.0, 5.0, 0.0]  # another guardrail 5 m away
    speck = np.random.default_rng(0).normal([30.0, 30.0, 1.0], 0.05, (20, 3))
    run = group_runs(np.concatenate([a, b, speck]))
    assert run.dtype == np.int32
    assert set(np.unique(run[: len(a)])) == {0}  # numbered by first point
    assert set(np.unique(run[len(a) : len(a) + len(b)])) == {1}
    assert (run[len(a) + len(b) :] == -1).all()


def test_group_runs_drops_short_groups_and_checks_input():
    short = make_run(1, spacing=1.0, seed=3).xyz  # 1 m long
    assert (group_runs(short, RunParams(min_length_m=1.5)) == -1).all()
    assert group_runs(np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ReconstructionError, match="NaN"):
        group_runs(np.array([[0.0, np.inf, 0.0]]))
    with pytest.raises(ReconstructionError, match="shape"):
        group_runs(np.zeros((4, 2)))


@pytest.mark.parametrize("arc", [None, 20.0])
def test_order_poles_puts_the_road_on_plus_z(arc):
    run = make_run(4, arc_radius=arc, seed=4)
    shuffled = [_poles(run)[i] for i in (3, 0, 4, 1, 2)]
    for toward in (run.toward_road, -run.toward_road):
        ordered = order_poles(shuffled, toward)
        split = split_units(run.xyz, ordered)
        assert all(f.normal @ toward > 0 for f in split.frames)
        x = np.array([p.position for p in ordered])
        steps = np.linalg.norm(np.diff(x[:, :2], axis=0), axis=1)
        np.testing.assert_allclose(steps, 2.0, atol=0.01)  # consecutive neighbours (chords)


def test_order_poles_checks_the_direction():
    with pytest.raises(ReconstructionError, match="horizontal"):
        order_poles([], np.array([0.0, 0.0, 1.0]))
    with pytest.raises(ReconstructionError, match=r"\(3,\)"):
        order_poles([], np.array([1.0, 0.0]))


def test_one_unit_run():
    run = make_run(1, seed=5)
    det = detect_poles(run.xyz, run.ground)
    poles = order_poles(det.poles, run.toward_road)
    far = np.array([[100.0, 100.0, 1.0]])
    split = split_units(np.concatenate([run.xyz, far]), poles)
    assert len(split.frames) == 1 and split.notes == ()
    assert abs(split.frames[0].length - 2.0) < 0.01
    assert (split.unit_of_point[:-1] == 0).all() and split.unit_of_point[-1] == -1


def test_no_unit_without_two_poles():
    run = make_run(1, seed=6)
    split = split_units(run.xyz, _poles(run)[:1])
    assert split.frames == [] and (split.unit_of_point == -1).all() and split.notes


def test_missing_pole_is_inserted_at_the_spacing():
    run = make_run(5, missing=(3,), seed=7)  # pole 3 has no points
    det = detect_poles(run.xyz, run.ground)
    assert len(det.poles) == 5
    split = split_units(run.xyz, order_poles(det.poles, run.toward_road))
    assert len(split.frames) == 5
    np.testing.assert_allclose([f.length for f in split.frames], 2.0, atol=0.02)
    assert split.virtual.sum() == 1 and "missing" in split.notes[0]
    # The virtual pole stands where the true one was (straight run).
    truth = make_run(5, seed=7).poles
    v = split.poles[int(np.flatnonzero(split.virtual)[0])].position
    assert np.linalg.norm(truth[:, :2] - v[:2], axis=1).min() < 0.01


def test_curved_run_units_follow_the_curve():
    run = make_run(6, arc_radius=15.0, seed=8)
    det = detect_poles(run.xyz, run.ground)
    split = split_units(run.xyz, order_poles(det.poles, run.toward_road))
    assert len(split.frames) == 6
    pts, idx = unit_points(run.xyz, split)
    assert sum(len(i) for i in idx) == (split.unit_of_point >= 0).sum() == len(run.xyz)
    for p, i, f in zip(pts, idx, split.frames, strict=True):
        np.testing.assert_allclose(p, f.to_unit(run.xyz[i]))
        rails = p[~run.is_pole[i]]
        # Rails lie on the pole plane of their own unit: z within radius + noise, x within range.
        assert np.abs(rails[:, 2]).max() < 0.05
        assert rails[:, 0].min() > -0.05 and rails[:, 0].max() < f.length + 0.05
        # The two rails at their heights above the ground line.
        assert np.abs(np.abs(rails[:, 1] - 0.58) - 0.18).max() < 0.05


def test_unit_points_checks_lengths():
    run = make_run(1, seed=9)
    split = split_units(run.xyz, _poles(run))
    with pytest.raises(ReconstructionError, match="points"):
        unit_points(run.xyz[:10], split)
