"""Points that another unit confirms (§4.2-4.3): the unit shape is what repeats unit after
unit. A shrub pressed against one unit's rails, or a hedge's face behind them, leaves streaks
of points that the chaining of §4.3 follows as pipes, that pull a wave's chain off its course,
or that fill the gap under an arch's crown. Such points behind the unit's plane with no point
of another unit near them are strays (:func:`strays_behind`). In the plane a pipe may show in
one unit alone (a scan line running along a diagonal), so there nothing is asked of them.

Near means in the same cube of ``confirm_cell_m`` or in one of its 26 neighbours (so up to
two cells apart along each axis): cubes rather than a radius, since a dense superimposition
holds hundreds of points within a few centimetres of each point, too many to list pair by
pair.
"""

from __future__ import annotations

import itertools

import numpy as np

from guardrail_core.errors import ReconstructionError
from guardrail_core.reconstruct.pipes.params import PipeParams

#: Cube offsets of a cell's neighbourhood, itself included: (27, 3).
_NEIGHBOURS = np.array(list(itertools.product((-1, 0, 1), repeat=3)), np.int64)
#: Keys of cells hold each coordinate, shifted to be non-negative, in this many bits.
_BITS = 20


def strays_behind(points: np.ndarray, unit_of_point: np.ndarray, p: PipeParams) -> np.ndarray:
    """Mask (N,) of the points (N, 3) more than ``confirm_behind_m`` behind the median depth
    (z) of all of them that no other unit confirms (``confirm_cell_m``); none in a run of fewer
    than ``confirm_min_units`` units.

    Raises
    ------
    ReconstructionError
        The arrays disagree in length.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    unit = np.asarray(unit_of_point).reshape(-1)
    if len(unit) != len(points):
        raise ReconstructionError(
            f"{len(points)} points but {len(unit)} units of points: one unit per point"
        )
    if len(points) == 0 or len(np.unique(unit)) < p.confirm_min_units:
        return np.zeros(len(points), bool)
    behind = points[:, 2] < np.median(points[:, 2]) - p.confirm_behind_m
    if not behind.any():
        return behind
    return behind & ~confirmed_by_another_unit(points, unit, p.confirm_cell_m)


def confirmed_by_another_unit(
    points: np.ndarray, unit_of_point: np.ndarray, cell: float
) -> np.ndarray:
    """Which points have a point of another unit near them.

    Parameters
    ----------
    points : (N, 3) float64, unit coordinates, metres
    unit_of_point : (N,) int, the unit each point came from
    cell : float, metres: the cube size of "near" (see the module's notes)

    Returns
    -------
    (N,) bool

    Raises
    ------
    ReconstructionError
        The arrays disagree in length, or ``cell`` is not positive.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    unit = np.asarray(unit_of_point, np.int64).reshape(-1)
    if len(unit) != len(points):
        raise ReconstructionError(
            f"{len(points)} points but {len(unit)} units of points: one unit per point"
        )
    if not cell > 0:
        raise ReconstructionError(f"the cell must be a positive length, got {cell}")
    if len(points) == 0:
        return np.zeros(0, bool)
    ijk = np.floor((points - points.min(axis=0)) / cell).astype(np.int64) + 1
    if int(ijk.max()) >= (1 << _BITS) - 1:
        raise ReconstructionError(f"the points span too many cells of {cell} m")
    key = _keys(ijk)
    # Per cell: how many units hold points in it, and one of them (the only one where 1).
    pairs = np.unique(np.column_stack([key, unit]), axis=0)
    cells, first, n_units = np.unique(pairs[:, 0], return_index=True, return_counts=True)
    some_unit = pairs[first, 1]
    confirmed = np.zeros(len(points), bool)
    for offset in _NEIGHBOURS:
        neighbour = _keys(ijk + offset)
        at = np.clip(np.searchsorted(cells, neighbour), 0, len(cells) - 1)
        there = cells[at] == neighbour
        other = there & ((n_units[at] > 1) | (some_unit[at] != unit))
        confirmed |= other
    return confirmed


def _keys(ijk: np.ndarray) -> np.ndarray:
    """One int64 key (M,) per cell index triple (M, 3), each index in [0, 2**_BITS)."""
    return (ijk[:, 0] << (2 * _BITS)) | (ijk[:, 1] << _BITS) | ijk[:, 2]
