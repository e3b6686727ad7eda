"""Sliced segments (§3.1): lattice wireframe components, 0.5 m slices and their summaries."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from guardrail_core.extract.lattice import build_lattice
from guardrail_core.extract.segments import (
    SegmentParams,
    Segments,
    absorb_fragments,
    summarise_segments,
    wireframe_components,
)
from guardrail_core.extract.slices import slice_components

#: The thresholds these scenes are built around (the defaults at the time of writing).
PARAMS = SegmentParams(
    link_distance_m=0.3, along_reach=3, rotation_reach=2, phase_reach=4, slice_length_m=0.5
)


def test_default_slices_are_the_papers_half_metre() -> None:
    assert SegmentParams().slice_length_m == 0.5


class LatticeScene:
    """A full (rotation, phase) grid of background points, not kept, placed 50 m below
    everything (so they could link to nothing), into which objects are written."""

    def __init__(self, rotations: int, phases: int, rng: np.random.Generator) -> None:
        self.phases = phases
        r, p = np.meshgrid(np.arange(rotations), np.arange(phases), indexing="ij")
        self.rotation, self.phase = r.ravel(), p.ravel()
        self.xyz = rng.uniform(-100.0, 100.0, (len(self.rotation), 3))
        self.xyz[:, 2] -= 150.0
        self.kept = np.zeros(len(self.rotation), bool)
        self.present = np.ones(len(self.rotation), bool)
        self.object = np.full(len(self.rotation), -1)

    def cells(self, rotation: np.ndarray, phase: np.ndarray) -> np.ndarray:
        return np.asarray(rotation) * self.phases + np.asarray(phase)

    def put(self, name: int, rotation, phase, xyz) -> None:
        cell = self.cells(rotation, phase)
        self.xyz[cell] = xyz
        self.kept[cell] = True
        self.object[cell] = name

    def build(self, rng: np.random.Generator):
        """Points present, in random order: xyz, kept, object, rotation, phase, lattice."""
        index = rng.permutation(np.flatnonzero(self.present))
        rotation, phase = self.rotation[index], self.phase[index]
        lattice = build_lattice(rotation, phase, self.phases)
        return self.xyz[index], self.kept[index], self.object[index], rotation, phase, lattice


def rail(scene: LatticeScene, name: int, rotations, phases, *, y: float, spacing=0.1) -> None:
    """A horizontal rail: on every given rotation (x = spacing * r) a short vertical profile
    of 5 cm steps at lateral y, one point per given phase."""
    r, k = np.meshgrid(np.asarray(rotations), np.arange(len(phases)), indexing="ij")
    r, k = r.ravel(), k.ravel()
    xyz = np.column_stack([spacing * r + 0.05, np.full(len(r), y), 0.5 + 0.05 * k])
    scene.put(name, r, np.asarray(phases)[k], xyz)


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two labelings group the points identically (up to renumbering)."""
    pairs = np.unique(np.stack([a, b], axis=1), axis=0)
    return len(pairs) == len(np.unique(a)) == len(np.unique(b))


def test_two_rails_beside_each_other_are_two_components() -> None:
    """Two rails 1 m apart whose pulses are lattice neighbours (phases 8-10 and 11-13, within
    phase_reach) are two components; the background points are not kept and get -1."""
    rng = np.random.default_rng(30)
    scene = LatticeScene(100, 20, rng)
    rail(scene, 0, range(100), [8, 9, 10], y=2.0)
    rail(scene, 1, range(100), [11, 12, 13], y=3.0)
    xyz, kept, obj, _, _, lattice = scene.build(rng)

    component = wireframe_components(xyz, kept, lattice, PARAMS)

    assert component.dtype == np.int32 and component.shape == (len(xyz),)
    assert (component[~kept] == -1).all()
    assert set(np.unique(component[kept]).tolist()) == {0, 1}
    assert same_partition(component[kept], obj[kept])
    # Numbered in order of each component's first point.
    assert component[np.flatnonzero(kept)[0]] == 0


