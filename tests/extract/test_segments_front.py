"""What touches the back of a rail is cut from it (``SegmentParams.front_layer_m``): a hedge
that the wireframe joins to the rail in front of it, with no gap between them."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.extract.segments import SegmentParams
from guardrail_core.extract.slices import slice_components

PARAMS = SegmentParams()


def _rail_and_hedge(
    rng: np.random.Generator, side: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One slice of one component: a pipe rail 2 m from the path (two pipes at 0.2 and 0.85 m
    and a post, 150 points within 3 cm of its face) and a hedge touching its back (600 points
    spread over 0.05-0.75 m behind the face, 0.1-1.3 m high). ``side`` -1 puts it right of the
    path. Returns station, lateral, height (N,) and which points are the rail's (N,) bool."""
    rail_depth = rng.uniform(0.0, 0.03, 150)
    rail_height = np.concatenate(
        [rng.normal(0.2, 0.01, 50), rng.normal(0.85, 0.01, 50), rng.uniform(0.1, 0.9, 50)]
    )
    hedge_depth = rng.uniform(0.05, 0.75, 600)
    hedge_height = rng.uniform(0.1, 1.3, 600)
    lateral = side * (2.0 + np.concatenate([rail_depth, hedge_depth]))
    height = np.concatenate([rail_height, hedge_height])
    rail = np.repeat([True, False], [150, 600])
    return rng.uniform(0.0, 0.5, len(lateral)), lateral, height, rail


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_a_hedge_touching_the_back_of_a_rail_is_cut_from_it(side: float) -> None:
    station, lateral, height, rail = _rail_and_hedge(np.random.default_rng(50), side)
    component = np.zeros(len(lateral), np.int64)
    segments = slice_components(component, station, PARAMS, lateral, height)
    assert len(segments) == 2
    front, back = (segments.point_segment == s for s in range(2))
    # Every rail point is in front; what came with it is the hedge's nearest 3 cm.
    assert front[rail].all()
    assert (np.abs(lateral[front & ~rail]) < 2.0 + 0.05 + PARAMS.front_layer_m).all()
    assert rail[front].mean() > 0.5
    assert not rail[back].any()
    # The part behind is another object: a component of its own, in the same slice.
    assert segments.component[0] != segments.component[1]
    np.testing.assert_array_equal(segments.slice_index, [0, 0])
    np.testing.assert_array_equal(
        segments.point_component, segments.component[segments.point_segment]
    )


def test_the_cut_needs_heights_and_can_be_turned_off() -> None:
    station, lateral, height, _ = _rail_and_hedge(np.random.default_rng(51))
    component = np.zeros(len(lateral), np.int64)
    assert len(slice_components(component, station, PARAMS, lateral)) == 1
    off = SegmentParams(front_layer_m=0.0)
    assert len(slice_components(component, station, off, lateral, height)) == 1


def test_clutter_in_front_of_a_rail_does_not_move_its_front() -> None:
    """A sparse scan's few hits up to 12 cm in front of the rail, in the rail's bin and the one
    before: the front is the rail's face, so the rail stays whole in front."""
    rng = np.random.default_rng(52)
    station, lateral, height, rail = _rail_and_hedge(rng)
    clutter = rng.uniform(1.88, 1.99, 8)
    lateral = np.concatenate([lateral, clutter])
    height = np.concatenate([height, rng.uniform(0.1, 0.3, 8)])
    station = np.concatenate([station, rng.uniform(0.0, 0.5, 8)])
    rail = np.concatenate([rail, np.zeros(8, bool)])
    segments = slice_components(np.zeros(len(lateral), np.int64), station, PARAMS, lateral, height)
    assert len(segments) == 2
    assert (segments.point_segment[rail] == 0).all()


def test_a_beam_with_its_post_behind_stays_whole() -> None:
    """A W-beam 8.5 cm deep (300 points), its post 0.5-0.6 m behind its face (60 points) and
    clutter in front (as in test_segments): what lies behind the front layer spans more than
    front_behind_min_width_m across and front_behind_min_length_m along, but holds fewer than
    front_behind_ratio times the front's points."""
    rng = np.random.default_rng(53)
    beam = rng.uniform(4.70, 4.785, 300)
    post = rng.uniform(5.2, 5.3, 60)
    clutter = rng.choice(np.arange(4.35, 4.6, 0.12), 12)
    lateral = -np.concatenate([beam, post, clutter])
    height = np.concatenate(
        [rng.uniform(0.45, 0.8, 300), rng.uniform(0.0, 0.75, 60), rng.uniform(0.0, 0.1, 12)]
    )
    station = rng.uniform(0.0, 0.5, len(lateral))
    segments = slice_components(np.zeros(len(lateral), np.int64), station, PARAMS, lateral, height)
    assert 5.2 - 4.70 - PARAMS.front_layer_m > PARAMS.front_behind_min_width_m
    assert len(segments) == 1


def test_a_hedge_whose_front_is_a_thin_band_stays_whole() -> None:
    """A hedge with no rail, bulging towards the road at 0.7-0.85 m: its nearest points are a
    band thinner than front_min_height_m, as is a car's flank; no rail's face is."""
    rng = np.random.default_rng(54)
    height = rng.uniform(0.1, 1.3, 800)
    bulge = np.abs(height - 0.78)  # the face recedes above and below the bulge
    lateral = 2.0 + bulge + 0.7 * rng.uniform(0.0, 1.0, 800) ** 2
    station = rng.uniform(0.0, 0.5, len(lateral))
    segments = slice_components(np.zeros(len(lateral), np.int64), station, PARAMS, lateral, height)
    near = lateral < 2.0 + PARAMS.front_layer_m
    assert np.ptp(height[near]) < PARAMS.front_min_height_m
    assert len(segments) == 1


