"""Rail-top height above the local road, per segment along a run, against a standard.

Repaving raises the road and lowers the rail above it, so the height is measured against the
road beside the run, not the posts' ground. Along the line of the run's poles (detected and
inserted, in order), every ``height_bin_m`` gets:

- the rail top: the ``rail_top_percentile`` of the heights of the guardrail points there that
  are no pole's; where a bin has fewer than ``min_points`` of them, the unit model's highest
  member placed on the poles' ground line (``rail_source`` says which);
- the road: a plane (height over station and offset) fitted to the road points of the segment
  on the road side within ``road_reach_m``, read at the rail's offset; where the segment has
  fewer than ``min_points`` road points, the poles' ground interpolated along the run
  (``road_source`` says which).

Each ``segment_length_m`` reports the min, median and max of its bins' heights and whether all
lie in the standard's rail-top range.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.reconstruct.condition.params import ConditionParams
from guardrail_core.reconstruct.condition.standards import Standard
from guardrail_core.reconstruct.model import RunModel, UnitModel
from guardrail_core.reconstruct.runs import check_points

ROAD_POINTS = "road points"
POLES_GROUND = "poles' ground"


@dataclass(frozen=True)
class SegmentHeight:
    """The rail-top height above the road over one segment of a run.

    Attributes
    ----------
    start_m, end_m : float, metres along the run (the poles' line) from its first pole
    min_m, median_m, max_m : float, metres: over the segment's bins (NaN: no bin measured)
    n_bins : int, bins with a rail top and a road height
    rail_source : "points", "model", "points+model" (some bins each) or "none"
    road_source : :data:`ROAD_POINTS` or :data:`POLES_GROUND`
    compliant : bool, every bin within the standard's rail-top range; None: nothing measured
    """

    start_m: float
    end_m: float
    min_m: float
    median_m: float
    max_m: float
    n_bins: int
    rail_source: str
    road_source: str
    compliant: bool | None


def rail_heights(
    xyz: np.ndarray,
    road: np.ndarray | None,
    run: RunModel,
    standard: Standard,
    params: ConditionParams = ConditionParams(),
) -> list[SegmentHeight]:
    """The rail-top height above the road per segment of a run.

    Parameters
    ----------
    xyz : (N, 3) float64, metres, world: the run's guardrail points
    road : (G, 3) float64, metres, world: road-surface points near the run; may be empty or None
    run : the run's reconstruction (its poles, in order, road on the +z side of the units)
    standard : the rail-top range
    params : segment and bin lengths, reaches, minimum points

    Returns
    -------
    One :class:`SegmentHeight` per ``segment_length_m`` from the first pole to the last (the
    last segment may be shorter); none for a run of fewer than two poles.
    """
    xyz = check_points(xyz)
    road = np.zeros((0, 3)) if road is None else check_points(road, "road")
    if len(run.poles) < 2:
        return []
    line = _PoleLine(np.array([p.position for p in run.poles], np.float64))
    # Pole points are no rail top: a post may stand above the rail.
    radius = np.array([p.radius for p in run.poles]) + params.pole_margin_m
    d, k = cKDTree(line.xyz[:, :2]).query(xyz[:, :2])
    rails = xyz[d > radius[k]] if len(xyz) else xyz
    station, offset = line.locate(rails[:, :2])
    keep = np.abs(offset) <= params.rail_max_offset_m
    # Sorted by station, a segment's or a bin's points are one slice (no mask per bin).
    order = np.argsort(station[keep], kind="stable")
    z, station, offset = rails[keep][order, 2], station[keep][order], offset[keep][order]
    road_station, road_offset = line.locate(road[:, :2])
    model_top = _model_top(run.model)
    out = []
    for start in np.arange(0.0, line.length, params.segment_length_m):  # per segment
        end = min(start + params.segment_length_m, line.length)
        i0, i1 = np.searchsorted(station, [start, end])
        rail_offset = float(np.median(offset[i0:i1])) if i1 > i0 else 0.0
        road_z, road_source = _road_height(
            road, road_station, road_offset, start, end, line, params
        )
        edges = np.arange(start, end, params.height_bin_m)
        heights, sources = [], set()
        for lo in edges:  # per bin
            hi = min(lo + params.height_bin_m, end)
            mid = (lo + hi) / 2
            j0, j1 = np.searchsorted(station, [lo, hi])
            if j1 - j0 >= params.min_points:
                top = float(np.percentile(z[j0:j1], params.rail_top_percentile))
                sources.add("points")
            elif model_top is not None:
                top = line.ground_at(mid) + model_top
                sources.add("model")
            else:
                continue
            heights.append(top - road_z(mid, rail_offset))
        out.append(_segment(start, end, heights, sources, road_source, standard))
    return out


def _segment(
    start: float,
    end: float,
    heights: list[float],
    sources: set[str],
    road_source: str,
    standard: Standard,
) -> SegmentHeight:
    """The :class:`SegmentHeight` of a segment's bin heights (metres)."""
    rail_source = "+".join(sorted(sources, key=["points", "model"].index)) or "none"
    if not heights:
        nan = float("nan")
        return SegmentHeight(start, end, nan, nan, nan, 0, rail_source, road_source, None)
    h = np.asarray(heights)
    low, high = float(h.min()), float(h.max())
    compliant = standard.rail_top_in_range(low) and standard.rail_top_in_range(high)
    return SegmentHeight(
        float(start),
        float(end),
        low,
        float(np.median(h)),
        high,
        len(h),
        rail_source,
        road_source,
        bool(compliant),
    )


def _road_height(
    road: np.ndarray,
    road_station: np.ndarray,
    road_offset: np.ndarray,
    start: float,
    end: float,
    line: _PoleLine,
    params: ConditionParams,
) -> tuple[Callable[[float, float], float], str]:
    """A function (station m, offset m) -> road height (m) over one segment, and its source.

    A least-squares plane z = a + b (station - mid) + c offset through the road points of the
    segment on the road side (0 < offset <= ``road_reach_m``); where they span no plane (all on
    one line), their median; where fewer than ``min_points``, the poles' ground.
    """
    near = (
        (road_station >= start)
        & (road_station < end)
        & (road_offset > 0)
        & (road_offset <= params.road_reach_m)
    )
    if near.sum() < params.min_points:
        return (lambda s, o: line.ground_at(s)), POLES_GROUND
    mid = (start + end) / 2
    design = np.column_stack([np.ones(near.sum()), road_station[near] - mid, road_offset[near]])
    coef, _, rank, _ = np.linalg.lstsq(design, road[near, 2], rcond=None)
    if rank < 3:
        level = float(np.median(road[near, 2]))
        return (lambda s, o: level), ROAD_POINTS
    a, b, c = (float(v) for v in coef)
    return (lambda s, o: a + b * (s - mid) + c * o), ROAD_POINTS


def _model_top(model: UnitModel | None) -> float | None:
    """Metres above the poles' ground line: the unit model's highest member (beam section or
    pipe), None without a model or members."""
    if model is None:
        return None
    if model.section is not None and len(model.section):
        return float(np.max(model.section[:, 1]))
    tops = [float(p.axis[:, 1].max()) + p.radius for p in model.pipes if len(p.axis)]
    return max(tops) if tops else None


class _PoleLine:
    """The polyline through a run's poles (P >= 2, in order): stations and offsets on it.

    ``xyz`` (P, 3) float64, metres, the poles' ground points. Station: horizontal metres along
    the line from the first pole; offset: horizontal metres across it, positive toward the road
    (the unit frames' z, along x up).
    """

    def __init__(self, xyz: np.ndarray) -> None:
        self.xyz = xyz
        chord = np.diff(xyz[:, :2], axis=0)
        self.seg_length = np.linalg.norm(chord, axis=1)
        self.along = chord / np.maximum(self.seg_length, 1e-12)[:, None]  # 1e-12: no 0 division
        self.normal = np.column_stack([self.along[:, 1], -self.along[:, 0]])  # along x up
        self.stations = np.concatenate([[0.0], np.cumsum(self.seg_length)])
        self.length = float(self.stations[-1])

    def locate(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(station, offset), each (N,) metres, of points ``xy`` (N, 2) on the line's nearest
        piece (of the two meeting at the nearest pole)."""
        n_seg = len(self.seg_length)
        if len(xy) == 0:
            return np.zeros(0), np.zeros(0)
        _, nearest = cKDTree(self.xyz[:, :2]).query(xy)
        best_s = np.zeros(len(xy))
        best_o = np.zeros(len(xy))
        best_d = np.full(len(xy), np.inf)
        for seg in (np.clip(nearest - 1, 0, n_seg - 1), np.clip(nearest, 0, n_seg - 1)):
            d = xy - self.xyz[seg, :2]
            t = np.einsum("ij,ij->i", d, self.along[seg])
            o = np.einsum("ij,ij->i", d, self.normal[seg])
            # Beyond the line's ends the station runs on (negative, or past the length).
            inner = np.clip(t, 0.0, self.seg_length[seg])
            first, last = seg == 0, seg == n_seg - 1
            inner = np.where(first & (t < 0), t, inner)
            inner = np.where(last & (t > self.seg_length[seg]), t, inner)
            dist = np.hypot(t - inner, o)
            better = dist < best_d
            best_d[better] = dist[better]
            best_s[better] = (self.stations[seg] + inner)[better]
            best_o[better] = o[better]
        return best_s, best_o

    def ground_at(self, station: float) -> float:
        """Metres: the poles' ground height at a station, interpolated between poles."""
        return float(np.interp(station, self.stations, self.xyz[:, 2]))
