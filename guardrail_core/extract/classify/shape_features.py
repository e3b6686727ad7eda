"""Shape features of segments: what a segment's points say about it, without any image.

A guardrail is long, parallel to the road, continuous along it and at rail height; a bicycle rack
or a sign post is short, a hedge is scattered. These features describe a segment (its size,
height, shape and intensity) and the chain of pieces it belongs to (its length along the road
and how straight beside it; see :mod:`guardrail_core.extract.classify.piece_chains`), all in
track coordinates, so they do not depend on where the road runs. The classifier fuses them with
the crop's embedding, and classifies segments that have no crop from them alone.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from guardrail_core.errors import IncompatibleModelError, InvalidOptionError
from guardrail_core.extract.classify.label_correction_params import CorrectionParams
from guardrail_core.extract.classify.piece_chains import piece_chains
from guardrail_core.extract.classify.segment_extents import SegmentExtents, neighbour_pairs
from guardrail_core.extract.segments import SegmentParams, Segments

SHAPE_FEATURE_NAMES = (
    "height_min_m",
    "height_max_m",
    "height_mean_m",
    "station_extent_m",
    "log_points",
    "intensity_mean",
    "intensity_std",
    "linearity",
    "planarity",
    "scattering",
    "axis_along_road",
    "axis_vertical",
    "normal_vertical",
    "normal_across_road",
    "station_coverage",
    "height_coverage",
    "chain_log_length_m",
    "chain_log_slices",
    "chain_height_min_m",
    "chain_height_top_m",
    "chain_lateral_spread_m",
    "chain_lateral_slope",
)
# A chain's top is the median of its pieces' highest points, not the highest: a shrub grown into
# a railing joins the railing's chain in the few slices where the two touch, and the chain's
# highest point was then the shrub's (1.86 m over a 15 m, 1.05 m railing, which a model that
# never saw the design called other by it; leave one design out, README).
# The offset from the trajectory and the width across it are left out on purpose: they tell the
# near side of the road from the far side, not a guardrail from anything else, and a model that
# learnt them missed far-side guardrails (seen-design F 95.0% with them, 98.3% without).
SHAPE_FEATURE_DIM = len(SHAPE_FEATURE_NAMES)

NEIGHBOUR_FEATURE_NAMES = (
    "neighbours_log_count",
    "neighbours_max_chain_log_length_m",
    "neighbours_max_log_points",
    "neighbours_max_height_m",
)
# The chain features taken over the whole component, and the longest neighbour's by them: what
# models trained before chains (2026-11-29) read. They are computed for those models alone; no
# model is trained on them now (SegmentHeadParams.feature_names leaves them out).
WHOLE_COMPONENT_FEATURE_NAMES = (
    "component_log_length_m",
    "component_log_slices",
    "component_height_min_m",
    "component_height_max_m",
    "component_lateral_spread_m",
    "component_lateral_slope",
    "neighbours_max_component_log_length_m",
)
SEGMENT_FEATURE_NAMES = (
    SHAPE_FEATURE_NAMES + NEIGHBOUR_FEATURE_NAMES + WHOLE_COMPONENT_FEATURE_NAMES
)
SEGMENT_FEATURE_DIM = len(SEGMENT_FEATURE_NAMES)


def check_feature_layout(features: np.ndarray) -> np.ndarray:
    """``features`` as (S, :data:`SEGMENT_FEATURE_DIM`) float32: segment features laid out as
    this version computes them (:data:`SEGMENT_FEATURE_NAMES`), the layout a model's named
    features are read from.

    Raises
    ------
    InvalidOptionError
        Not an (S, F) array.
    IncompatibleModelError
        Another number of columns: segments written by another version of guardrail (an
        unreleased one before chains wrote 26), whose columns no model can read by name.
    """
    features = np.asarray(features, np.float32)
    if features.ndim != 2:
        raise InvalidOptionError(f"segment features: expected (S, F), got shape {features.shape}")
    if features.shape[1] != SEGMENT_FEATURE_DIM:
        raise IncompatibleModelError(
            f"segment features: expected {SEGMENT_FEATURE_DIM} columns per segment, got "
            f"{features.shape[1]}: segments written by another version of guardrail; process "
            "the drive again"
        )
    return features


def feature_columns(names: Sequence[str]) -> np.ndarray:
    """(K,) int64: the columns of :data:`SEGMENT_FEATURE_NAMES` that ``names`` are, in order.

    Raises
    ------
    ValueError
        A name is not a segment feature this version computes, or comes twice.
    """
    names = list(names)
    unknown = [name for name in names if name not in SEGMENT_FEATURE_NAMES]
    if unknown or len(set(names)) != len(names):
        raise ValueError(
            f"segment features: unknown {unknown}" if unknown else "segment features: repeated"
        )
    return np.array([SEGMENT_FEATURE_NAMES.index(name) for name in names], np.int64)


_BIN_M = 0.05  # coverage bins along the road and in height (metres)
_INTENSITY_SCALE = 65535.0  # LAS intensity is uint16
_MAX_SLOPE = 10.0  # a chain's lateral drift per metre along the road is clipped to this


def shape_features(
    station: np.ndarray,
    lateral: np.ndarray,
    height: np.ndarray,
    intensity: np.ndarray,
    segments: Segments,
    params: SegmentParams = SegmentParams(),
) -> np.ndarray:
    """Shape features of every segment.

    Parameters
    ----------
    station, lateral, height : (N,) float64, metres, track coordinates of every point
        (see :mod:`guardrail_core.sensors.track`)
    intensity : (N,) uint16, return intensity
    segments : the sliced segments of those N points
    params : the slice length the segments were cut with (``slice_length_m``) and the chains'
        gap (``chain_gap_m``)

    Returns
    -------
    (S, SHAPE_FEATURE_DIM) float32, columns named by :data:`SHAPE_FEATURE_NAMES`; finite.
    """
    return _shape_and_whole_component(station, lateral, height, intensity, segments, params)[0]


def _shape_and_whole_component(
    station: np.ndarray,
    lateral: np.ndarray,
    height: np.ndarray,
    intensity: np.ndarray,
    segments: Segments,
    params: SegmentParams,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`shape_features`, and (S, 6) float32 its chain columns taken over each segment's
    whole component (the first six of :data:`WHOLE_COMPONENT_FEATURE_NAMES`)."""
    n_seg = len(segments)
    out = np.zeros((n_seg, SHAPE_FEATURE_DIM), np.float32)
    if n_seg == 0:
        return out, np.zeros((0, 6), np.float32)
    slice_length_m = params.slice_length_m
    order = segments.order
    starts = segments.starts[:-1]
    count = segments.n_points.astype(np.float64)
    seg_of = np.repeat(np.arange(n_seg), segments.n_points)
    # Station relative to the segment's slice start keeps the sums well conditioned.
    s = np.asarray(station, np.float64)[order] - segments.slice_index[seg_of] * slice_length_m
    lat = np.asarray(lateral, np.float64)[order]
    h = np.asarray(height, np.float64)[order]
    inten = np.asarray(intensity, np.float64)[order] / _INTENSITY_SCALE

    def mean(v: np.ndarray) -> np.ndarray:
        return np.add.reduceat(v, starts) / count

    def span(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.minimum.reduceat(v, starts), np.maximum.reduceat(v, starts)

    h_min, h_max = span(h)
    s_min, s_max = span(s)
    l_min, l_max = span(lat)
    l_mean = mean(lat)
    h_mean = mean(h)
    i_mean = mean(inten)
    i_std = np.sqrt(np.maximum(mean(inten**2) - i_mean**2, 0.0))

    # Covariance in (station, lateral, height), eigenvalues ascending.
    coords = np.stack([s, lat, h], axis=1)
    centred = coords - np.stack([mean(s), l_mean, h_mean], axis=1)[seg_of]
    cov = np.add.reduceat(centred[:, :, None] * centred[:, None, :], starts, axis=0)
    cov /= count[:, None, None]
    values, vectors = np.linalg.eigh(cov)
    values = np.maximum(values, 0.0)
    largest = np.maximum(values[:, 2], 1e-12)
    axis = vectors[:, :, 2]
    normal = vectors[:, :, 0]

    # Share of 5 cm bins along the slice and over the height range that hold a point.
    s_bin = np.clip(np.floor(s / _BIN_M), 0, None).astype(np.int64)
    h_bin = np.floor((h - h_min[seg_of]) / _BIN_M).astype(np.int64)
    s_cover = _distinct_per_segment(seg_of, s_bin, n_seg) / max(slice_length_m / _BIN_M, 1.0)
    h_cover = _distinct_per_segment(seg_of, h_bin, n_seg) / (
        np.floor((h_max - h_min) / _BIN_M) + 1.0
    )

    # The chain each segment belongs to (and, for models from before chains, its whole
    # component): its length along the road and its course.
    chain = piece_chains(segments.component, segments.slice_index, l_min, l_max, params.chain_gap_m)
    station_m = segments.slice_index.astype(np.float64) * slice_length_m
    course = (station_m + s_min, station_m + s_max, h_min, h_max, station_m, l_mean)
    _, component = np.unique(segments.component, return_inverse=True)

    columns = [
        h_min,
        h_max,
        h_mean,
        s_max - s_min,
        np.log(count),
        i_mean,
        i_std,
        (values[:, 2] - values[:, 1]) / largest,
        (values[:, 1] - values[:, 0]) / largest,
        values[:, 0] / largest,
        np.abs(axis[:, 0]),
        np.abs(axis[:, 2]),
        np.abs(normal[:, 2]),
        np.abs(normal[:, 1]),
        s_cover,
        h_cover,
        *_course_features(chain, *course, median_top=True),
    ]
    out[:] = np.stack(columns, axis=1)
    whole = np.stack(_course_features(component, *course), axis=1).astype(np.float32)
    return (
        np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0),
        np.nan_to_num(whole, nan=0.0, posinf=0.0, neginf=0.0),
    )