def test_components_behind_are_numbered_apart_from_every_component_in_front() -> None:
    """Two components, each a rail with a hedge behind in two slices: the hedges become two
    components (one for each component they were cut from), none equal to a rail's."""
    rng = np.random.default_rng(55)
    parts = []
    for comp, offset, side in ((0, 0.0, 1.0), (1, 0.5, -1.0)):
        for piece in range(2):
            station, lateral, height, _ = _rail_and_hedge(rng, side)
            parts.append(
                (np.full(len(lateral), comp), station + 0.5 * piece + offset, lateral, height)
            )
    component, station, lateral, height = (np.concatenate(x) for x in zip(*parts, strict=True))
    segments = slice_components(component, station, PARAMS, lateral, height)
    assert len(segments) == 8
    fronts = {int(c) for s, c in enumerate(segments.component) if s % 2 == 0}
    backs = {int(c) for s, c in enumerate(segments.component) if s % 2 == 1}
    assert len(fronts) == 2 and len(backs) == 2 and not fronts & backs


def test_a_sparse_scans_few_hits_in_front_stay_with_the_rest() -> None:
    """A tenth of the rail and hedge's points (a sparse real scan): the front holds fewer than
    front_min_points, too little shape to judge apart, and the slice stays whole; asking for
    fewer cuts it."""
    station, lateral, height, rail = _rail_and_hedge(np.random.default_rng(56))
    keep = np.arange(len(lateral)) % 10 == 0
    station, lateral, height, rail = station[keep], lateral[keep], height[keep], rail[keep]
    component = np.zeros(len(lateral), np.int64)
    assert len(slice_components(component, station, PARAMS, lateral, height)) == 1
    few = SegmentParams(front_min_points=5)
    segments = slice_components(component, station, few, lateral, height)
    assert len(segments) == 2
    assert (segments.point_segment[rail] == 0).all()


def _far_rail(
    rng: np.random.Generator, behind_depth: tuple[float, float], behind_along: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One slice of one component across the road: a pipe rail 5 m right of the path (two
    pipes at 0.3 and 0.8 m, 80 points within 3 cm of its face) and 250 points behind it,
    ``behind_depth`` metres behind its face and ``behind_along`` metres along the slice,
    0.1-0.95 m high. Returns station, lateral, height (N,) and which points are the rail's."""
    rail_depth = rng.uniform(0.0, 0.03, 80)
    rail_height = np.concatenate([rng.normal(0.3, 0.01, 40), rng.normal(0.8, 0.01, 40)])
    depth = np.concatenate([rail_depth, rng.uniform(*behind_depth, 250)])
    height = np.concatenate([rail_height, rng.uniform(0.1, 0.95, 250)])
    station = np.concatenate([rng.uniform(0.0, 0.5, 80), rng.uniform(*behind_along, 250)])
    return station, -(5.0 + depth), height, np.repeat([True, False], [80, 250])


@pytest.mark.parametrize("seed", [60, 61, 62])
def test_the_face_of_a_hedge_behind_a_far_rail_is_cut_from_it(seed: int) -> None:
    """Seen from across the road only the hedge's face, 0.15-0.35 m behind the rail, is
    scanned: the slice is narrower than gap_width_m and what lies behind narrower than
    gap_piece_m, yet it fills the slice along the path and outnumbers the rail."""
    station, lateral, height, rail = _far_rail(np.random.default_rng(seed), (0.15, 0.35), (0, 0.5))
    assert np.ptp(lateral) < PARAMS.gap_width_m
    segments = slice_components(np.zeros(len(lateral), np.int64), station, PARAMS, lateral, height)
    assert len(segments) == 2
    np.testing.assert_array_equal(segments.point_segment, np.where(rail, 0, 1))
    assert segments.component[0] != segments.component[1]


@pytest.mark.parametrize("seed", [63, 64, 65])
def test_a_thick_post_behind_a_rail_stays_with_it(seed: int) -> None:
    """A post 0.08-0.25 m behind the rail's face holding three times the rail's points (a near
    pole, densely scanned) is as deep as a hedge's face but 0.12 m thick along the path: the
    slice stays whole, even with a few stray hits behind the rail along the whole slice. Asking
    for less length cuts it, so the length is what keeps it."""
    rng = np.random.default_rng(seed)
    station, lateral, height, _ = _far_rail(rng, (0.08, 0.25), (0.19, 0.31))
    stray = 3
    station = np.concatenate([station, rng.uniform(0.0, 0.5, stray)])
    lateral = np.concatenate([lateral, -5.0 - rng.uniform(0.1, 0.3, stray)])
    height = np.concatenate([height, rng.uniform(0.1, 0.9, stray)])
    component = np.zeros(len(lateral), np.int64)
    assert len(slice_components(component, station, PARAMS, lateral, height)) == 1
    short = SegmentParams(front_behind_min_length_m=0.05)
    assert len(slice_components(component, station, short, lateral, height)) == 2
