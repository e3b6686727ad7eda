"""Shape features of segments: what a segment's points say about it, without any image.

A guardrail is long, parallel to the road, continuous along it and at rail height; a bicycle rack
or a sign post is short, a hedge is scattered. These features describe a segment (its size,
height, shape and intensity) and the connected component it was cut from (its length along the
road and how straight beside it), all in track coordinates, so they do not depend on where the
road runs. The classifier fuses them with the crop's embedding, and classifies segments that have
no crop from them alone.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from guardrail_core.extract.correct import CorrectionParams, SegmentExtents, neighbour_pairs
from guardrail_core.extract.segments import Segments

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
    "component_log_length_m",
    "component_log_slices",
    "component_height_min_m",
    "component_height_max_m",
    "component_lateral_spread_m",
    "component_lateral_slope",
)
# The offset from the trajectory and the width across it are left out on purpose: they tell the
# near side of the road from the far side, not a guardrail from anything else, and a model that
# learnt them missed far-side guardrails (seen-design F 95.0% with them, 98.3% without).
SHAPE_FEATURE_DIM = len(SHAPE_FEATURE_NAMES)

NEIGHBOUR_FEATURE_NAMES = (
    "neighbours_log_count",
    "neighbours_max_component_log_length_m",
    "neighbours_max_log_points",
    "neighbours_max_height_m",
)
SEGMENT_FEATURE_NAMES = SHAPE_FEATURE_NAMES + NEIGHBOUR_FEATURE_NAMES
SEGMENT_FEATURE_DIM = len(SEGMENT_FEATURE_NAMES)


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
_MAX_SLOPE = 10.0  # a component's lateral drift per metre along the road is clipped to this


def shape_features(
    station: np.ndarray,
    lateral: np.ndarray,
    height: np.ndarray,
    intensity: np.ndarray,
    segments: Segments,
    slice_length_m: float,
) -> np.ndarray:
    """Shape features of every segment.

    Parameters
    ----------
    station, lateral, height : (N,) float64, metres, track coordinates of every point
        (see :mod:`guardrail_core.sensors.track`)
    intensity : (N,) uint16, return intensity
    segments : the sliced segments of those N points
    slice_length_m : the slice length the segments were cut with

    Returns
    -------
    (S, SHAPE_FEATURE_DIM) float32, columns named by :data:`SHAPE_FEATURE_NAMES`; finite.
    """
    n_seg = len(segments)
    out = np.zeros((n_seg, SHAPE_FEATURE_DIM), np.float32)
    if n_seg == 0:
        return out
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

    # The component each segment was cut from: its length along the road and its course.
    comp = segments.component.astype(np.int64)
    _, comp_index = np.unique(comp, return_inverse=True)
    n_comp = int(comp_index.max()) + 1
    slices = segments.slice_index.astype(np.float64)
    c_first = np.full(n_comp, np.inf)
    c_last = np.full(n_comp, -np.inf)
    np.minimum.at(c_first, comp_index, slices * slice_length_m + s_min)
    np.maximum.at(c_last, comp_index, slices * slice_length_m + s_max)
    c_slices = np.bincount(comp_index, minlength=n_comp).astype(np.float64)
    c_hmin = np.full(n_comp, np.inf)
    c_hmax = np.full(n_comp, -np.inf)
    np.minimum.at(c_hmin, comp_index, h_min)
    np.maximum.at(c_hmax, comp_index, h_max)
    # Lateral course: a least-squares line of the segments' mean offset against station.
    x = slices * slice_length_m
    w = np.bincount(comp_index, minlength=n_comp).astype(np.float64)
    sx = np.bincount(comp_index, x, n_comp) / w
    sy = np.bincount(comp_index, l_mean, n_comp) / w
    sxx = np.bincount(comp_index, x * x, n_comp) / w - sx**2
    sxy = np.bincount(comp_index, x * l_mean, n_comp) / w - sx * sy
    syy = np.maximum(np.bincount(comp_index, l_mean * l_mean, n_comp) / w - sy**2, 0.0)
    slope = np.where(sxx > 1e-9, sxy / np.maximum(sxx, 1e-9), 0.0)
    residual = np.sqrt(np.maximum(syy - slope * sxy, 0.0))

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
        np.log1p((c_last - c_first)[comp_index]),
        np.log(c_slices[comp_index]),
        c_hmin[comp_index],
        c_hmax[comp_index],
        residual[comp_index],
        np.minimum(np.abs(slope), _MAX_SLOPE)[comp_index],
    ]
    out[:] = np.stack(columns, axis=1)
    return np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)


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
    n = len(shape)
    pairs = neighbour_pairs(extents, params)
    a = np.concatenate([pairs[:, 0], pairs[:, 1]])
    b = np.concatenate([pairs[:, 1], pairs[:, 0]])
    out = np.full((n, len(NEIGHBOUR_FEATURE_NAMES)), -1.0, np.float32)
    out[:, 0] = np.log1p(np.bincount(a, minlength=n))
    for column, name in enumerate(
        ("component_log_length_m", "log_points", "height_max_m"), start=1
    ):
        values = np.full(n, -1.0, np.float32)
        np.maximum.at(values, a, shape[b, SHAPE_FEATURE_NAMES.index(name)])
        out[:, column] = values
    return out


def segment_features(
    station: np.ndarray,
    lateral: np.ndarray,
    height: np.ndarray,
    intensity: np.ndarray,
    segments: Segments,
    extents: SegmentExtents,
    slice_length_m: float,
    correction: CorrectionParams = CorrectionParams(),
) -> np.ndarray:
    """(S, SEGMENT_FEATURE_DIM) float32: :func:`shape_features` then :func:`neighbour_features`."""
    shape = shape_features(station, lateral, height, intensity, segments, slice_length_m)
    return np.concatenate([shape, neighbour_features(shape, extents, correction)], axis=1)


def _distinct_per_segment(seg_of: np.ndarray, value: np.ndarray, n_seg: int) -> np.ndarray:
    """(S,) number of distinct ``value`` per segment, for sorted ``seg_of``."""
    stride = int(value.max(initial=0)) + 1
    key = np.unique(seg_of * stride + value)
    return np.bincount(key // stride, minlength=n_seg).astype(np.float64)
