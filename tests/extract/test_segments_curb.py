"""A curb under the front of a rail is linked apart from it (``SegmentParams.curb_gap_m``,
:mod:`guardrail_core.extract.curbs`): the posts of a rail set just behind a curb join the two
into one component, and a slice without a post holds both, with an empty band between them."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.extract.curbs import curb_points, separate_curbs
from guardrail_core.extract.segments import SegmentParams, wireframe_components
from tests.extract.test_segments import LatticeScene

PARAMS = SegmentParams()


def _beam_over_curb(
    rng: np.random.Generator, side: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One slice of one component, as a far W-beam behind a curb is scanned: the beam's plate
    (200 points, 0.58-0.92 m above the road, its face 2.0 m from the path and 9 cm deep), and
    in front of it a curb (80 points, 1.84-1.93 m from the path, 0-0.15 m high) with a few
    road points before it. ``side`` -1 puts it right of the path. Returns station, lateral,
    height (N,) and which points are the beam's (N,) bool."""
    beam_depth = 2.0 + rng.uniform(0.0, 0.09, 200)
    beam_height = rng.uniform(0.58, 0.92, 200)
    curb_depth = np.concatenate([rng.uniform(1.84, 1.93, 80), rng.uniform(1.77, 1.84, 6)])
    curb_height = np.concatenate([rng.uniform(0.0, 0.15, 80), rng.uniform(-0.01, 0.01, 6)])
    lateral = side * np.concatenate([beam_depth, curb_depth])
    height = np.concatenate([beam_height, curb_height])
    beam = np.repeat([True, False], [200, 86])
    return rng.uniform(0.0, 0.5, len(lateral)), lateral, height, beam


def _curb(
    station: np.ndarray, lateral: np.ndarray, height: np.ndarray, params=PARAMS
) -> np.ndarray:
    return curb_points(np.zeros(len(station), np.int64), station, lateral, height, params)


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_a_curb_under_a_beams_front_is_found(side: float) -> None:
    station, lateral, height, beam = _beam_over_curb(np.random.default_rng(60), side)
    np.testing.assert_array_equal(_curb(station, lateral, height), ~beam)


def test_no_curb_is_found_when_turned_off() -> None:
    station, lateral, height, _ = _beam_over_curb(np.random.default_rng(61))
    assert not _curb(station, lateral, height, SegmentParams(curb_gap_m=0.0)).any()


def test_a_slice_holding_the_post_that_joins_them_has_no_curb() -> None:
    """The post (0.1 m behind the beam's face, from the curb's top to the beam's) fills the
    band."""
    rng = np.random.default_rng(62)
    station, lateral, height, _ = _beam_over_curb(rng)
    station = np.concatenate([station, rng.uniform(0.2, 0.34, 60)])
    lateral = np.concatenate([lateral, rng.uniform(2.1, 2.24, 60)])
    height = np.concatenate([height, rng.uniform(0.15, 0.9, 60)])
    assert not _curb(station, lateral, height).any()


def test_in_a_slice_a_post_fills_the_curb_before_its_foot_is_curb_too() -> None:
    """Slice 0: the beam over the curb; slice 1: the same with the beam's post (0.1 m behind
    the beam's face, from the curb's top up) filling the band: the curb is curb in both, the
    post's foot is not."""
    rng = np.random.default_rng(68)
    parts = [_beam_over_curb(rng), _beam_over_curb(rng)]
    post = rng.uniform(0.5, 0.64, 60), rng.uniform(2.1, 2.24, 60), rng.uniform(0.15, 0.9, 60)
    station = np.concatenate([parts[0][0], parts[1][0] + 0.5, post[0] + 0.5])
    lateral = np.concatenate([parts[0][1], parts[1][1], post[1]])
    height = np.concatenate([parts[0][2], parts[1][2], post[2]])
    beam = np.concatenate([parts[0][3], parts[1][3], np.ones(60, bool)])
    curb = curb_points(np.zeros(len(station), np.int64), station, lateral, height, PARAMS)
    np.testing.assert_array_equal(curb, ~beam)


@pytest.mark.parametrize(
    ("what", "depth", "rise"),
    [
        ("ground sloping into a ditch", (1.84, 1.93), (-0.3, 0.1)),
        ("grass", (1.2, 1.93), (0.0, 0.15)),
    ],
)
def test_ground_or_grass_before_a_fence_is_no_curb(
    what: str, depth: tuple[float, float], rise: tuple[float, float]
) -> None:
    """Under the band, in front of what stands above it, but rising 0.4 m (the ground of a
    ditch's or an embankment's slope) or spreading 0.7 m across (grass): no curb."""
    rng = np.random.default_rng(69)
    station, lateral, height, beam = _beam_over_curb(rng)
    n = int((~beam).sum())
    lateral[~beam] = rng.uniform(*depth, n)
    height[~beam] = rng.uniform(*rise, n)
    assert not _curb(station, lateral, height).any(), what


