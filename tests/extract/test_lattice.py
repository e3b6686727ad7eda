"""The scan lattice (§3.1): points indexed by (rotation, phase), neighbours and normals."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.errors import GuardrailError
from guardrail_core.extract.lattice import Lattice, build_lattice, lattice_normals, neighbour_at


def shuffled_grid(
    rng: np.random.Generator, rotations: int, phases: int, *, first: int = 0, holes: int = 0
) -> tuple[np.ndarray, np.ndarray, dict[tuple[int, int], int]]:
    """(rotation, phase) of a full grid minus ``holes`` random cells, in random order.

    Returns rotation (N,), phase (N,) and the map (rotation, phase) -> point index.
    """
    r, p = np.meshgrid(np.arange(rotations) + first, np.arange(phases), indexing="ij")
    r, p = r.ravel(), p.ravel()
    keep = np.ones(len(r), bool)
    keep[rng.choice(len(r), holes, replace=False)] = False
    r, p = r[keep], p[keep]
    order = rng.permutation(len(r))
    r, p = r[order], p[order]
    where = {(int(a), int(b)): i for i, (a, b) in enumerate(zip(r, p, strict=True))}
    return r, p, where


def expected_neighbour(
    r: np.ndarray,
    p: np.ndarray,
    where: dict[tuple[int, int], int],
    phases: int,
    d_rotation: int,
    d_phase: int,
) -> np.ndarray:
    """Brute force: the point at (r + d_rotation, p + d_phase), the phase wrapping onto the
    next (or previous) rotation as the pulses do; -1 where that cell is empty."""
    out = np.full(len(r), -1, np.int64)
    for i, (a, b) in enumerate(zip(r, p, strict=True)):
        flat = (int(a) + d_rotation) * phases + int(b) + d_phase
        out[i] = where.get((flat // phases, flat % phases), -1)
    return out


@pytest.mark.parametrize(
    ("d_rotation", "d_phase"), [(0, 1), (0, -1), (1, 0), (-1, 0), (0, 4), (0, -4), (2, -3), (1, 9)]
)
def test_neighbours_on_a_shuffled_grid_with_holes(d_rotation: int, d_phase: int) -> None:
    rng = np.random.default_rng(10)
    rotations, phases = 7, 12
    r, p, where = shuffled_grid(rng, rotations, phases, first=1000, holes=15)
    lattice = build_lattice(r, p, phases)

    assert lattice.grid.shape == (rotations, phases)
    assert lattice.first_rotation == 1000
    assert lattice.phases == phases
    got = lattice.neighbour(d_rotation, d_phase)
    assert got.dtype == np.int64
    np.testing.assert_array_equal(got, expected_neighbour(r, p, where, phases, d_rotation, d_phase))


def test_grid_holds_every_point_at_its_cell() -> None:
    rng = np.random.default_rng(11)
    r, p, _ = shuffled_grid(rng, 5, 8, first=-3, holes=6)
    lattice = build_lattice(r, p, 8)
    np.testing.assert_array_equal(lattice.grid[r - lattice.first_rotation, p], np.arange(len(r)))
    np.testing.assert_array_equal(lattice.cell, (r + 3) * 8 + p)
    assert (lattice.grid == -1).sum() == 6
    assert lattice.grid.dtype == np.int32


def test_next_phase_walks_the_whole_grid_in_firing_order() -> None:
    """Following neighbour(0, 1) from the first pulse visits every point once, in order."""
    rng = np.random.default_rng(12)
    rotations, phases = 4, 9
    r, p, where = shuffled_grid(rng, rotations, phases)
    following = build_lattice(r, p, phases).neighbour(0, 1)
    visited = [where[(0, 0)]]
    while following[visited[-1]] >= 0:
        visited.append(int(following[visited[-1]]))
    assert len(visited) == rotations * phases
    np.testing.assert_array_equal(r[visited] * phases + p[visited], np.arange(rotations * phases))


def test_ends_of_the_grid_have_no_neighbour() -> None:
    rng = np.random.default_rng(13)
    r, p, where = shuffled_grid(rng, 3, 5)
    lattice = build_lattice(r, p, 5)
    assert lattice.neighbour(0, 1)[where[(2, 4)]] == -1
    assert lattice.neighbour(0, -1)[where[(0, 0)]] == -1
    last_row = np.flatnonzero(r == 2)
    first_row = np.flatnonzero(r == 0)
    assert (lattice.neighbour(1, 0)[last_row] == -1).all()
    assert (lattice.neighbour(-1, 0)[first_row] == -1).all()
    assert (lattice.neighbour(3, 0) == -1).all()
    np.testing.assert_array_equal(lattice.neighbour(0, 0), np.arange(len(r)))


def test_duplicate_measurements_of_one_pulse_keep_one_cell() -> None:
    """Two returns of one pulse: the last keeps the cell; the other has no cell and no
    neighbours, and nobody has it as a neighbour."""
    rotation = np.array([0, 0, 0, 1, 0, 1])
    phase = np.array([0, 1, 2, 1, 1, 1])  # (0, 1) twice: points 1 and 4; (1, 1) twice: 3 and 5
    lattice = build_lattice(rotation, phase, 3)

    np.testing.assert_array_equal(lattice.grid, [[0, 4, 2], [-1, 5, -1]])
    np.testing.assert_array_equal(lattice.cell, [0, -1, 2, -1, 1, 4])
    for d_rotation, d_phase in [(0, 1), (0, -1), (1, 0), (-1, 0)]:
        got = lattice.neighbour(d_rotation, d_phase)
        assert got[1] == -1 and got[3] == -1
        assert 1 not in got and 3 not in got
    np.testing.assert_array_equal(lattice.neighbour(0, 1), [4, -1, -1, -1, 2, -1])
    np.testing.assert_array_equal(lattice.neighbour(1, 0), [-1, -1, -1, -1, 5, -1])


def test_empty_lattice() -> None:
    lattice = build_lattice(np.zeros(0, np.int64), np.zeros(0, np.int64), 16)
    assert lattice.neighbour(0, 1).shape == (0,)
    normals, valid = lattice_normals(np.zeros((0, 3)), lattice, max_neighbour_distance_m=0.5)
    assert normals.shape == (0, 3) and valid.shape == (0,)


@pytest.mark.parametrize(
    ("rotation", "phase"),
    [
        pytest.param([0, 0, 1], [-1, 0, 0], id="negative-phase"),
        pytest.param([0, 0, 1], [0, 2, 0], id="phase-past-points-per-rotation"),
        pytest.param([0, 1], [0, 0, 1], id="lengths-differ"),
    ],
)
def test_phase_outside_a_rotation_is_a_named_error(rotation: list[int], phase: list[int]) -> None:
    with pytest.raises(GuardrailError):
        build_lattice(np.array(rotation), np.array(phase), 2)


def plane_lattice(
    rotations: int,
    phases: int,
    *,
    rotation_step: float = 0.1,
    phase_step: float = 0.05,
    normal: np.ndarray,
) -> tuple[np.ndarray, Lattice, np.ndarray, np.ndarray]:
    """Points on the plane through (1, 2, 3) with ``normal``, rotations along one in-plane axis
    and phases along the other. Returns xyz (N, 3), the lattice, rotation and phase."""
    normal = normal / np.linalg.norm(normal)
    u = np.cross(normal, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    r, p = np.meshgrid(np.arange(rotations), np.arange(phases), indexing="ij")
    r, p = r.ravel(), p.ravel()
    xyz = (
        np.array([1.0, 2.0, 3.0]) + (r * rotation_step)[:, None] * u + (p * phase_step)[:, None] * v
    )
    return xyz, build_lattice(r, p, phases), r, p


def angle_to(normals: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Angle (degrees) between unit normals (N, 3) and ``normal``, up to sign."""
    normal = normal / np.linalg.norm(normal)
    return np.degrees(np.arccos(np.clip(np.abs(normals @ normal), 0.0, 1.0)))


