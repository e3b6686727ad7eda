"""Shape and neighbour features of segments, checked on segments of known geometry."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.extract.correct import CorrectionParams, SegmentExtents
from guardrail_core.extract.segments import SegmentParams, slice_components, summarise_segments
from guardrail_core.extract.shape_features import (
    NEIGHBOUR_FEATURE_NAMES,
    SEGMENT_FEATURE_DIM,
    SHAPE_FEATURE_NAMES,
    neighbour_features,
    segment_features,
    shape_features,
)

PARAMS = SegmentParams(slice_length_m=0.5)


def features_of(station, lateral, height, component, intensity=None):
    station, lateral, height = (np.asarray(v, np.float64) for v in (station, lateral, height))
    component = np.asarray(component)
    if intensity is None:
        intensity = np.full(len(station), 1000, np.uint16)
    segments = slice_components(component, station, PARAMS)
    table = shape_features(station, lateral, height, intensity, segments, PARAMS.slice_length_m)
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
    np.testing.assert_allclose(f["component_log_length_m"], np.log1p(4.99), atol=1e-9)
    np.testing.assert_allclose(f["component_log_slices"], np.log(10))
    np.testing.assert_allclose(f["component_lateral_spread_m"], 0.0, atol=1e-6)
    np.testing.assert_allclose(f["component_lateral_slope"], 0.0, atol=1e-9)


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
    np.testing.assert_allclose(f["component_lateral_slope"], 0.5, atol=1e-9)


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
    shape = shape_features(station, lateral, height, intensity, segments, PARAMS.slice_length_m)
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
    combined = segment_features(
        station, lateral, height, intensity, segments, extents, PARAMS.slice_length_m
    )
    assert combined.shape == (len(segments), SEGMENT_FEATURE_DIM)
    np.testing.assert_array_equal(combined[:, len(SHAPE_FEATURE_NAMES) :], near)


def test_no_segments_no_features() -> None:
    segments = slice_components(np.full(3, -1), np.zeros(3), PARAMS)
    out = shape_features(
        np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3, np.uint16), segments, 0.5
    )
    assert out.shape == (0, len(SHAPE_FEATURE_NAMES))
