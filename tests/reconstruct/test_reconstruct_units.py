"""Runs (grouping) and units (§4.1): ordering, one unit, missing poles, curved runs, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.errors import ReconstructionError
from guardrail_core.reconstruct.model import Pole
from guardrail_core.reconstruct.poles import detect_poles
from guardrail_core.reconstruct.runs import RunParams, _closest_voxels, group_runs
from guardrail_core.reconstruct.units import (
    UnitParams,
    order_poles,
    run_spacing,
    split_units,
    unit_points,
)
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


def test_a_run_one_slice_cut_in_two_is_one_run_but_not_with_a_guardrail_of_other_heights():
    # A slice called other (0.5 m: a shrub against the rails) cut a guardrail in two: its
    # pieces stand on one line with the same heights, and are one run again.
    xyz = make_run(4, seed=6).xyz
    cut = xyz[(xyz[:, 0] < 14.2) | (xyz[:, 0] > 14.7)]
    assert np.unique(group_runs(cut)).tolist() == [0]
    assert np.unique(group_runs(cut, RunParams(bridge_m=0.0))).tolist() == [0, 1]
    # A railing 0.2 m higher beyond the same gap after the guardrail's end (an arch fence
    # after a W-beam) stays a run of its own, and so does one 0.5 m beside the line.
    higher = make_run(2, rails=(0.6, 0.95), pole_height=1.0, seed=7).xyz + [8.5, 0.0, 0.16]
    beside = make_run(2, seed=8).xyz + [8.5, 0.5, 0.16]
    for other in (higher, beside):
        run = group_runs(np.concatenate([xyz, other]))
        assert np.unique(run[: len(xyz)]).tolist() == [0]
        assert np.unique(run[len(xyz) :]).tolist() == [1]
    # Without the gap cut, the same railing beyond it is the guardrail's continuation.
    same = make_run(2, seed=9).xyz + [8.5, 0.0, 0.16]
    assert np.unique(group_runs(np.concatenate([xyz, same]))).tolist() == [0]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_closest_voxels_of_two_runs_are_those_every_pair_of_voxels_gives(seed):
    # The bridge looks for each pair of components' closest voxels in cells of its reach, not
    # among every pair of voxels within it (4 GB for 2.8 million points): the same pairs.
    rng = np.random.default_rng(seed)
    centroids = rng.uniform(0.0, 6.0, (400, 3)) * [1.0, 1.0, 0.3]
    comp = rng.integers(0, 12, 400)
    reach = 0.8
    got = _closest_voxels(centroids, comp, reach)
    d = np.linalg.norm(centroids[:, None] - centroids[None], axis=2)
    expected = {}
    for a, b in zip(*np.nonzero((d <= reach) & (comp[:, None] < comp[None])), strict=True):
        pair = (int(comp[a]), int(comp[b]))
        if pair not in expected or d[a, b] < d[expected[pair]]:
            expected[pair] = (int(a), int(b))
    assert got == [expected[pair] for pair in sorted(expected)]
    assert len(got) > 20


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


def test_what_stands_behind_the_poles_belongs_to_no_unit():
    # A hedge 0.3 m behind the pole plane that the classifier called guardrail is no part of
    # the units; a post's back (0.04 m behind) and a rail bowing 0.1 m behind are.
    run = make_run(2, seed=9)
    poles = _poles(run)
    frame_normal = -run.toward_road / np.linalg.norm(run.toward_road)  # away from the road
    middle = (run.poles[0] + run.poles[1]) / 2 + [0.0, 0.0, 0.5]
    behind = middle + np.outer([0.04, 0.1, 0.3, 0.6], frame_normal)
    split = split_units(np.concatenate([run.xyz, behind]), order_poles(poles, run.toward_road))
    assert split.unit_of_point[-4:].tolist() == [0, 0, -1, -1]
    assert (split.unit_of_point[: len(run.xyz)] >= 0).all()
    anywhere = UnitParams(max_behind_m=1.0)
    split = split_units(
        np.concatenate([run.xyz, behind]), order_poles(poles, run.toward_road), anywhere
    )
    assert split.unit_of_point[-4:].tolist() == [0, 0, 0, 0]


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


def test_the_spacing_is_the_gap_most_gaps_are_multiples_of():
    # Missed poles make gaps of two or three spacings; a false pole two odd ones.
    assert run_spacing(np.array([4.0, 8.0, 4.01, 12.0]), 0.08) == pytest.approx(4.0)
    assert run_spacing(np.array([2.0, 0.7, 1.3, 2.0, 2.0]), 0.08) == pytest.approx(2.0)
    # The KITTI motorway's W-beam: a delineator 7.9 m before the posts 4.2 m apart. The median
    # of the gaps made the spacing 6.0 m.
    assert run_spacing(np.array([7.86, 4.23]), 0.08) == pytest.approx(4.23)
    assert run_spacing(np.array([8.0, 8.0]), 0.08) == pytest.approx(8.0)  # every other missed


def test_a_gap_shorter_than_any_railing_spacing_is_never_the_spacing():
    # A W-beam run of a development street: two stems of a hedge behind it passed for posts,
    # 1.01 m apart; 1.01 m divides the posts' 2 m gaps, so it won, and every 2 m gap got a
    # virtual pole in its middle.
    gaps = np.array([2.0, 2.0, 1.76, 1.63, 1.01, 1.67, 2.0, 4.0, 2.0])
    assert run_spacing(gaps, 0.08) == pytest.approx(1.01)
    assert run_spacing(gaps, 0.08, UnitParams().min_spacing_m) == pytest.approx(2.0)
    assert run_spacing(np.array([0.9, 1.1]), 0.08, 1.5) == 0.0  # no spacing at all


def test_false_poles_a_metre_apart_put_no_pole_in_the_run_gaps():
    run = make_run(6, seed=12)
    poles = order_poles(_poles(run), run.toward_road)
    start, step = poles[2].position, poles[3].position - poles[2].position
    # Two hedge stems between posts 2 and 3, 0.45 and 1.45 m along, and posts 4 and 5 missed.
    stems = [Pole(start + t * step, run.pole_radius, 0.8, 30) for t in (0.225, 0.725)]
    kept = [*poles[:3], *stems, poles[3], poles[6]]
    split = split_units(run.xyz, kept)
    # The 4 m gap between posts 3 and 6 takes the two posts missed there, and no other.
    assert split.virtual.sum() == 2
    virtual = np.array([p.position for p, v in zip(split.poles, split.virtual, strict=True) if v])
    off = np.linalg.norm(run.poles[None, :, :2] - virtual[:, None, :2], axis=2).min(axis=1)
    assert off.max() < 0.01
    # With no floor the stems' 1 m gap is the spacing: a virtual pole in each 2 m gap and five
    # in the 6 m one.
    split = split_units(run.xyz, kept, UnitParams(min_spacing_m=0.0))
    assert split.virtual.sum() == 1 + 1 + 5


def test_an_end_pole_off_the_spacing_is_no_post():
    run = make_run(3, spacing=4.0, seed=10)
    poles = order_poles(_poles(run), run.toward_road)
    start, step = poles[0].position, poles[1].position - poles[0].position
    # A delineator post on the rail's line 3.6 m before the first post (0.9 spacings).
    delineator = Pole(start - 0.9 * step, run.pole_radius, run.pole_height, 30)
    split = split_units(run.xyz, [delineator, *poles])
    assert len(split.poles) == 4 and not split.virtual.any()
    np.testing.assert_allclose([f.length for f in split.frames], 4.0, atol=0.02)
    assert not any(np.allclose(p.position, delineator.position) for p in split.poles)
    assert "no post" in split.notes[0]
    # Two spacings before it, it is a post with one missed between.
    post = Pole(start - 2.0 * step, run.pole_radius, run.pole_height, 30)
    split = split_units(run.xyz, [post, *poles])
    assert len(split.poles) == 6 and split.virtual.sum() == 1
    # Two poles both stay, whatever their gap: nothing tells which is off.
    split = split_units(run.xyz, [delineator, poles[0]])
    seen = [p.position for p, v in zip(split.poles, split.virtual, strict=True) if not v]
    np.testing.assert_allclose(seen, [delineator.position, poles[0].position])


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


@pytest.mark.parametrize("arc", [None, 30.0])
def test_the_rail_beyond_the_end_poles_gets_poles_at_the_spacing(arc):
    # A sparse scan sees the last three poles of a run of six units no more, but their rails.
    run = make_run(6, arc_radius=arc, missing=(4, 5, 6), seed=21)
    truth = make_run(6, arc_radius=arc, seed=21).poles
    det = detect_poles(run.xyz, run.ground)
    assert len(det.poles) == 4
    split = split_units(run.xyz, order_poles(det.poles, run.toward_road))
    assert len(split.frames) == 6 and split.extrapolated.sum() == 3
    np.testing.assert_array_equal(split.anchored, [True] * 3 + [False] * 3)
    assert "beyond the end poles" in " ".join(split.notes)
    placed = np.array([p.position for p in split.poles])
    order = np.argsort(np.linalg.norm(truth[:, :2] - placed[0, :2], axis=1))
    placed = placed if order[0] == 0 else placed[::-1]
    error = np.linalg.norm(placed - truth, axis=1)
    assert error[:4].max() < 0.01  # detected
    assert error[4:].max() < 0.05  # placed along the rail (0.5 % of the 6 m extrapolated)
    # Every rail point has its unit.
    assert (split.unit_of_point[~run.is_pole] >= 0).all()
    off = split_units(
        run.xyz, order_poles(det.poles, run.toward_road), UnitParams(min_extension_points=0)
    )
    assert len(off.frames) == 3 and not off.extrapolated.any()


def test_uneven_ground_under_the_poles_follows_the_rail():
    run = make_run(4, seed=22)
    poles = _poles(run)
    bumps = [0.05, -0.04, 0.03, 0.0, -0.05]  # a verge measured 5 cm high or low
    uneven = [
        Pole(p.position + [0.0, 0.0, b], p.radius, p.height - b, p.n_points)
        for p, b in zip(poles, bumps, strict=True)
    ]
    rails = run.xyz[~run.is_pole]
    split = split_units(rails, uneven)
    got = np.array([p.position for p in split.poles])
    assert np.abs(got - run.poles).max() < 0.01  # back on the ground the rail stands on
    np.testing.assert_allclose([p.height for p in split.poles], run.pole_height, atol=0.01)
    assert "uneven ground" in " ".join(split.notes)
    # Within the tolerance (measurement noise) the measured ground stays.
    slight = [
        Pole(p.position + [0.0, 0.0, b / 5], p.radius, p.height, p.n_points)
        for p, b in zip(poles, bumps, strict=True)
    ]
    kept = split_units(rails, slight)
    np.testing.assert_array_equal([p.position for p in kept.poles], [p.position for p in slight])
    assert kept.notes == ()


def test_a_rail_unseen_near_one_pole_leaves_the_measured_ground():
    # Across the street the top rail went unseen for the first metre: there the rail's top
    # reads 0.36 m low. The grounds measured at the poles lie on one line, the rail tops do
    # not, so the rail is what is uneven and no pole is moved.
    run = make_run(4, seed=23)
    rails = run.xyz[~run.is_pole]
    near_first = np.linalg.norm(rails[:, :2] - run.poles[0, :2], axis=1) < 1.0
    top_rail = rails[:, 2] - np.interp(rails[:, 0], run.poles[:, 0], run.poles[:, 2]) > 0.6
    rails = rails[~(near_first & top_rail)]
    split = split_units(rails, _poles(run))
    np.testing.assert_array_equal([p.position for p in split.poles], run.poles)
    assert "uneven ground" not in " ".join(split.notes)
    # With the same rails, grounds off their line (a verge under two poles) follow the rail.
    bumps = [0.0, 0.06, -0.05, 0.0, 0.0]
    uneven = [
        Pole(p.position + [0.0, 0.0, b], p.radius, p.height - b, p.n_points)
        for p, b in zip(_poles(run), bumps, strict=True)
    ]
    got = np.array([p.position for p in split_units(rails, uneven).poles])
    assert np.abs(got[1:3] - run.poles[1:3]).max() < 0.01


def test_clutter_across_the_run_beyond_its_end_places_no_pole():
    # A bush 1.0-1.3 m beyond the last pole, 2 m across the run: its points run across, not on.
    run = make_run(3, grade=0.0, seed=23)
    rng = np.random.default_rng(23)
    along = (run.poles[-1] - run.poles[-2]) / np.linalg.norm(run.poles[-1] - run.poles[-2])
    n = 300
    bush = (
        run.poles[-1]
        + rng.uniform(1.0, 1.3, (n, 1)) * along
        + rng.uniform(-1.0, 1.0, (n, 1)) * run.toward_road
        + rng.uniform(0.2, 0.9, (n, 1)) * [0.0, 0.0, 1.0]
    )
    split = split_units(np.vstack([run.xyz[~run.is_pole], bush]), _poles(run))
    assert len(split.frames) == 3 and not split.extrapolated.any()