def _course_features(
    group: np.ndarray,
    first_m: np.ndarray,
    last_m: np.ndarray,
    h_min: np.ndarray,
    h_max: np.ndarray,
    station_m: np.ndarray,
    l_mean: np.ndarray,
    median_top: bool = False,
) -> list[np.ndarray]:
    """Each segment's group's (chain's or component's) length along the road, segments,
    heights and lateral course: six (S,) float64 columns, as the chain features are named.

    ``group`` (S,) int64 numbers the groups from 0; the rest are (S,) float64 metres: where
    each segment starts and ends along the road, its lowest and highest point, its slice's
    start and its mean lateral offset. The group's top is the highest of its segments' highest
    points, or with ``median_top`` their median (the chain's ``chain_height_top_m``).
    """
    n_group = int(group.max()) + 1
    first = np.full(n_group, np.inf)
    last = np.full(n_group, -np.inf)
    np.minimum.at(first, group, first_m)
    np.maximum.at(last, group, last_m)
    low = np.full(n_group, np.inf)
    np.minimum.at(low, group, h_min)
    if median_top:
        high = _median_per_group(group, h_max, n_group)
    else:
        high = np.full(n_group, -np.inf)
        np.maximum.at(high, group, h_max)
    # Lateral course: a least-squares line of the segments' mean offset against station.
    w = np.bincount(group, minlength=n_group).astype(np.float64)
    sx = np.bincount(group, station_m, n_group) / w
    sy = np.bincount(group, l_mean, n_group) / w
    sxx = np.bincount(group, station_m * station_m, n_group) / w - sx**2
    sxy = np.bincount(group, station_m * l_mean, n_group) / w - sx * sy
    syy = np.maximum(np.bincount(group, l_mean * l_mean, n_group) / w - sy**2, 0.0)
    slope = np.where(sxx > 1e-9, sxy / np.maximum(sxx, 1e-9), 0.0)
    residual = np.sqrt(np.maximum(syy - slope * sxy, 0.0))
    return [
        np.log1p((last - first)[group]),
        np.log(w[group]),
        low[group],
        high[group],
        residual[group],
        np.minimum(np.abs(slope), _MAX_SLOPE)[group],
    ]


