"""Road removal (§3.1): drop road-surface points and points far from the road.

A point is road surface when it lies at or below the road height estimated from the trajectory
(within a tolerance for crown, grade and sidewalks) and its normal is close to vertical. Points
beyond the road's edges by more than a margin, or high above the road, cannot be guardrails and go
too: guardrails stand along the roadway.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from guardrail_core.errors import InvalidOptionError
from guardrail_core.extract.lattice import Lattice, lattice_normals
from guardrail_core.params import StageParams, param
from guardrail_core.sensors.track import TrackCoordinates

# Codes of :func:`remove_road`'s ``kept`` result for the points that are not kept.
ROAD = 1
OFF_ROAD = 2


@dataclass(frozen=True)
class RoadParams(StageParams):
    """Thresholds of road removal.

    The paper removes points "equal to or smaller than the estimated road height" with normals
    "close to the Z axis"; it gives no numbers, so the tolerances here are ours.
    """

    height_tolerance_m: float = param(
        0.25,
        unit="m",
        ge=0,
        le=2,
        doc="road surface lies at most this far above the trajectory's road height (crown, "
        "grade, sidewalks and verges at curb height); guardrail rails start higher",
    )
    max_normal_tilt_deg: float = param(
        25.0, unit="deg", gt=0, lt=90, doc="normals within this angle of vertical are ground"
    )
    normal_neighbour_distance_m: float = param(
        0.2,
        unit="m",
        gt=0,
        le=5,
        doc="lattice neighbours farther than this lie on another surface (a rail above the "
        "sidewalk) and are not used for normals",
    )
    normal_phase_step: int = param(
        4,
        ge=1,
        le=1000,
        doc="normals span this many pulses either side along the scan line (a baseline of "
        "centimetres, well above the range noise)",
    )
    road_level_m: float = param(
        0.08,
        unit="m",
        ge=0,
        le=1,
        doc="ground points within this height of the road height mark the roadway, whose "
        "lateral extent gives the road edges",
    )
    edge_bin_m: float = param(
        5.0,
        unit="m",
        gt=0,
        le=1000,
        doc="road edges are measured per stretch of this length along the trajectory",
    )
    edge_min_points: int = param(
        20,
        ge=1,
        le=1_000_000,
        doc="a stretch with fewer road-level points has no edges of its own: it takes its "
        "neighbours'",
    )
    edge_percentile: float = param(
        1.0,
        ge=0,
        lt=50,
        doc="percent: a stretch's road edges are this percentile of its road-level points' "
        "lateral offsets and 100 minus it (a few stray points do not widen the road)",
    )
    edge_margin_m: float = param(
        5.0,
        unit="m",
        ge=0,
        le=100,
        doc="points farther than this outside the road edges are removed as far from the road "
        "(keeps the sidewalk and what stands along it, drops the buildings behind)",
    )
    max_lateral_m: float = param(
        15.0,
        unit="m",
        gt=0,
        le=200,
        doc="hard limit on distance from the trajectory, and the road half-width assumed where "
        "a stretch has no road points",
    )
    max_height_m: float = param(
        3.0,
        unit="m",
        gt=0,
        le=100,
        doc="points higher than this above the road are removed (guardrails are about 1 m high)",
    )


def remove_road(
    xyz: np.ndarray,
    track: TrackCoordinates,
    lattice: Lattice,
    params: RoadParams = RoadParams(),
) -> np.ndarray:
    """Classify points as kept, road surface or far from the road.

    Parameters
    ----------
    xyz : (N, 3) float64, metres
    track : the points' track coordinates (station, lateral, height above the road)
    lattice : the points' scan lattice, for normals from lattice neighbours
    params : thresholds

    Returns
    -------
    (N,) uint8: 0 kept, :data:`ROAD` road surface, :data:`OFF_ROAD` far from the road.

    References
    ----------
    Matsumoto et al. 2019, §3.1.
    """
    n = len(xyz)
    lengths = {len(track.station), len(track.lateral), len(track.height), len(lattice.cell)}
    if lengths != {n}:
        raise InvalidOptionError(
            f"remove_road: {n} points but track coordinates and lattice of lengths {sorted(lengths)}"
        )
    # Normals are needed only where a point is low enough to be road surface.
    low = np.flatnonzero(track.height <= params.height_tolerance_m)
    normals, valid = lattice_normals(
        xyz,
        lattice,
        max_neighbour_distance_m=params.normal_neighbour_distance_m,
        phase_step=params.normal_phase_step,
        points=low,
    )
    vertical = np.abs(normals[:, 2]) >= np.cos(np.deg2rad(params.max_normal_tilt_deg))
    road = np.zeros(len(track.height), bool)
    # A low point without a normal is a stray ground return: nothing above the ground is that
    # isolated on the lattice.
    road[low] = vertical | ~valid

    left_edge, right_edge = _road_edges(track, road, params)
    far = (
        (track.lateral > left_edge + params.edge_margin_m)
        | (track.lateral < right_edge - params.edge_margin_m)
        | (np.abs(track.lateral) > params.max_lateral_m)
        | (track.height > params.max_height_m)
    )
    out = np.zeros(len(xyz), np.uint8)
    out[far] = OFF_ROAD
    out[road] = ROAD
    return out


def _road_edges(
    track: TrackCoordinates, road: np.ndarray, params: RoadParams
) -> tuple[np.ndarray, np.ndarray]:
    """Left and right road edge (N,) in lateral metres at every point's station.

    Per stretch of ``edge_bin_m`` the edges are the ``edge_percentile`` and 100 minus
    ``edge_percentile`` percentiles of the lateral positions of road-level ground points;
    stretches with fewer than ``edge_min_points`` take their neighbours' edges.
    """
    n = len(track.station)
    if n == 0:
        return np.zeros(0), np.zeros(0)
    level = road & (np.abs(track.height) <= params.road_level_m)
    first = np.floor(track.station.min() / params.edge_bin_m)
    bins = (np.floor(track.station / params.edge_bin_m) - first).astype(np.int64)
    n_bins = int(bins.max()) + 1
    left = np.full(n_bins, np.nan)
    right = np.full(n_bins, np.nan)
    lateral = track.lateral[level]
    level_bins = bins[level]
    order = np.argsort(level_bins, kind="stable")
    starts = np.searchsorted(level_bins[order], np.arange(n_bins + 1))
    percentile = params.edge_percentile
    for b in np.flatnonzero(np.diff(starts) >= params.edge_min_points):
        values = lateral[order[starts[b] : starts[b + 1]]]
        right[b], left[b] = np.percentile(values, [percentile, 100 - percentile])
    have = np.flatnonzero(~np.isnan(left))
    if len(have) == 0:
        return np.full(n, params.max_lateral_m), np.full(n, -params.max_lateral_m)
    centres = np.arange(n_bins)
    left = np.interp(centres, have, left[have])
    right = np.interp(centres, have, right[have])
    return left[bins], right[bins]
