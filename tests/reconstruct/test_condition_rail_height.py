"""Rail-top height above the local road per segment along a run, on synthetic runs whose answers
are exact: a W-beam lowered by 40 mm reads 747 mm against the MGS's 787 mm and fails."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.reconstruct.condition import ConditionParams, load_standard, rail_heights
from guardrail_core.reconstruct.condition.rail_height import POLES_GROUND, ROAD_POINTS
from guardrail_core.reconstruct.model import Pole, RunModel, UnitModel
from guardrail_core.reconstruct.unit_frame import UnitFrame

SPACING = 1.905
#: Along the run is +x; the road is on the -y side (offset toward the road = -y).
RAIL_OFFSET = 0.2


def _road_z(x, offset, crossfall):
    return 0.05 + crossfall * offset + 0.0 * x


def _scene(top_above_road, *, length=19.05, crossfall=0.0, road=True, skip=None, model=None):
    """Posts every MGS spacing on the verge (ground z 0), a W-beam whose top stands
    ``top_above_road`` above the road at the beam's face (offset ``RAIL_OFFSET``), and road
    points 0.5-3 m toward the road, ``0.05 + crossfall * offset`` high. ``skip`` (x0, x1): no
    rail points there."""
    xs = np.arange(0.0, length + 1e-9, SPACING)
    poles = [Pole(np.array([x, 0.0, 0.0]), 0.05, 0.7, 100) for x in xs]
    frames = [
        UnitFrame.between(poles[i].position, poles[i + 1].position) for i in range(len(xs) - 1)
    ]
    run = RunModel(0, poles, frames, model, np.zeros(len(frames), bool), 0)
    top = _road_z(0.0, RAIL_OFFSET, crossfall) + top_above_road
    gx, gz = np.meshgrid(np.arange(0.0, length, 0.02), np.arange(0.0, 0.31, 0.01))
    gz = top - gz  # rows every 10 mm down from the top: the top row is 1/31 of the points
    rail = np.column_stack([gx.ravel(), np.full(gx.size, -RAIL_OFFSET), gz.ravel()])
    if skip is not None:
        rail = rail[(rail[:, 0] < skip[0]) | (rail[:, 0] >= skip[1])]
    posts = [
        np.column_stack([np.full(50, x), np.full(50, -0.05), np.linspace(0.0, top + 0.1, 50)])
        for x in xs
    ]  # posts standing above the rail: no rail top
    xyz = np.concatenate([rail, *posts])
    ground = np.zeros((0, 3))
    if road:
        rx, ro = np.meshgrid(np.arange(0.0, length, 0.25), np.arange(0.5, 3.0, 0.25))
        ground = np.column_stack([rx.ravel(), -ro.ravel(), _road_z(rx, ro, crossfall).ravel()])
    return xyz, ground, run


def test_a_run_lowered_by_40_mm_reads_747_mm_and_fails_the_mgs():
    mgs = load_standard("mgs")
    xyz, road, run = _scene(0.787 - 0.040)
    segments = rail_heights(xyz, road, run, mgs)
    assert [s.start_m for s in segments] == pytest.approx([0, 10])
    assert [s.end_m for s in segments] == pytest.approx([10, 19.05])
    for s in segments:
        assert (s.min_m, s.median_m, s.max_m) == pytest.approx((0.747, 0.747, 0.747), abs=1e-9)
        assert s.compliant is False
        assert s.road_source == ROAD_POINTS and s.rail_source == "points"
        assert s.n_bins == pytest.approx((s.end_m - s.start_m) / 0.5, abs=1)
    nominal = rail_heights(*_scene(0.787), mgs)
    assert all(s.compliant and s.median_m == pytest.approx(0.787) for s in nominal)


def test_the_road_plane_is_read_at_the_beams_face_on_a_crossfall():
    # The road rises 4 % away from the rail; the beam's top is 787 mm above the road at its
    # face, 5 cm above the road's edge level there, as a plane through the road points says.
    xyz, road, run = _scene(0.787, crossfall=0.04)
    segments = rail_heights(xyz, road, run, load_standard("mgs"))
    assert all(s.median_m == pytest.approx(0.787, abs=1e-9) for s in segments)


def test_without_road_points_the_poles_ground_is_the_road_and_the_output_says_so():
    xyz, _, run = _scene(0.70)  # the rail top is 0.75 m above the poles' ground (road at 0.05)
    segments = rail_heights(xyz, None, run, load_standard("mgs"))
    assert all(s.road_source == POLES_GROUND for s in segments)
    assert all(s.median_m == pytest.approx(0.75) and s.compliant is False for s in segments)


def test_where_no_rail_points_lie_the_unit_model_gives_the_rail_top():
    beam = UnitModel(
        type="beam", length=SPACING, section=np.array([[0.0, 0.5], [0.1, 0.83], [0.0, 0.8]])
    )
    xyz, road, run = _scene(0.78, skip=(12.0, 19.05), model=beam)
    first, second = rail_heights(xyz, road, run, load_standard("mgs"))
    assert first.rail_source == "points" and first.median_m == pytest.approx(0.78)
    # 12-19 m: the model's top (0.83 m above the poles' ground, 0.78 above the road) placed
    # along the run; 10-12 m: the points.
    assert second.rail_source == "points+model"
    assert second.min_m == pytest.approx(0.78) and second.max_m == pytest.approx(0.78)
    bare = RunModel(0, run.poles, run.units, None, run.registered, 0)
    without = rail_heights(xyz, road, bare, load_standard("mgs"))
    assert without[1].n_bins == 4  # only the bins with points


def test_segment_length_and_a_run_of_one_pole():
    xyz, road, run = _scene(0.787)
    params = ConditionParams(segment_length_m=5.0)
    assert len(rail_heights(xyz, road, run, load_standard("mgs"), params)) == 4
    one = RunModel(0, run.poles[:1], [], None, np.zeros(0, bool), 0)
    assert rail_heights(xyz, road, one, load_standard("mgs")) == []