def _median_per_group(group: np.ndarray, values: np.ndarray, n_group: int) -> np.ndarray:
    """(G,) float64 the median of ``values`` (S,) over each group of ``group`` (S,) int64, 0 to
    G - 1, every group non-empty (the mean of the middle two for an even count)."""
    order = np.lexsort((values, group))
    start = np.searchsorted(group[order], np.arange(n_group))
    size = np.bincount(group, minlength=n_group)
    ranked = np.asarray(values, np.float64)[order]
    return 0.5 * (ranked[start + (size - 1) // 2] + ranked[start + size // 2])


def neighbour_features(
    shape: np.ndarray, extents: SegmentExtents, params: CorrectionParams = CorrectionParams()
) -> np.ndarray:
    """What surrounds each segment: its neighbours (as label correction defines them) and the
    longest, largest and highest among them, so a short piece beside a long rail knows it.

    Parameters
    ----------
    shape : (S, SHAPE_FEATURE_DIM) float32 from :func:`shape_features`
    extents : where the segments lie
    params : the neighbour distance (``touch_distance_m``)

    Returns
    -------
    (S, len(NEIGHBOUR_FEATURE_NAMES)) float32; a segment without neighbours gets 0 count and -1
    for the maxima.
    """
    return _neighbour_columns(shape, *_neighbours(extents, params))


def _neighbours(extents: SegmentExtents, params: CorrectionParams) -> tuple[np.ndarray, ...]:
    """(P,) int64 ``a`` and ``b``: segment ``a[k]`` has neighbour ``b[k]`` (both ways)."""
    pairs = neighbour_pairs(extents, params)
    return np.r_[pairs[:, 0], pairs[:, 1]], np.r_[pairs[:, 1], pairs[:, 0]]


def _neighbour_columns(shape: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    n = len(shape)
    out = np.full((n, len(NEIGHBOUR_FEATURE_NAMES)), -1.0, np.float32)
    out[:, 0] = np.log1p(np.bincount(a, minlength=n))
    for column, name in enumerate(("chain_log_length_m", "log_points", "height_max_m"), start=1):
        out[:, column] = _neighbours_max(shape[:, SHAPE_FEATURE_NAMES.index(name)], a, b)
    return out


def _neighbours_max(values: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(S,) float32 the largest of ``values`` (S,) over each segment's neighbours (segment
    ``a[k]`` has neighbour ``b[k]``), -1 for a segment without."""
    out = np.full(len(values), -1.0, np.float32)
    np.maximum.at(out, a, values[b])
    return out


def segment_features(
    station: np.ndarray,
    lateral: np.ndarray,
    height: np.ndarray,
    intensity: np.ndarray,
    segments: Segments,
    extents: SegmentExtents,
    params: SegmentParams = SegmentParams(),
    correction: CorrectionParams = CorrectionParams(),
) -> np.ndarray:
    """(S, SEGMENT_FEATURE_DIM) float32: :func:`shape_features`, :func:`neighbour_features`, then
    the :data:`WHOLE_COMPONENT_FEATURE_NAMES` (for models trained before chains)."""
    shape, whole = _shape_and_whole_component(station, lateral, height, intensity, segments, params)
    a, b = _neighbours(extents, correction)
    longest = _neighbours_max(whole[:, 0], a, b)
    return np.concatenate([shape, _neighbour_columns(shape, a, b), whole, longest[:, None]], axis=1)


def _distinct_per_segment(seg_of: np.ndarray, value: np.ndarray, n_seg: int) -> np.ndarray:
    """(S,) number of distinct ``value`` per segment, for sorted ``seg_of``."""
    stride = int(value.max(initial=0)) + 1
    key = np.unique(seg_of * stride + value)
    return np.bincount(key // stride, minlength=n_seg).astype(np.float64)
