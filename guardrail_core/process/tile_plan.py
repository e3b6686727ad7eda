"""Processing tiles: stretches of the trajectory, each processed with a margin of its neighbours.

A tile *owns* the points whose station (metres along the trajectory,
:mod:`guardrail_core.sensors.track`) lies in its stretch, and *sees* its stretch widened by the
margin on both sides: components, slices, label correction and the shape features of a point
near a tile's edge then come out as they would in the whole drive. Tile edges fall on slice
edges (multiples of the slice length), so every 0.5 m slice, and every segment in it, belongs to
exactly one tile.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from guardrail_core.errors import InvalidOptionError


@dataclass(frozen=True)
class ProcessTile:
    """One processing tile.

    Attributes
    ----------
    number : 0, 1, ... along the drive
    station_m : [first, last) metres it owns; -inf and +inf at the drive's ends
    window_m : [first, last) metres it sees: ``station_m`` widened by the margin
    """

    number: int
    station_m: tuple[float, float]
    window_m: tuple[float, float]

    def owns(self, station: float) -> bool:
        return self.station_m[0] <= station < self.station_m[1]


def plan_tiles(
    length_m: float, tile_m: float | None, margin_m: float, slice_length_m: float
) -> list[ProcessTile]:
    """Cut a drive of ``length_m`` metres of trajectory into tiles of ``tile_m`` metres
    (None: one tile owning everything), each seeing ``margin_m`` metres beyond both ends. The
    last tile owns the rest of the drive: from half a tile to one and a half.

    Raises
    ------
    InvalidOptionError
        ``tile_m`` is not a positive multiple of ``slice_length_m`` (a slice would straddle two
        tiles), or ``margin_m`` is negative.
    """
    if not margin_m >= 0:
        raise InvalidOptionError(f"the tile margin must be 0 m or more, got {margin_m}")
    if tile_m is None or tile_m >= length_m:
        return [ProcessTile(0, (-math.inf, math.inf), (-math.inf, math.inf))]
    slices = tile_m / slice_length_m
    if not tile_m > 0 or abs(slices - round(slices)) > 1e-9:
        raise InvalidOptionError(
            f"tiles must be a positive multiple of the {slice_length_m} m slice, got {tile_m} m"
        )
    # A remainder shorter than half a tile joins the last tile: a task of a few metres would
    # cost a worker's round (and its margins) for almost nothing.
    count = max(1, math.floor(length_m / tile_m + 0.5))
    tiles = []
    for k in range(count):
        lo = -math.inf if k == 0 else k * tile_m
        hi = math.inf if k == count - 1 else (k + 1) * tile_m
        tiles.append(ProcessTile(k, (lo, hi), (lo - margin_m, hi + margin_m)))
    return tiles
