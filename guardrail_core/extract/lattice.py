"""The scan lattice: points indexed by (rotation, phase), their neighbours and normals (§3.1).

A profile scanner fires its pulses in a fixed order, so a point's rotation and phase numbers (from
its GPS time, Kohira et al. 2017) place it on a 2D grid whose neighbours are neighbours in space.
The grid gives every neighbour query in O(1), without a KD-tree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from guardrail_core.errors import DriveDimensionError, DriveFormatError


@dataclass(frozen=True)
class Lattice:
    """A dense grid of point indices over the rotations a drive covers.

    Attributes
    ----------
    grid : (R, P) int32, index of the point at (rotation - first_rotation, phase), -1 where no
        return was recorded. R rotations, P phases per rotation.
    first_rotation : int, rotation number of the grid's first row
    cell : (N,) int64, flat grid cell of every point (-1 for a point that lost its cell to a
        duplicate measurement of the same pulse)
    """

    grid: np.ndarray
    first_rotation: int
    cell: np.ndarray

    @property
    def phases(self) -> int:
        return int(self.grid.shape[1])

    def neighbour(
        self, d_rotation: int, d_phase: int, points: np.ndarray | None = None
    ) -> np.ndarray:
        """Index of each point's neighbour at (+d_rotation, +d_phase); -1 where there is none.

        ``points`` (M,) int selects the points asked about (default: all N). A phase step past
        the end of a rotation continues on the next rotation, as the pulses do.
        """
        rows, phases = self.grid.shape
        cell = self.cell if points is None else self.cell[points]
        target = cell + d_rotation * phases + d_phase
        ok = (cell >= 0) & (target >= 0) & (target < rows * phases)
        out = np.full(cell.shape, -1, np.int64)
        out[ok] = self.grid.ravel()[target[ok]]
        return out


def build_lattice(rotation: np.ndarray, phase: np.ndarray, points_per_rotation: int) -> Lattice:
    """Map points onto the scan lattice.

    Parameters
    ----------
    rotation, phase : (N,) int, lattice coordinates of the points (from the drive)
    points_per_rotation : int, phases per rotation (scanner parameters)

    References
    ----------
    Matsumoto et al. 2019, §3.1; Kohira et al. 2017.
    """
    rotation = np.asarray(rotation, np.int64)
    phase = np.asarray(phase, np.int64)
    if rotation.shape != phase.shape or rotation.ndim != 1:
        raise DriveDimensionError(
            f"scan lattice: rotation {rotation.shape} and phase {phase.shape} must be (N,) each"
        )
    if len(phase) and (phase.min() < 0 or phase.max() >= points_per_rotation):
        raise DriveFormatError(
            f"scan lattice: phases must lie in 0..{points_per_rotation - 1} (the scanner's points "
            f"per rotation), got {phase.min()}..{phase.max()}"
        )
    if len(rotation) == 0:
        return Lattice(np.full((1, points_per_rotation), -1, np.int32), 0, np.zeros(0, np.int64))
    first = int(rotation.min())
    rows = int(rotation.max()) - first + 1
    cell = (rotation - first) * points_per_rotation + phase
    grid = np.full(rows * points_per_rotation, -1, np.int32)
    grid[cell] = np.arange(len(cell), dtype=np.int32)
    # Two returns of one pulse keep the last; the other has no cell and no lattice neighbours.
    cell = np.where(grid[cell] == np.arange(len(cell)), cell, -1)
    return Lattice(grid.reshape(rows, points_per_rotation), first, cell)


def lattice_normals(
    xyz: np.ndarray,
    lattice: Lattice,
    *,
    max_neighbour_distance_m: float,
    phase_step: int = 4,
    points: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Surface normals from lattice neighbours.

    The normal is the cross product of the difference along the scan line (phase - k to
    phase + k) and across scan lines (rotation - 1 to rotation + 1). A missing or distant
    neighbour is replaced by the point itself (a one-sided difference).

    Parameters
    ----------
    xyz : (N, 3) float64, metres
    lattice : the points' lattice
    max_neighbour_distance_m : neighbours farther than this lie across a depth jump and are
        not used
    phase_step : k, pulses either side along the scan line. Adjacent pulses lie millimetres
        apart near the scanner, as close as the range noise, so a wider baseline is needed.
    points : (M,) int, the points whose normals are wanted (default: all N)

    Returns
    -------
    normals : (M, 3) float64 unit vectors (zeros where undefined)
    valid : (M,) bool, whether the normal is defined (both directions had a neighbour)
    """
    xyz = np.asarray(xyz, np.float64)
    points = np.arange(len(xyz)) if points is None else np.asarray(points, np.int64)
    normals = np.zeros((len(points), 3))
    valid = np.zeros(len(points), bool)
    cell = lattice.cell[points]
    _normals(
        xyz,
        points,
        cell,
        lattice.grid.ravel(),
        # Flat steps to the neighbours along the scan line and across it: +k, -k, +1 line, -1.
        np.array([phase_step, -phase_step, lattice.phases, -lattice.phases], np.int64),
        float(max_neighbour_distance_m) ** 2,
        normals,
        valid,
    )
    return normals, valid