def test_normals_of_a_tilted_plane() -> None:
    normal = np.array([0.3, -0.5, 0.8])
    xyz, _, r, p = plane_lattice(20, 40, normal=normal)
    rng = np.random.default_rng(14)
    order = rng.permutation(len(xyz))  # the lattice, not the order, gives the neighbours
    xyz, lattice = xyz[order], build_lattice(r[order], p[order], 40)

    normals, valid = lattice_normals(xyz, lattice, max_neighbour_distance_m=0.5)

    assert valid.all()  # the grid's edges use one-sided differences
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    assert angle_to(normals, normal).max() < 0.5


def test_normals_of_a_noisy_plane_need_the_wide_baseline() -> None:
    """5 mm of range noise on a plane sampled every 5 cm along the scan line and 10 cm across:
    with phase_step=4 (a 40 cm baseline) every normal with neighbours on both sides lies within
    10 degrees, the median within 2.5; adjacent pulses (phase_step=1) are 1.5 times as far off
    at the median."""
    rng = np.random.default_rng(15)
    normal = np.array([0.0, 0.6, 0.8])
    xyz, lattice, r, p = plane_lattice(40, 60, normal=normal)
    xyz = xyz + rng.normal(0.0, 0.005, (len(xyz), 1)) * normal / np.linalg.norm(normal)

    wide, valid = lattice_normals(xyz, lattice, max_neighbour_distance_m=0.5, phase_step=4)
    narrow, _ = lattice_normals(xyz, lattice, max_neighbour_distance_m=0.5, phase_step=1)

    assert valid.all()
    error = angle_to(wide, normal)
    two_sided = (r > 0) & (r < 39) & (p >= 4) & (p < 56)
    assert error[two_sided].max() < 10.0
    assert np.median(error) < 2.5
    assert np.median(angle_to(narrow, normal)) > 1.5 * np.median(error)