@pytest.mark.parametrize(("shift", "expected"), [(0.2, 1), (0.5, 2)])
def test_a_jump_beyond_the_link_distance_splits(shift: float, expected: int) -> None:
    """A rail that steps sideways by ``shift`` halfway: 0.1 m between scan lines and a 0.2 m
    step are within 0.3 m; a 0.5 m step is not."""
    rng = np.random.default_rng(31)
    scene = LatticeScene(60, 12, rng)
    rail(scene, 0, range(30), [4, 5, 6], y=2.0)
    rail(scene, 1, range(30, 60), [4, 5, 6], y=2.0 + shift)
    xyz, kept, obj, _, _, lattice = scene.build(rng)

    component = wireframe_components(xyz, kept, lattice, PARAMS)

    assert len(np.unique(component[kept])) == expected
    if expected == 2:
        assert same_partition(component[kept], obj[kept])


@pytest.mark.parametrize(("missing", "expected"), [((), 1), ((20,), 1), ((20, 21), 2)])
@pytest.mark.parametrize("how", ["absent", "not kept"])
def test_missing_scan_lines_are_bridged_up_to_rotation_reach(
    missing: tuple[int, ...], expected: int, how: str
) -> None:
    """Scan lines 5 cm apart: one missing line is bridged (rotation_reach=2); two are not,
    though the 15 cm across them is within the link distance."""
    rng = np.random.default_rng(32)
    scene = LatticeScene(40, 10, rng)
    rail(scene, 0, range(40), [3, 4, 5], y=2.0, spacing=0.05)
    gone = np.isin(scene.rotation, missing)
    if how == "absent":
        scene.present[gone] = False
    else:
        scene.kept[gone] = False
    xyz, kept, _, _, _, lattice = scene.build(rng)

    component = wireframe_components(xyz, kept, lattice, PARAMS)

    assert len(np.unique(component[kept])) == expected


@pytest.mark.parametrize(
    ("dropped", "expected"), [((), 1), ((15,), 1), ((15, 16), 1), ((15, 16, 17), 2)]
)
@pytest.mark.parametrize("how", ["absent", "not kept"])
def test_dropped_pulses_are_bridged_up_to_along_reach(
    dropped: tuple[int, ...], expected: int, how: str
) -> None:
    """A post scanned by one scan line, pulses 5 cm apart: up to two dropped pulses in a row
    are bridged (along_reach=3), three are not, though 20 cm is within the link distance."""
    rng = np.random.default_rng(33)
    scene = LatticeScene(1, 30, rng)
    phase = np.arange(30)
    scene.put(
        0, np.zeros(30, int), phase, np.column_stack([np.zeros(30), np.zeros(30), 0.05 * phase])
    )
    gone = np.isin(scene.phase, dropped)
    if how == "absent":
        scene.present[gone] = False
    else:
        scene.kept[gone] = False
    xyz, kept, _, _, phase, lattice = scene.build(rng)

    component = wireframe_components(xyz, kept, lattice, PARAMS)

    assert len(np.unique(component[kept])) == expected
    if expected == 2:
        assert same_partition(component[kept], (phase[kept] > 15).astype(int))


