"""Posts of a run: the lean of each post from its fitted axis, and posts missing where the
spacing breaks, on synthetic runs whose answers are exact."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.reconstruct.condition import (
    ConditionParams,
    load_standard,
    missing_posts,
    post_leans,
)
from guardrail_core.reconstruct.model import Pole, RunModel
from guardrail_core.reconstruct.unit_frame import UnitFrame

RADIUS = 0.05
HEIGHT = 0.9
#: Along the run is +x; the road is on the -y side (the unit frames' z = x × up).
TOWARD_ROAD = np.array([0.0, -1.0, 0.0])


def _post_points(base, along_deg, toward_deg, rng, noise=0.002, n=600):
    """(n, 3) points of a post whose axis leans by ``along_deg`` along +x and ``toward_deg``
    toward the road, standing on ``base`` (3,): the road-side half seen (±75°), as a scanner."""
    drift = (
        np.array([np.tan(np.radians(along_deg)), 0.0])
        + np.tan(np.radians(toward_deg)) * (TOWARD_ROAD[:2])
    )
    axis = np.array([*drift, 1.0])
    axis /= np.linalg.norm(axis)
    z = rng.uniform(0.0, HEIGHT, n)  # heights on the axis' own length, close enough
    s = z / axis[2]
    # The seen half faces the road: angles around the road direction (projected off the axis).
    road = TOWARD_ROAD - (TOWARD_ROAD @ axis) * axis
    road /= np.linalg.norm(road)
    side = np.cross(axis, road)
    a = rng.uniform(-np.radians(75), np.radians(75), n)
    r = RADIUS + rng.normal(0, noise, n)
    ring = np.cos(a)[:, None] * road + np.sin(a)[:, None] * side
    return base + s[:, None] * axis + r[:, None] * ring


def _rail_points(x0, x1, rng, offset=0.25, n=3000):
    """A rail plate on the road side, 0.45-0.75 m high, clear of the posts."""
    x = rng.uniform(x0, x1, n)
    z = rng.uniform(0.45, 0.75, n)
    return np.column_stack([x, np.full(n, -offset), z])


def _run(xs, seen=None, leans=None, seed=0):
    """A straight run with posts at ``xs``; ``leans`` {index: (along_deg, toward_deg)}."""
    rng = np.random.default_rng(seed)
    leans = leans or {}
    seen = [True] * len(xs) if seen is None else seen
    pts = [_rail_points(xs[0], xs[-1], rng)]
    poles = []
    for k, (x, is_seen) in enumerate(zip(xs, seen, strict=True)):
        base = np.array([x, 0.0, 0.0])
        along, toward = leans.get(k, (0.0, 0.0))
        if is_seen:
            pts.append(_post_points(base, along, toward, rng))
        # Pole detection fits a vertical cylinder: its xy is the leaning axis' at mid-height.
        drift = (
            np.array([np.tan(np.radians(along)), 0.0])
            + np.tan(np.radians(toward)) * (TOWARD_ROAD[:2])
        )
        position = np.array([*(base[:2] + drift * HEIGHT / 2), 0.0])
        poles.append(Pole(position, RADIUS, HEIGHT, 300 if is_seen else 0))
    frames = [
        UnitFrame.between(poles[i].position, poles[i + 1].position) for i in range(len(xs) - 1)
    ]
    run = RunModel(0, poles, frames, None, np.zeros(len(frames), bool), 0)
    return np.concatenate(pts), run


def test_a_post_tilted_5_degrees_toward_the_road_reads_5_degrees():
    xyz, run = _run([0.0, 1.905, 3.81], leans={1: (0.0, 5.0)})
    leans = post_leans(xyz, run, load_standard("mgs"))
    assert [p.index for p in leans] == [0, 1, 2]
    tilted = leans[1]
    assert tilted.lean_deg == pytest.approx(5.0, abs=0.1)
    assert tilted.toward_road_deg == pytest.approx(5.0, abs=0.1)
    assert tilted.along_deg == pytest.approx(0.0, abs=0.1)
    assert tilted.n_points >= 500
    # The MGS profile states no lean limit: the params' fallback (5°) applies, so 5° is borderline;
    # the upright posts read near 0 and are not flagged.
    assert tilted.limit_deg == ConditionParams().max_lean_deg
    for upright in (leans[0], leans[2]):
        assert upright.lean_deg < 0.3 and not upright.flagged


def test_a_lean_splits_into_along_the_run_and_toward_the_road():
    xyz, run = _run([0.0, 2.0, 4.0], leans={0: (3.0, -4.0), 2: (-8.0, 0.0)})
    leans = post_leans(xyz, run, params=ConditionParams(max_lean_deg=6.0))
    first, last = leans[0], leans[2]
    assert first.along_deg == pytest.approx(3.0, abs=0.15)
    assert first.toward_road_deg == pytest.approx(-4.0, abs=0.15)  # away from the road
    expected = np.degrees(np.arctan(np.hypot(np.tan(np.radians(3)), np.tan(np.radians(4)))))
    assert first.lean_deg == pytest.approx(expected, abs=0.15)
    assert not first.flagged
    assert last.lean_deg == pytest.approx(8.0, abs=0.15) and last.flagged
    assert last.along_deg == pytest.approx(-8.0, abs=0.15)


def test_unseen_posts_get_no_lean_and_a_post_without_points_gets_nan():
    xyz, run = _run([0.0, 2.0, 4.0, 6.0], seen=[True, False, True, True])
    leans = post_leans(xyz, run)
    assert [p.index for p in leans] == [0, 2, 3]
    empty = post_leans(np.zeros((0, 3)), run)
    assert all(np.isnan(p.lean_deg) and not p.flagged for p in empty)


def _pole(x, seen=True):
    return Pole(np.array([x, 0.0, 0.0]), RADIUS, HEIGHT, 100 if seen else 0)


def _model(poles):
    frames = [
        UnitFrame.between(poles[i].position, poles[i + 1].position) for i in range(len(poles) - 1)
    ]
    return RunModel(0, poles, frames, None, np.zeros(len(frames), bool), 0)


def test_a_gap_of_two_spacings_reports_one_missing_post_at_its_middle():
    s = 1.905
    xs = [0.0, s, 2 * s, 4 * s, 5 * s, 6 * s]  # the post at 3 s is missing
    check = missing_posts(_model([_pole(x) for x in xs]), load_standard("mgs"))
    assert len(check.missing) == 1
    post = check.missing[0]
    assert post.station_m == pytest.approx(3 * s)
    np.testing.assert_allclose(post.position, [3 * s, 0.0, 0.0], atol=1e-12)
    assert post.after_pole == 2 and post.gap_m == pytest.approx(2 * s)
    assert check.run_spacing_m == pytest.approx(s) and check.compliant is True
    # The reconstruction inserted a virtual pole there (no points): the same answer.
    with_virtual = [_pole(x) for x in xs[:3]] + [_pole(3 * s, seen=False)]
    with_virtual += [_pole(x) for x in xs[3:]]
    again = missing_posts(_model(with_virtual), load_standard("mgs"))
    assert [m.station_m for m in again.missing] == pytest.approx([3 * s])


def test_a_gap_of_three_spacings_has_two_missing_posts_and_a_wrong_spacing_is_reported():
    xs = [0.0, 2.5, 5.0, 12.5, 15.0]  # 2.5 m posts against MGS's 1.905 m; 5 to 12.5 m: 2 missing
    check = missing_posts(_model([_pole(x) for x in xs]), load_standard("mgs"))
    assert [m.station_m for m in check.missing] == pytest.approx([7.5, 10.0])
    assert check.spacing_m == pytest.approx(2.5)  # the run's own spacing places them
    # 2.5 m is beyond the fallback tolerance (8 % of 1.905 m, 0.15 m) of the standard's spacing.
    assert check.tolerance_m == pytest.approx(0.08 * 1.905)
    assert check.compliant is False
    # Two seen posts give one gap: the run's spacing is unknown, the standard's places them.
    two = missing_posts(_model([_pole(0.0), _pole(3 * 1.905)]), load_standard("mgs"))
    assert two.compliant is None
    assert [m.station_m for m in two.missing] == pytest.approx([1.905, 3.81])


def test_a_blockout_beside_the_post_does_not_tilt_its_axis():
    xyz, run = _run([0.0, 2.0, 4.0], leans={1: (0.0, 5.0)}, seed=3)
    # A blockout's face: points on the road side of the tilted post, 0.5-0.65 m high, inside
    # the reach around its axis; its sections fit circles pulled toward the road.
    rng = np.random.default_rng(4)
    z = rng.uniform(0.5, 0.65, 200)
    drift = np.tan(np.radians(5.0)) * z
    blob = np.column_stack([2.0 + rng.uniform(-0.04, 0.04, 200), -(drift + 0.09), z])
    leans = post_leans(np.concatenate([xyz, blob]), run)
    assert leans[1].lean_deg == pytest.approx(5.0, abs=0.3)


def test_the_reconstruction_of_a_synthetic_run_reads_upright_posts_a_missing_one_and_its_rail():
    from guardrail_core.reconstruct.condition import rail_heights
    from guardrail_core.reconstruct.condition.standards import standard_from_mapping
    from guardrail_core.reconstruct.pipeline import reconstruct_run
    from tests.reconstruct_fixtures import make_run

    synth = make_run(6, spacing=2.0, missing=(3,), seed=5)
    run, _ = reconstruct_run(synth.xyz, synth.ground, synth.toward_road, run_id=0)
    assert [p.n_points > 0 for p in run.poles] == [True] * 3 + [False] + [True] * 3
    leans = post_leans(synth.xyz, run)
    assert len(leans) == 6 and all(p.lean_deg < 1.0 for p in leans)
    pipe_rail = standard_from_mapping(
        {
            "name": "pipe-rail",
            "title": "a test's pipe railing",
            "source": "tests/reconstruct_fixtures.py: rails at 0.4 and 0.76 m, radius 24.3 mm",
            "notes": "none",
            "verified": True,
            "rail_top_nominal_m": 0.784,
            "rail_top_min_m": 0.77,
            "rail_top_max_m": 0.80,
            "rail_height_tolerance_m": 0.01,
            "post_spacing_m": 2.0,
            "post_spacing_tolerance_m": 0.05,
            "max_post_lean_deg": 2.0,
            "dent_depth_tolerance_m": None,
        }
    )
    check = missing_posts(run, pipe_rail)
    assert [m.station_m for m in check.missing] == pytest.approx([6.0], abs=0.05)
    assert check.compliant is True
    # The rail's top is seen up to 75° around the pipe: 0.76 + 0.0243 sin 75° = 0.7835 m.
    segments = rail_heights(synth.xyz, synth.ground, run, pipe_rail)
    assert len(segments) == 2
    for s in segments:
        assert s.road_source == "road points" and s.compliant
        assert s.median_m == pytest.approx(0.7835, abs=0.006)