@pytest.mark.parametrize("bottom", [0.15, 0.2, 0.25])
def test_a_pipe_rails_bottom_rail_under_its_top_rail_is_no_curb(bottom: float) -> None:
    """Two pipes (radius 2.4 cm) in one plane 2 m from the path, the bottom one 0.15-0.25 m
    above the road: a band of 0.6 m between them, but the bottom pipe is not in front."""
    rng = np.random.default_rng(63)
    n = 80
    depth = 2.0 + rng.uniform(0.0, 0.024, 2 * n)
    height = np.concatenate([rng.normal(bottom, 0.012, n), rng.normal(bottom + 0.65, 0.012, n)])
    assert not _curb(rng.uniform(0.0, 0.5, 2 * n), depth, height).any()


def test_a_curb_end_or_a_few_low_hits_are_no_curb() -> None:
    """What lies under the band spans less than curb_min_length_m along the slice (a curb's
    end), or holds fewer than curb_min_points."""
    rng = np.random.default_rng(64)
    station, lateral, height, beam = _beam_over_curb(rng)
    short = station.copy()
    short[~beam] = rng.uniform(0.0, 0.15, int((~beam).sum()))
    assert not _curb(short, lateral, height).any()
    keep = beam | (np.cumsum(~beam) <= PARAMS.curb_min_points - 1)
    assert not _curb(station[keep], lateral[keep], height[keep]).any()


def test_the_rest_of_a_curb_under_a_rail_is_curb_too() -> None:
    """Slice 0: the beam over the curb; slice 1: the curb alone (the same component); slice 2:
    a low object alone, of a component with no curb under a rail."""
    rng = np.random.default_rng(65)
    station, lateral, height, beam = _beam_over_curb(rng)
    curb_on = rng.uniform(0.5, 1.0, 80), rng.uniform(1.84, 1.93, 80), rng.uniform(0, 0.15, 80)
    low = rng.uniform(1.0, 1.5, 40), rng.uniform(3.0, 3.2, 40), rng.uniform(0.0, 0.25, 40)
    station, lateral, height = (
        np.concatenate(parts)
        for parts in zip((station, lateral, height), curb_on, low, strict=True)
    )
    component = np.repeat([0, 1], [len(beam) + 80, 40])
    curb = curb_points(component, station, lateral, height, PARAMS)
    np.testing.assert_array_equal(
        curb, np.concatenate([~beam, np.ones(80, bool), np.zeros(40, bool)])
    )


def _rails_on_a_curb(rng: np.random.Generator):
    """A scan lattice (10 cm between scan lines): a curb 1.85 m from the path, 0-0.1 m high, on
    all 100 scan lines (object 0); two rails 2 m from the path, 0.6-0.8 m high, on scan lines
    0-29 and 60-89 (objects 1 and 2), each with one post (scan lines 12 and 72, 5 cm behind
    the rail's face) from the curb's top to the rail. Returns xyz, kept, object, lattice."""
    scene = LatticeScene(100, 16, rng)
    r = np.arange(100)

    def put(name: int, rotations: np.ndarray, phases: range, y: float, z: np.ndarray) -> None:
        rr, kk = np.meshgrid(rotations, np.arange(len(phases)), indexing="ij")
        xyz = np.column_stack([0.1 * rr.ravel(), np.full(rr.size, y), z[kk.ravel()]])
        scene.put(name, rr.ravel(), np.asarray(phases)[kk.ravel()], xyz)

    put(0, r, range(0, 3), 1.85, np.array([0.0, 0.05, 0.1]))
    for name, (first, post) in enumerate([(0, 12), (60, 72)], start=1):
        put(name, r[first : first + 30], range(10, 15), 2.0, np.linspace(0.6, 0.8, 5))
        put(name, np.array([post]), range(3, 10), 2.05, np.linspace(0.16, 0.55, 7))
    xyz, kept, obj, _, _, lattice = scene.build(rng)
    return xyz, kept, obj, lattice


def test_two_rails_joined_by_a_curb_through_their_posts_are_linked_apart() -> None:
    """The wireframe makes one component of the curb, the rails and their posts; with the
    curbs separated, each rail with its post is a component and the curb is no rail's, in the
    posts' slices too."""
    xyz, kept, obj, lattice = _rails_on_a_curb(np.random.default_rng(66))
    before = wireframe_components(xyz, kept, lattice, PARAMS)
    assert len(np.unique(before[kept])) == 1
    station, lateral, height = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    after = separate_curbs(xyz, before, lattice, station, lateral, height, PARAMS)
    np.testing.assert_array_equal(after < 0, ~kept)
    rail_a, rail_b = (np.unique(after[obj == name]) for name in (1, 2))
    assert len(rail_a) == 1 and len(rail_b) == 1 and rail_a[0] != rail_b[0]
    assert not np.isin(after[obj == 0], [rail_a[0], rail_b[0]]).any()


def test_components_are_returned_as_they_are_where_no_curb_is_found() -> None:
    xyz, kept, _, lattice = _rails_on_a_curb(np.random.default_rng(67))
    before = wireframe_components(xyz, kept, lattice, PARAMS)
    off = SegmentParams(curb_gap_m=0.0)
    after = separate_curbs(xyz, before, lattice, xyz[:, 0], xyz[:, 1], xyz[:, 2], off)
    np.testing.assert_array_equal(after, before)
