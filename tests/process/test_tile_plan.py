"""Processing tiles: edges on slice edges, the drive's ends open, a short remainder joined."""

from __future__ import annotations

import math

import pytest

from guardrail_core.errors import InvalidOptionError
from guardrail_core.process.tile_plan import plan_tiles


@pytest.mark.parametrize(
    ("length_m", "edges"),
    [
        (300.4, [100.0, 200.0]),  # 0.4 m left over: part of the last tile
        (349.9, [100.0, 200.0]),
        (350.0, [100.0, 200.0, 300.0]),  # half a tile left over: a tile of its own
        (420.0, [100.0, 200.0, 300.0]),
        (160.0, [100.0]),
        (140.0, []),
        (149.0, []),
        (40.0, []),
    ],
)
def test_tiles_cover_the_drive_with_a_short_remainder_joined(
    length_m: float, edges: list[float]
) -> None:
    tiles = plan_tiles(length_m, 100.0, 10.0, 0.5)
    bounds = [-math.inf, *edges, math.inf]
    assert [t.station_m for t in tiles] == list(zip(bounds[:-1], bounds[1:], strict=True))
    assert [t.number for t in tiles] == list(range(len(tiles)))
    for tile in tiles:
        assert tile.window_m == (tile.station_m[0] - 10.0, tile.station_m[1] + 10.0)


def test_one_tile_when_none_is_asked_for_or_the_tile_is_longer_than_the_drive() -> None:
    whole = (-math.inf, math.inf)
    assert [t.station_m for t in plan_tiles(300.0, None, 10.0, 0.5)] == [whole]
    assert [t.station_m for t in plan_tiles(300.0, 400.0, 10.0, 0.5)] == [whole]


def test_a_tile_that_is_not_a_whole_number_of_slices_or_a_negative_margin_is_refused() -> None:
    with pytest.raises(InvalidOptionError, match="multiple of the 0.5 m slice"):
        plan_tiles(300.0, 100.2, 10.0, 0.5)
    with pytest.raises(InvalidOptionError, match="margin must be 0 m or more"):
        plan_tiles(300.0, 100.0, -1.0, 0.5)