def test_neighbours_across_a_depth_jump_are_not_used() -> None:
    """Two parallel horizontal planes 1 m apart, split along the scan line: every normal is
    vertical, including those of the points beside the jump (one-sided differences)."""
    r, p = np.meshgrid(np.arange(10), np.arange(30), indexing="ij")
    r, p = r.ravel(), p.ravel()
    xyz = np.column_stack([r * 0.1, p * 0.05, np.where(p < 15, 0.0, 1.0)])
    normals, valid = lattice_normals(xyz, build_lattice(r, p, 30), max_neighbour_distance_m=0.5)
    assert valid.all()
    np.testing.assert_allclose(np.abs(normals[:, 2]), 1.0, atol=1e-12)


def test_a_point_without_neighbours_has_no_normal() -> None:
    """An isolated point, a point whose neighbours are all too far, and a point on a lone scan
    line (neighbours along it but none across) have valid False and a zero normal."""
    # Scan line 0: phases 0..9 on a line; scan line 5: one point; scan line 7: a point far from
    # its neighbours on scan lines 6 and 8.
    rotation = np.array([0] * 10 + [5, 6, 7, 8])
    phase = np.array(list(range(10)) + [3, 3, 3, 3])
    xyz = np.zeros((14, 3))
    xyz[:10, 1] = np.arange(10) * 0.05
    xyz[10] = [0.5, 0.0, 0.0]
    xyz[11:, 0] = [0.6, 0.7, 0.8]
    xyz[12, 2] = 5.0  # scan line 7's point is 5 m above its neighbours
    normals, valid = lattice_normals(
        xyz, build_lattice(rotation, phase, 10), max_neighbour_distance_m=0.5
    )
    expected = np.zeros(14, bool)
    np.testing.assert_array_equal(valid, expected)
    np.testing.assert_array_equal(normals, 0.0)


def test_neighbours_and_normals_of_a_subset_equal_those_of_all_points() -> None:
    rng = np.random.default_rng(16)
    normal = np.array([0.2, 0.1, 1.0])
    xyz, lattice, _, _ = plane_lattice(15, 30, normal=normal)
    xyz = xyz + rng.normal(0.0, 0.003, xyz.shape)
    subset = rng.choice(len(xyz), 100, replace=False)

    for d_rotation, d_phase in [(0, 4), (-1, 0), (1, -2)]:
        np.testing.assert_array_equal(
            lattice.neighbour(d_rotation, d_phase, subset),
            lattice.neighbour(d_rotation, d_phase)[subset],
        )
    all_normals, all_valid = lattice_normals(xyz, lattice, max_neighbour_distance_m=0.5)
    normals, valid = lattice_normals(xyz, lattice, max_neighbour_distance_m=0.5, points=subset)
    assert normals.shape == (100, 3)
    np.testing.assert_array_equal(valid, all_valid[subset])
    np.testing.assert_allclose(normals, all_normals[subset], rtol=0, atol=1e-15)
    empty, empty_valid = lattice_normals(
        xyz, lattice, max_neighbour_distance_m=0.5, points=np.zeros(0, np.int64)
    )
    assert empty.shape == (0, 3) and empty_valid.shape == (0,)


def test_the_compiled_neighbour_lookup_is_the_lattices() -> None:
    """neighbour_at (what the compiled normals and components use) answers as neighbour does,
    gaps, duplicates and the grid's edges included."""
    rng = np.random.default_rng(5)
    phases = 7
    rotation = rng.integers(10, 16, 60)
    phase = rng.integers(0, phases, 60)
    lattice = build_lattice(rotation, phase, phases)
    grid = lattice.grid.ravel()
    for d_rotation, d_phase in [(0, 1), (0, -3), (1, 0), (-1, 2), (2, -6), (6, 0), (0, 0)]:
        expected = lattice.neighbour(d_rotation, d_phase)
        step = d_rotation * phases + d_phase
        got = [neighbour_at(int(c), step, grid) for c in lattice.cell]
        np.testing.assert_array_equal(got, expected)