def brute_force_components(
    xyz: np.ndarray, kept: np.ndarray, rotation: np.ndarray, phase: np.ndarray, phases: int
) -> np.ndarray:
    """Components from every pair of kept points whose flat lattice cells differ by one of the
    wireframe's window offsets and that lie closer than the link distance."""
    offsets = {d for d in range(1, PARAMS.along_reach + 1)} | {
        r * phases + d
        for r in range(1, PARAMS.rotation_reach + 1)
        for d in range(-PARAMS.phase_reach, PARAMS.phase_reach + 1)
    }
    cell = rotation * phases + phase
    idx = np.flatnonzero(kept)
    i, j = np.meshgrid(idx, idx, indexing="ij")
    i, j = i.ravel(), j.ravel()
    linked = np.isin(np.abs(cell[j] - cell[i]), list(offsets))
    linked &= np.linalg.norm(xyz[i] - xyz[j], axis=1) < PARAMS.link_distance_m
    n = len(xyz)
    graph = coo_matrix((np.ones(linked.sum()), (i[linked], j[linked])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def test_components_equal_a_brute_force_wireframe() -> None:
    """Jittered points, some cells empty, some points not kept: the components are those of
    the wireframe built pair by pair, numbered in order of their first point."""
    rng = np.random.default_rng(34)
    rotations, phases = 24, 20
    r, p = np.meshgrid(np.arange(rotations), np.arange(phases), indexing="ij")
    r, p = r.ravel(), p.ravel()
    present = rng.random(len(r)) > 0.1
    r, p = r[present], p[present]
    order = rng.permutation(len(r))
    r, p = r[order], p[order]
    xyz = np.column_stack([0.1 * r, 0.05 * p, np.zeros(len(r))]) + rng.normal(0, 0.25, (len(r), 3))
    kept = rng.random(len(r)) > 0.2

    component = wireframe_components(xyz, kept, build_lattice(r, p, phases), PARAMS)
    truth = brute_force_components(xyz, kept, r, p, phases)

    assert (component[~kept] == -1).all()
    assert same_partition(component[kept], truth[kept])
    sizes = np.unique(truth[kept], return_counts=True)[1]
    n_components = len(sizes)
    # The fixture is neither one blob nor dust: many components of several points.
    assert (sizes > 1).sum() >= 10 and sizes.max() < 0.8 * kept.sum()
    _, first = np.unique(component[kept], return_index=True)
    np.testing.assert_array_equal(component[kept][np.sort(first)], np.arange(n_components))


def test_nothing_kept() -> None:
    rng = np.random.default_rng(35)
    scene = LatticeScene(5, 6, rng)
    xyz, kept, _, _, _, lattice = scene.build(rng)
    component = wireframe_components(xyz, kept, lattice, PARAMS)
    np.testing.assert_array_equal(component, -1)

    segments = slice_components(component, xyz[:, 0], PARAMS)
    assert len(segments) == 0
    assert (segments.point_segment == -1).all() and len(segments.point_segment) == len(xyz)
    np.testing.assert_array_equal(segments.starts, [0])
    summary = summarise_segments(xyz, np.zeros(len(xyz)), xyz[:, 1], xyz[:, 2], segments)
    assert summary.centroid.shape == (0, 3) and summary.bbox_min.shape == (0, 3)
    assert summary.lateral.shape == summary.height.shape == summary.time.shape == (0, 2)


def test_a_ten_metre_rail_is_twenty_slices() -> None:
    """Two rails of 100 scan lines at x = 0.05 + 0.1 r (10 m), three pulses per line: 20 slices
    each, 5 scan lines x 3 pulses = 15 points per segment, ids ordered by slice then rail."""
    rng = np.random.default_rng(36)
    scene = LatticeScene(100, 20, rng)
    rail(scene, 0, range(100), [8, 9, 10], y=2.0)
    rail(scene, 1, range(100), [11, 12, 13], y=3.0)
    xyz, kept, obj, _, _, lattice = scene.build(rng)
    component = wireframe_components(xyz, kept, lattice, PARAMS)

    segments = slice_components(component, xyz[:, 0], PARAMS)

    assert isinstance(segments, Segments)
    assert len(segments) == 40
    np.testing.assert_array_equal(segments.n_points, 15)
    np.testing.assert_array_equal(segments.slice_index, np.repeat(np.arange(20), 2))
    np.testing.assert_array_equal(segments.component, np.tile([0, 1], 20))
    for s in range(40):
        members = segments.members(s)
        assert len(np.unique(obj[members])) == 1
        assert (np.floor(xyz[members, 0] / 0.5) == segments.slice_index[s]).all()


def test_slices_are_half_open_and_continue_below_zero() -> None:
    station = np.array([0.0, 0.4999, 0.5, 1.0, -0.0001, -0.5, -0.50001])
    segments = slice_components(np.zeros(7, np.int64), station, PARAMS)
    np.testing.assert_array_equal(segments.slice_index, [-2, -1, 0, 1, 2])
    np.testing.assert_array_equal(segments.point_segment, [2, 2, 3, 4, 1, 1, 0])


def _median_slice(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One component in one slice, across: a rail at 6.35 m (300 points) with its post 0.1 m
    behind (20 points), a hedge thinly spread over 6.6-7.5 m (40 points), a rail at 8.1 m (300).
    Returns station, lateral and the truth piece (0 near rail and post, 1 hedge, 2 far rail)."""
    lateral = np.concatenate(
        [
            rng.normal(6.35, 0.02, 300),
            rng.normal(6.45, 0.01, 20),
            rng.uniform(6.6, 7.5, 40),
            rng.normal(8.1, 0.02, 300),
        ]
    )
    truth = np.repeat([0, 0, 1, 2], [300, 20, 40, 300])
    return rng.uniform(0.0, 0.5, len(lateral)), lateral, truth


def test_a_wide_slice_is_cut_where_its_points_thin_out_across() -> None:
    station, lateral, truth = _median_slice(np.random.default_rng(40))
    component = np.zeros(len(lateral), np.int64)
    segments = slice_components(component, station, PARAMS, lateral)
    assert len(segments) == 3
    for s in range(3):  # each piece is one thing: the post stays with its rail
        assert len(np.unique(truth[segments.members(s)])) == 1
    np.testing.assert_array_equal(segments.component, 0)
    np.testing.assert_array_equal(segments.slice_index, 0)
    # Without lateral offsets, or with the cut turned off, the slice stays whole.
    assert len(slice_components(component, station, PARAMS)) == 1
    whole = SegmentParams(max_width_m=0.0, gap_width_m=0.0)
    assert len(slice_components(component, station, whole, lateral)) == 1


def test_a_rail_is_cut_from_the_hedge_just_behind_it() -> None:
    """A pipe rail (60 points at 5.2 m) with a hedge 0.12 m behind it, dense at its face and
    thinning over 0.6 m (400 points): no wide valley, but an empty gap."""
    rng = np.random.default_rng(42)
    rail = rng.normal(5.2, 0.005, 60)
    hedge = 5.35 + rng.exponential(0.12, 400).clip(0, 0.6)
    lateral = np.concatenate([rail, hedge])
    station = rng.uniform(0.0, 0.5, len(lateral))
    component = np.zeros(len(lateral), np.int64)
    segments = slice_components(component, station, PARAMS, lateral)
    assert len(segments) == 2
    np.testing.assert_array_equal(segments.n_points, [60, 400])
    assert (lateral[segments.members(0)] < 5.25).all()
    # The same rail and hedge in a slice no wider than gap_width_m, or with the cut off, stay one.
    narrow = SegmentParams(gap_width_m=float(np.ptp(lateral)) + 0.01)
    assert len(slice_components(component, station, narrow, lateral)) == 1
    off = SegmentParams(gap_width_m=0.0)
    assert len(slice_components(component, station, off, lateral)) == 1


def test_a_post_behind_its_beam_stays_with_it_across_a_gap() -> None:
    """A W-beam 0.25 m deep (400 points), its post's few hits 0.2-0.35 m behind it and a
    sparse scan's clutter at the road edge: gaps of 0.1 m and more, but no piece beside them
    spans 0.4 m, so nothing is cut."""
    rng = np.random.default_rng(43)
    beam = rng.uniform(-4.95, -4.70, 400)
    post = rng.uniform(-5.30, -5.15, 6)
    clutter = rng.choice(np.arange(-4.55, -4.25, 0.12), 12)
    lateral = np.concatenate([beam, post, clutter])
    station = rng.uniform(0.0, 0.5, len(lateral))
    segments = slice_components(np.zeros(len(lateral), np.int64), station, PARAMS, lateral)
    assert np.ptp(lateral) > PARAMS.gap_width_m
    assert len(segments) == 1


def test_a_narrow_or_evenly_filled_slice_stays_whole() -> None:
    rng = np.random.default_rng(41)
    station = rng.uniform(0.0, 0.5, 400)
    beam_and_post = np.concatenate([rng.normal(4.8, 0.02, 380), rng.normal(5.3, 0.01, 20)])
    wall = rng.uniform(3.0, 6.0, 400)  # 3 m wide, evenly filled
    for lateral in (beam_and_post, wall):
        segments = slice_components(np.zeros(400, np.int64), station, PARAMS, lateral)
        assert len(segments) == 1


def random_segments(seed: int, n: int = 3000) -> tuple[np.ndarray, np.ndarray, Segments]:
    """Random components (-1: not kept; sparse numbers) and stations, including negative."""
    rng = np.random.default_rng(seed)
    component = rng.choice([-1, 0, 1, 2, 5, 9], n)
    station = rng.uniform(-3.0, 7.0, n)
    return component, station, slice_components(component, station, PARAMS)


@pytest.mark.parametrize("seed", [37, 38])
def test_every_kept_point_is_in_exactly_one_segment(seed: int) -> None:
    component, station, segments = random_segments(seed)
    kept = np.flatnonzero(component >= 0)
    n = len(segments)

    assert segments.point_segment.dtype == np.int32
    np.testing.assert_array_equal(segments.point_segment >= 0, component >= 0)
    np.testing.assert_array_equal(segments.point_component, component)
    members = np.concatenate([segments.members(s) for s in range(n)])
    np.testing.assert_array_equal(np.sort(members), kept)  # a permutation of the kept points
    assert segments.n_points.sum() == len(kept)
    np.testing.assert_array_equal(segments.n_points, np.bincount(segments.point_segment[kept]))
    np.testing.assert_array_equal(np.diff(segments.starts), segments.n_points)
    assert segments.starts[0] == 0 and segments.starts[-1] == len(kept)
    # One segment per (slice, component) pair present, ids in order of slice then component.
    slices = np.floor(station[kept] / 0.5).astype(int)
    pairs = set(zip(slices.tolist(), component[kept].tolist(), strict=True))
    assert len(pairs) == n
    keys = list(zip(segments.slice_index.tolist(), segments.component.tolist(), strict=True))
    assert keys == sorted(pairs)
    for s in range(n):
        m = segments.members(s)
        assert (segments.point_segment[m] == s).all()
        assert (component[m] == segments.component[s]).all()
        assert (station[m] >= 0.5 * segments.slice_index[s]).all()
        assert (station[m] < 0.5 * (segments.slice_index[s] + 1)).all()


def test_summary_equals_a_per_segment_computation() -> None:
    component, station, segments = random_segments(39)
    rng = np.random.default_rng(40)
    n = len(component)
    xyz = rng.normal(0.0, 10.0, (n, 3)) + np.array([5e5, 4e6, 30.0])  # big map coordinates
    gps_time = rng.uniform(1e9, 1e9 + 100.0, n)
    lateral, height = rng.uniform(-15, 15, n), rng.uniform(-1, 3, n)

    summary = summarise_segments(xyz, gps_time, lateral, height, segments)

    for s in range(len(segments)):
        m = segments.members(s)
        np.testing.assert_allclose(summary.centroid[s], xyz[m].mean(axis=0), rtol=1e-15, atol=0)
        np.testing.assert_array_equal(summary.bbox_min[s], xyz[m].min(axis=0))
        np.testing.assert_array_equal(summary.bbox_max[s], xyz[m].max(axis=0))
        np.testing.assert_array_equal(summary.lateral[s], [lateral[m].min(), lateral[m].max()])
        np.testing.assert_array_equal(summary.height[s], [height[m].min(), height[m].max()])
        np.testing.assert_array_equal(summary.time[s], [gps_time[m].min(), gps_time[m].max()])


def test_summary_centroids_to_a_picometre_near_the_origin() -> None:
    component, _, segments = random_segments(41)
    rng = np.random.default_rng(42)
    xyz = rng.uniform(-20.0, 20.0, (len(component), 3))
    zeros = np.zeros(len(component))
    summary = summarise_segments(xyz, zeros, zeros, zeros, segments)
    expected = np.array([xyz[segments.members(s)].mean(axis=0) for s in range(len(segments))])
    np.testing.assert_allclose(summary.centroid, expected, rtol=0, atol=1e-12)


def test_fragments_join_the_nearest_large_component_within_reach() -> None:
    params = SegmentParams(fragment_points=10, fragment_reach_m=0.3)
    # Component 0: a rail of 40 points along x at y = 0; component 1: a rail at y = 1 m.
    # Fragment 2 lies 0.2 m from rail 0; fragment 3 lies 0.25 m from rail 1 and 0.75 m from
    # rail 0; fragment 4 is 0.5 m from everything; points of 5 are not kept.
    x = np.linspace(0.0, 3.9, 40)
    rail_0 = np.stack([x, np.zeros(40), np.zeros(40)], axis=1)
    rail_1 = np.stack([x, np.ones(40), np.zeros(40)], axis=1)
    fragment_2 = np.array([[1.0, 0.2, 0.0], [1.05, 0.3, 0.0]])
    fragment_3 = np.array([[2.0, 0.75, 0.0], [2.0, 0.7, 0.05], [2.05, 0.6, 0.1]])
    fragment_4 = np.array([[6.0, 0.5, 0.0]])
    not_kept = np.array([[1.0, 0.1, 0.0]])
    xyz = np.concatenate([rail_0, rail_1, fragment_2, fragment_3, fragment_4, not_kept])
    component = np.repeat([0, 1, 2, 3, 4, -1], [40, 40, 2, 3, 1, 1])
    merged = absorb_fragments(xyz, component, params)
    expected = np.repeat([0, 1, 0, 1, 2, -1], [40, 40, 2, 3, 1, 1])
    np.testing.assert_array_equal(merged, expected)
    assert merged.dtype == np.int32


def test_a_fragment_goes_whole_to_the_component_its_closest_point_reaches() -> None:
    params = SegmentParams(fragment_points=5, fragment_reach_m=0.3)
    a = np.stack([np.linspace(0, 1, 10), np.zeros(10), np.zeros(10)], axis=1)
    b = a + [0.0, 0.5, 0.0]
    # One point 0.2 m from a, one 0.1 m from b: the whole fragment goes to b.
    fragment = np.array([[0.5, 0.2, 0.0], [0.5, 0.4, 0.0]])
    component = np.repeat([0, 1, 2], [10, 10, 2])
    merged = absorb_fragments(np.concatenate([a, b, fragment]), component, params)
    np.testing.assert_array_equal(merged[20:], [1, 1])


@pytest.mark.parametrize("reach", [0.0, 0.1])
def test_no_reach_or_nothing_near_leaves_components_as_they_are(reach: float) -> None:
    params = SegmentParams(fragment_points=10, fragment_reach_m=reach)
    rail = np.stack([np.linspace(0, 2, 20), np.zeros(20), np.zeros(20)], axis=1)
    fragment = np.array([[1.0, 0.2, 0.0]])
    component = np.repeat([0, 1], [20, 1])
    merged = absorb_fragments(np.concatenate([rail, fragment]), component, params)
    np.testing.assert_array_equal(merged, component)


def _post_and_foot() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A post (60 points, 0.3-1.0 m above the road) and, 0.17 m below it, its foot with the
    sidewalk around it (20 points, 0.05-0.13 m): two components, as road removal leaves them."""
    post = np.stack([np.zeros(60), np.zeros(60), np.linspace(0.3, 1.0, 60)], axis=1)
    foot = np.stack(
        [np.linspace(-0.1, 0.1, 20), np.full(20, -0.05), np.linspace(0.05, 0.13, 20)], axis=1
    )
    xyz = np.concatenate([post, foot])
    return xyz, np.repeat([0, 1], [60, 20]), xyz[:, 2]


def test_a_post_foot_cut_off_near_the_ground_joins_its_post() -> None:
    xyz, component, height = _post_and_foot()
    params = SegmentParams(fragment_points=10, ground_fragment_points=30)
    np.testing.assert_array_equal(absorb_fragments(xyz, component, params, height), 0)
    # Without heights, or with the rule off, 20 points are no fragment.
    np.testing.assert_array_equal(absorb_fragments(xyz, component, params), component)
    off = SegmentParams(fragment_points=10, ground_fragment_points=0)
    np.testing.assert_array_equal(absorb_fragments(xyz, component, off, height), component)


@pytest.mark.parametrize(("raised_m", "points"), [(0.2, 30), (0.0, 20)])
def test_a_ground_fragment_reaches_no_higher_and_holds_fewer_points(
    raised_m: float, points: int
) -> None:
    """Raised 0.2 m (top 0.33 m: a low rail's reach), or of 20 points against a limit of 20,
    the piece stays a component of its own."""
    xyz, component, height = _post_and_foot()
    height = height + np.where(component == 1, raised_m, 0.0)
    params = SegmentParams(fragment_points=10, ground_fragment_points=points)
    np.testing.assert_array_equal(absorb_fragments(xyz, component, params, height), component)


def test_fragments_with_nothing_large_or_nothing_kept() -> None:
    xyz = np.zeros((3, 3))
    np.testing.assert_array_equal(
        absorb_fragments(xyz, np.array([0, 1, 2])), [0, 1, 2]
    )  # all small: nothing to join
    np.testing.assert_array_equal(absorb_fragments(xyz, np.full(3, -1)), [-1, -1, -1])