@numba.njit(cache=True, nogil=True)
def neighbour_at(cell: int, step: int, grid: np.ndarray) -> int:  # pragma: no cover - compiled
    """:meth:`Lattice.neighbour` of one point, for compiled loops: the point at the flat
    offset ``step`` (``d_rotation * phases + d_phase``) from flat ``cell`` in the raveled
    ``grid``; -1 where there is none."""
    if cell < 0:
        return -1
    target = cell + step
    if target < 0 or target >= len(grid):
        return -1
    return grid[target]


# Compiled: one pass per point instead of some 30 numpy passes over the low points of a tile
# (most of road removal's time), the same arithmetic in the same order.
@numba.njit(cache=True, nogil=True, error_model="numpy")
def _normals(
    xyz: np.ndarray,
    points: np.ndarray,
    cell: np.ndarray,
    grid: np.ndarray,
    steps: np.ndarray,
    max_sq: float,
    normals: np.ndarray,
    valid: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Fill ``normals`` (M, 3) and ``valid`` (M,) of :func:`lattice_normals`; ``steps`` (4,):
    flat lattice offsets of the neighbours ahead and behind along the line, then across."""
    near = np.empty((4, 3))
    for m in range(len(points)):
        i = points[m]
        for k in range(4):
            near[k, 0] = xyz[i, 0]
            near[k, 1] = xyz[i, 1]
            near[k, 2] = xyz[i, 2]
            j = neighbour_at(cell[m], steps[k], grid)
            if j < 0:
                continue
            d0 = xyz[j, 0] - xyz[i, 0]
            d1 = xyz[j, 1] - xyz[i, 1]
            d2 = xyz[j, 2] - xyz[i, 2]
            if d0 * d0 + d1 * d1 + d2 * d2 > max_sq:
                continue  # across a depth jump: the point itself stands in
            near[k, 0] = xyz[j, 0]
            near[k, 1] = xyz[j, 1]
            near[k, 2] = xyz[j, 2]
        a0 = near[0, 0] - near[1, 0]
        a1 = near[0, 1] - near[1, 1]
        a2 = near[0, 2] - near[1, 2]
        b0 = near[2, 0] - near[3, 0]
        b1 = near[2, 1] - near[3, 1]
        b2 = near[2, 2] - near[3, 2]
        n0 = a1 * b2 - a2 * b1
        n1 = a2 * b0 - a0 * b2
        n2 = a0 * b1 - a1 * b0
        length = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if length > 1e-9:
            valid[m] = True
            normals[m, 0] = n0 / length
            normals[m, 1] = n1 / length
            normals[m, 2] = n2 / length
