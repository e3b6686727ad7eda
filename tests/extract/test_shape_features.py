"""Shape and neighbour features of segments, checked on segments of known geometry."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.extract.classify.label_correction_params import CorrectionParams
from guardrail_core.extract.classify.piece_chains import piece_chains
from guardrail_core.extract.classify.segment_extents import SegmentExtents
from guardrail_core.extract.classify.shape_features import (
    NEIGHBOUR_FEATURE_NAMES,
    SEGMENT_FEATURE_DIM,
    SEGMENT_FEATURE_NAMES,
    SHAPE_FEATURE_NAMES,
    WHOLE_COMPONENT_FEATURE_NAMES,
    neighbour_features,
    segment_features,
    shape_features,
)
from guardrail_core.extract.segments import SegmentParams, summarise_segments
from guardrail_core.extract.slices import slice_components

PARAMS = SegmentParams(slice_length_m=0.5)


def features_of(station, lateral, height, component, intensity=None):
    station, lateral, height = (np.asarray(v, np.float64) for v in (station, lateral, height))
    component = np.asarray(component)
    if intensity is None:
        intensity = np.full(len(station), 1000, np.uint16)
    segments = slice_components(component, station, PARAMS)
    table = shape_features(station, lateral, height, intensity, segments, PARAMS)
    return segments, {name: table[:, i] for i, name in enumerate(SHAPE_FEATURE_NAMES)}


def test_a_rail_along_the_road_is_linear_continuous_and_long() -> None:
    # A 5 m rail at 0.7 m height, 3 m left, a point every centimetre: ten slices.
    station = np.arange(500) * 0.01 + 0.005
    segments, f = features_of(station, np.full(500, 3.0), np.full(500, 0.7), np.zeros(500, int))
    assert len(segments) == 10
    np.testing.assert_allclose(f["height_min_m"], 0.7)
    np.testing.assert_allclose(f["height_max_m"], 0.7)
    np.testing.assert_allclose(f["station_extent_m"], 0.49, atol=1e-9)
    np.testing.assert_allclose(f["log_points"], np.log(50))
    np.testing.assert_allclose(f["linearity"], 1.0, atol=1e-6)
    np.testing.assert_allclose(f["axis_along_road"], 1.0, atol=1e-6)
    np.testing.assert_allclose(f["station_coverage"], 1.0)
    np.testing.assert_allclose(f["height_coverage"], 1.0)
    np.testing.assert_allclose(f["chain_log_length_m"], np.log1p(4.99), atol=1e-9)
    np.testing.assert_allclose(f["chain_log_slices"], np.log(10))
    np.testing.assert_allclose(f["chain_lateral_spread_m"], 0.0, atol=1e-6)
    np.testing.assert_allclose(f["chain_lateral_slope"], 0.0, atol=1e-9)


def test_a_pole_is_vertical_and_a_slab_is_flat() -> None:
    rng = np.random.default_rng(1)
    pole_h = np.linspace(0.0, 1.0, 100)
    pole = (np.full(100, 0.2), np.full(100, 2.0) + rng.normal(0, 1e-3, 100), pole_h)
    slab_s, slab_l = rng.uniform(2.0, 2.5, 400), rng.uniform(4.0, 5.0, 400)
    slab = (slab_s, slab_l, np.full(400, 0.1))
    station, lateral, height = (np.concatenate([p, q]) for p, q in zip(pole, slab, strict=True))
    _, f = features_of(station, lateral, height, np.repeat([0, 1], [100, 400]))
    assert f["axis_vertical"][0] > 0.999 and f["linearity"][0] > 0.99
    # The pole covers 1 cm of its slice's 0.5 m, and all of its height.
    assert f["station_coverage"][0] == pytest.approx(1 / 10)
    assert f["height_coverage"][0] == pytest.approx(1.0)
    # Variances 0.5²/12 and 1²/12 across a flat slab: planarity (λ2 - λ3) / λ1 = 0.25.
    assert f["normal_vertical"][1] > 0.999 and f["planarity"][1] == pytest.approx(0.25, abs=0.05)
    assert f["scattering"][1] < 1e-6


def test_a_rail_that_veers_away_has_its_slope() -> None:
    station = np.arange(400) * 0.01 + 0.005
    _, f = features_of(station, 1.0 + 0.5 * station, np.full(400, 0.7), np.zeros(400, int))
    np.testing.assert_allclose(f["chain_lateral_slope"], 0.5, atol=1e-9)


def test_intensity_mean_and_spread_are_scaled_to_one() -> None:
    intensity = np.array([0, 65535] * 50, np.uint16)
    _, f = features_of(
        np.linspace(0.01, 0.49, 100), np.zeros(100), np.zeros(100), np.zeros(100, int), intensity
    )
    assert f["intensity_mean"][0] == pytest.approx(0.5)
    assert f["intensity_std"][0] == pytest.approx(0.5)


def test_neighbours_tell_a_short_piece_about_the_long_rail_beside_it() -> None:
    # A 5 m rail (component 0) and a 3-point piece (component 1) 0.1 m above its third slice;
    # a lone post (component 2) 3 m away.
    rail_s = np.arange(500) * 0.01 + 0.005
    piece_s = np.array([1.1, 1.2, 1.3])
    station = np.concatenate([rail_s, piece_s, [1.2]])
    lateral = np.concatenate([np.full(500, 3.0), np.full(3, 3.0), [6.0]])
    height = np.concatenate([np.full(500, 0.7), np.full(3, 0.8), [0.5]])
    component = np.repeat([0, 1, 2], [500, 3, 1])
    segments = slice_components(component, station, PARAMS)
    summary = summarise_segments(
        np.zeros((len(station), 3)), np.zeros(len(station)), lateral, height, segments
    )
    extents = SegmentExtents(
        segments.slice_index,
        summary.lateral,
        summary.height,
        segments.component,
        segments.n_points,
    )
    intensity = np.full(len(station), 100, np.uint16)
    shape = shape_features(station, lateral, height, intensity, segments, PARAMS)
    near = neighbour_features(shape, extents, CorrectionParams(touch_distance_m=0.3))
    assert near.shape == (len(segments), len(NEIGHBOUR_FEATURE_NAMES))
    piece = int(np.flatnonzero(segments.component == 1)[0])
    post = int(np.flatnonzero(segments.component == 2)[0])
    # The piece touches rail slices 1, 2 and 3 (its own slice and the two beside it).
    assert near[piece, 0] == pytest.approx(np.log1p(3))
    assert near[piece, 1] == pytest.approx(np.log1p(4.99))
    assert near[piece, 2] == pytest.approx(np.log(50))
    assert near[piece, 3] == pytest.approx(0.7)
    np.testing.assert_array_equal(near[post], [0.0, -1.0, -1.0, -1.0])
    combined = segment_features(station, lateral, height, intensity, segments, extents, PARAMS)
    assert combined.shape == (len(segments), SEGMENT_FEATURE_DIM)
    neighbours = slice(len(SHAPE_FEATURE_NAMES), len(SHAPE_FEATURE_NAMES) + near.shape[1])
    np.testing.assert_array_equal(combined[:, neighbours], near)


def test_no_segments_no_features() -> None:
    segments = slice_components(np.full(3, -1), np.zeros(3), PARAMS)
    out = shape_features(
        np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3, np.uint16), segments, PARAMS
    )
    assert out.shape == (0, len(SHAPE_FEATURE_NAMES))


def test_a_rail_keeps_its_own_chain_features_beside_the_hedge_its_component_holds() -> None:
    # One component: a 5 m rail 3 m left at 0.7 m, and a hedge 0.5-1.5 m behind it, 0-1.8 m
    # tall, that the wireframe joined to it. Slicing cuts every slice at the empty band between.
    rng = np.random.default_rng(3)
    rail_s = np.arange(500) * 0.01 + 0.005
    hedge_s = rng.uniform(0.0, 5.0, 8000)
    station = np.concatenate([rail_s, hedge_s])
    lateral = np.concatenate([np.full(500, 3.0), rng.uniform(3.5, 4.5, 8000)])
    height = np.concatenate([np.full(500, 0.7), rng.uniform(0.0, 1.8, 8000)])
    component = np.zeros(len(station), int)
    segments = slice_components(component, station, PARAMS, lateral, height)
    table = shape_features(
        station, lateral, height, np.full(len(station), 100, np.uint16), segments, PARAMS
    )
    f = {name: table[:, i] for i, name in enumerate(SHAPE_FEATURE_NAMES)}
    rail = np.isin(np.arange(len(segments)), segments.point_segment[:500])
    assert rail.sum() == 10 and len(segments) > 20  # the hedge is cut into pieces too
    np.testing.assert_allclose(f["chain_height_top_m"][rail], 0.7)
    np.testing.assert_allclose(f["chain_log_slices"][rail], np.log(10))
    np.testing.assert_allclose(f["chain_log_length_m"][rail], np.log1p(4.99), atol=1e-9)
    np.testing.assert_allclose(f["chain_lateral_spread_m"][rail], 0.0, atol=1e-6)
    assert np.all(f["chain_height_top_m"][~rail] > 1.75)
    assert np.all(f["chain_height_min_m"][~rail] < 0.05)


def test_a_shrub_grown_into_a_rail_does_not_raise_the_rails_chain_top() -> None:
    # One component: a 5 m rail 3 m left at 0.7 m, and a shrub 0-1.8 m tall touching it from
    # behind over 1 m (slices 4 and 5). Slices are not cut across (features_of): each is one
    # segment holding rail and shrub alike, as where the two touch, so the rail's chain runs
    # through the shrub. Its top is its pieces' median highest point.
    rng = np.random.default_rng(5)
    rail_s = np.arange(500) * 0.01 + 0.005

    def rail_and_shrub(length_m: float, shrub_from_m: float, shrub_to_m: float):
        rail = rail_s[rail_s < length_m]
        station = np.concatenate([rail, rng.uniform(shrub_from_m, shrub_to_m, 2000)])
        lateral = np.concatenate([np.full(len(rail), 3.0), rng.uniform(3.0, 3.6, 2000)])
        height = np.concatenate([np.full(len(rail), 0.7), rng.uniform(0.0, 1.8, 2000)])
        return features_of(station, lateral, height, np.zeros(len(station), int))

    segments, f = rail_and_shrub(5.0, 2.0, 3.0)
    assert len(segments) == 10
    assert f["height_max_m"][[4, 5]].min() > 1.75
    np.testing.assert_allclose(f["chain_log_slices"], np.log(10))
    np.testing.assert_allclose(f["chain_height_top_m"], 0.7)  # eight of ten pieces' tops
    assert np.all(f["chain_height_min_m"] < 0.05)
    # Two pieces of three reaching 1.8 m: the median is theirs.
    segments, f = rail_and_shrub(1.5, 0.5, 1.5)
    assert len(segments) == 3
    np.testing.assert_allclose(f["chain_height_top_m"], np.median(f["height_max_m"]))
    assert f["chain_height_top_m"].min() > 1.75


def test_piece_chains_link_consecutive_slices_of_one_component_side_by_side() -> None:
    # Segments:             0     1     2     3     4     5     6     7
    component = np.array([0, 0, 0, 0, 0, 1, 0, 0])
    slice_index = np.array([0, 1, 1, 0, 2, 1, 4, 0])
    lateral_min = np.array([3.0, 3.05, 3.0, 3.0, 3.18, 3.0, 3.0, 5.0])
    lateral_max = np.array([3.1, 3.1, 3.1, 3.1, 3.3, 3.1, 3.1, 6.0])
    chain = piece_chains(component, slice_index, lateral_min, lateral_max, gap_m=0.1)
    # 0 and 3 (stacked in slice 0) join through 1 and 2 in slice 1; 4 lies 0.08 m from them.
    assert len(set(chain[[0, 1, 2, 3, 4]])) == 1
    # Another component (5), a slice further than the next (6), and a piece 1.9 m away (7).
    assert len(set(chain[[0, 5, 6, 7]])) == 4
    assert sorted(set(chain)) == [0, 1, 2, 3]
    apart = piece_chains(component, slice_index, lateral_min, lateral_max, gap_m=0.05)
    assert apart[4] != apart[0] and apart[1] == apart[0]
    assert piece_chains(*(np.zeros(0) for _ in range(4)), gap_m=0.1).shape == (0,)


def test_models_from_before_chains_read_the_whole_components_features() -> None:
    # The rail and hedge of one component above: the whole-component columns are the chain
    # columns taken over the component (what the shipped model was trained on), and the longest
    # neighbour's by them.
    rng = np.random.default_rng(3)
    station = np.concatenate([np.arange(500) * 0.01 + 0.005, rng.uniform(0.0, 5.0, 8000)])
    lateral = np.concatenate([np.full(500, 3.0), rng.uniform(3.5, 4.5, 8000)])
    height = np.concatenate([np.full(500, 0.7), rng.uniform(0.0, 1.8, 8000)])
    segments = slice_components(np.zeros(len(station), int), station, PARAMS, lateral, height)
    summary = summarise_segments(
        np.zeros((len(station), 3)), np.zeros(len(station)), lateral, height, segments
    )
    extents = SegmentExtents(
        segments.slice_index, summary.lateral, summary.height, segments.component, segments.n_points
    )
    intensity = np.full(len(station), 100, np.uint16)
    table = segment_features(station, lateral, height, intensity, segments, extents, PARAMS)
    assert table.shape == (len(segments), SEGMENT_FEATURE_DIM)
    f = {name: table[:, i] for i, name in enumerate(SEGMENT_FEATURE_NAMES)}
    # The rail's component holds the hedge's near half (slicing cuts what lies behind a front
    # into a component of its own): its heights and its segments are the rail's and the hedge's.
    rail = np.isin(np.arange(len(segments)), segments.point_segment[:500])
    comp = segments.component[rail][0]
    assert np.all(segments.component[rail] == comp)
    mine = segments.component == comp
    points = np.isin(segments.point_segment, np.flatnonzero(mine))
    np.testing.assert_allclose(f["component_height_max_m"][mine], height[points].max(), rtol=1e-6)
    np.testing.assert_allclose(f["component_height_min_m"][mine], height[points].min(), atol=1e-6)
    np.testing.assert_allclose(f["component_log_slices"][mine], np.log(mine.sum()), rtol=1e-6)
    assert mine.sum() > rail.sum() and height[points].max() > 1.75
    np.testing.assert_allclose(
        f["neighbours_max_component_log_length_m"][rail], f["component_log_length_m"][rail]
    )
    np.testing.assert_allclose(f["chain_height_top_m"][rail], 0.7)
    # On a clean rail the chain is the component.
    station = np.arange(500) * 0.01 + 0.005
    _, clean = features_of(station, np.full(500, 3.0), np.full(500, 0.7), np.zeros(500, int))
    segments = slice_components(np.zeros(500, int), station, PARAMS)
    summary = summarise_segments(
        np.zeros((500, 3)), np.zeros(500), np.full(500, 3.0), np.full(500, 0.7), segments
    )
    extents = SegmentExtents(
        segments.slice_index, summary.lateral, summary.height, segments.component, segments.n_points
    )
    table = segment_features(
        station,
        np.full(500, 3.0),
        np.full(500, 0.7),
        np.full(500, 100, np.uint16),
        segments,
        extents,
        PARAMS,
    )
    for name in WHOLE_COMPONENT_FEATURE_NAMES:
        chain = name.replace("component_height_max_m", "chain_height_top_m")
        chain = chain.replace("component", "chain")
        np.testing.assert_array_equal(
            table[:, SEGMENT_FEATURE_NAMES.index(name)],
            table[:, SEGMENT_FEATURE_NAMES.index(chain)],
        )
