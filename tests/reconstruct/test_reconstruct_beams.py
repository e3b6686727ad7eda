"""Beam detection and section curves (Matsumoto et al. 2019, §4.4)."""

from pathlib import Path

import numpy as np
import pytest

from guardrail_core.errors import ReconstructionError
from guardrail_core.params import ParameterError
from guardrail_core.reconstruct.beams import BeamParams, reconstruct_beam
from guardrail_core.reconstruct.unit_type import unit_type
from guardrail_core.synth.designs import thrie_beam_section, w_beam_section

LENGTH = 4.0
POST_R = 0.0699


def _section_truth():
    s = w_beam_section()
    return np.column_stack([0.1 + s[:, 0], 0.6 + s[:, 1]])  # (z, y)


def _beam_points(rng, n=6000, noise=0.002):
    truth = _section_truth()
    seg = np.linalg.norm(np.diff(truth, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    u = rng.uniform(0, cum[-1], n)
    z = np.interp(u, cum, truth[:, 0]) + 0.00115  # the front face of a 2.3 mm plate
    y = np.interp(u, cum, truth[:, 1])
    pts = np.column_stack([rng.uniform(0, LENGTH, n), y, z])
    return pts + rng.normal(0, noise, pts.shape), truth


def _posts(rng, n=500):
    pts = []
    for x in (0.0, LENGTH):
        ang = rng.uniform(-np.pi / 2, np.pi / 2, n)
        pts.append(
            np.column_stack(
                [x + POST_R * np.sin(ang), rng.uniform(0, 0.78, n), POST_R * np.cos(ang)]
            )
        )
    return np.vstack(pts)


def _hausdorff(a, b):
    def dense(p):
        t = np.linspace(0, 1, 20)[:, None]
        return np.vstack([p[i] + t * (p[i + 1] - p[i]) for i in range(len(p) - 1)])

    a, b = dense(a), dense(b)
    d = np.linalg.norm(a[:, None] - b[None], axis=-1)
    return max(d.min(0).max(), d.min(1).max())


def test_w_beam_section_within_tolerance():
    rng = np.random.default_rng(0)
    pts, truth = _beam_points(rng)
    rec = reconstruct_beam(np.vstack([pts, _posts(rng)]), LENGTH, POST_R)
    assert rec.section.shape[1] == 2 and len(rec.section) > 20
    assert np.all(np.diff(rec.section[:, 1]) > 0)  # bottom to top
    assert _hausdorff(rec.section, truth) < 0.006
    assert rec.n_points > 0.9 * len(pts)


def test_shadowed_lower_flank_is_filled_by_mirroring():
    rng = np.random.default_rng(1)
    pts, truth = _beam_points(rng, n=8000)
    # the lower flank of the upper ridge (z rising with y) cannot be seen from above
    ridge = (pts[:, 1] > 0.6 + 0.02) & (pts[:, 1] < 0.6 + 0.08)
    rec = reconstruct_beam(pts[~ridge], LENGTH, POST_R)
    assert rec.notes
    assert _hausdorff(rec.section, truth) < 0.012
    straight = reconstruct_beam(pts[~ridge], LENGTH, POST_R, BeamParams(fill_shadowed=False))
    assert _hausdorff(rec.section, truth) < _hausdorff(straight.section, truth)


def test_unit_type_tells_beams_from_pipes():
    rng = np.random.default_rng(2)
    pts, _ = _beam_points(rng)
    assert unit_type(pts, LENGTH) == "beam"

    # a pipe fence: two rails and balusters every 125 mm, densely sampled
    def block(x0, x1, y0, y1, n):
        return np.column_stack(
            [rng.uniform(x0, x1, n), rng.uniform(y0, y1, n), rng.uniform(0, 0.02, n)]
        )

    rails = [block(0.0, 2.0, y - 0.024, y + 0.024, 4000) for y in (0.15, 0.86)]
    bal = [block(x - 0.011, x + 0.011, 0.15, 0.86, 800) for x in np.arange(0.125, 2.0, 0.125)]
    assert unit_type(np.vstack(rails + bal), 2.0) == "pipe"
    assert unit_type(np.vstack(rails), 2.0) == "pipe"


UNIT_TYPES = Path(__file__).parents[1] / "data" / "unit_types_dev_streets.npz"


def _superimposed(name: str) -> tuple[np.ndarray, float]:
    data = np.load(UNIT_TYPES)
    return data[f"{name}_points_mm"] / 1000.0, float(data[f"{name}_length"])


@pytest.mark.parametrize("name", ["pipe_wave", "pipe_diagonal_x", "pipe_diamond"])
def test_pipes_crossing_every_column_are_no_beam(name):
    # Superimposed units of simulated streets (tests/data/README.md). Where a rail and the
    # trough of a wave, or the ends of diagonals near a rail, blur into one band 0.2 m tall,
    # the rows look filled; a hedge behind the diamond fills them more. Every column still
    # leaves a gap of 0.12 m or more between the pipes.
    points, length = _superimposed(name)
    assert unit_type(points, length) == "pipe"
    # Without the gap test the unit is typed beam: the gap test is what tells.
    assert unit_type(points, length, BeamParams(max_column_gap_m=2.0)) == "beam"


def test_thrie_beam_with_shadowed_valleys_stays_a_beam():
    # A thrie beam of a simulated street whose shadowed valleys leave the tallest gaps of the
    # development streets' beams (~0.08 m).
    points, length = _superimposed("beam_thrie")
    assert unit_type(points, length) == "beam"
    assert unit_type(points, length, BeamParams(max_column_gap_m=0.05)) == "pipe"


def test_beam_scanned_in_sparse_lines_stays_a_beam():
    # A multi-beam scanner's lines cross a W-beam nearly level, 4.5 cm apart (as on the KITTI
    # motorway): a column holds a point every 4.5 cm, and no taller gap.
    rng = np.random.default_rng(5)
    truth = _section_truth()
    heights = np.arange(truth[0, 1], truth[-1, 1], 0.045)
    lines = []
    for y0 in heights:
        x = rng.uniform(0.0, LENGTH, 1000)
        y = y0 + 0.01 * x / LENGTH + rng.normal(0, 0.003, len(x))
        z = np.interp(y, truth[:, 1], truth[:, 0]) + rng.normal(0, 0.005, len(x))
        lines.append(np.column_stack([x, y, z]))
    assert unit_type(np.vstack(lines), LENGTH) == "beam"


def test_no_points_give_a_note():
    rec = reconstruct_beam(np.zeros((0, 3)), LENGTH, POST_R)
    assert rec.section.shape == (0, 2) and rec.notes
    assert unit_type(np.zeros((0, 3)), LENGTH) == "pipe"


def test_only_post_points_give_a_note():
    rng = np.random.default_rng(3)
    rec = reconstruct_beam(_posts(rng), LENGTH, POST_R)
    assert rec.section.shape == (0, 2) and rec.notes


@pytest.mark.parametrize("points", [np.array([[1.0, np.inf, 0.1]]), np.zeros((3, 4)), np.zeros(3)])
def test_bad_points_raise(points):
    with pytest.raises(ReconstructionError):
        reconstruct_beam(points, LENGTH, POST_R)
    with pytest.raises(ReconstructionError):
        unit_type(points, LENGTH)


@pytest.mark.parametrize(
    ("length", "pole_radius"), [(0.0, 0.07), (4.0, -0.07), (float("nan"), 0.07)]
)
def test_bad_unit_raises(length, pole_radius):
    with pytest.raises(ReconstructionError):
        reconstruct_beam(np.zeros((0, 3)), length, pole_radius)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"slice_interval_m": -0.01},
        {"cell_m": 0.0},
        {"filled_share": 1.5},
        {"taubin_mu": 0.2},
        {"min_points": 0},
        {"min_x_spread": 1.0},
        {"max_band_gap_m": -0.1},
        {"max_column_gap_m": 0.0},
        {"gap_column_points": 0},
    ],
)
def test_params_out_of_range_raise(kwargs):
    with pytest.raises(ParameterError, match=f"BeamParams.*{next(iter(kwargs))}"):
        BeamParams(**kwargs)


def test_clutter_at_one_x_or_far_below_is_not_the_beam():
    # A sparse real scan: a blockout column at one x just below the beam, and stray ground
    # points 0.3 m under it; every slice of these holds enough points to count.
    rng = np.random.default_rng(5)
    pts, truth = _beam_points(rng)
    column = np.column_stack(
        [rng.normal(2.0, 0.02, 300), rng.uniform(0.25, 0.44, 300), rng.uniform(0.0, 0.3, 300)]
    )
    ground = np.column_stack(
        [rng.uniform(0.2, 3.8, 300), rng.uniform(0.05, 0.12, 300), rng.uniform(-0.1, 0.4, 300)]
    )
    rec = reconstruct_beam(np.vstack([pts, column, ground]), LENGTH, POST_R)
    assert abs(rec.section[:, 1].min() - truth[:, 1].min()) < 0.01
    assert _hausdorff(rec.section, truth) < 0.006
    naive = BeamParams(min_x_spread=0.0, max_band_gap_m=1.0)
    loose = reconstruct_beam(np.vstack([pts, column, ground]), LENGTH, POST_R, naive)
    assert loose.section[:, 1].min() < truth[:, 1].min() - 0.1


def test_a_shadowed_bottom_flank_is_mirrored_down_to_the_plates_edge():
    # The scanner looks down on the beam: from 15 mm below its lowest crest nothing is seen.
    rng = np.random.default_rng(6)
    pts, truth = _beam_points(rng, n=8000)
    crest = truth[np.argmax(truth[:, 0] * (truth[:, 1] < 0.6)), 1]  # the lower ridge's crest
    rec = reconstruct_beam(pts[pts[:, 1] > crest - 0.015], LENGTH, POST_R)
    assert abs(rec.section[0, 1] - truth[0, 1]) < 0.004  # down to the edge, not short of it
    assert _hausdorff(rec.section, truth) < 0.008


def _thrie_seen_from_above(seed, n=4000, noise=0.003):
    """A thrie beam's points as a scanner above the road sees them: the upward-facing flanks
    and the crests' tops only (z within 10 mm of the crest), with noise. (N, 3), truth (M, 2)."""
    rng = np.random.default_rng(seed)
    s = thrie_beam_section()
    truth = np.column_stack([0.1 + s[:, 0], 0.55 + s[:, 1]])
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(truth, axis=0), axis=1))])
    u = rng.uniform(0, cum[-1], n)
    z, y = np.interp(u, cum, truth[:, 0]), np.interp(u, cum, truth[:, 1])
    rising = np.interp(u + 1e-4, cum, truth[:, 0]) > np.interp(u - 1e-4, cum, truth[:, 0])
    seen = ~rising | (z > truth[:, 0].max() - 0.01)
    pts = np.column_stack([rng.uniform(0, LENGTH, n), y, z + 0.00115])[seen]
    return pts + rng.normal(0, noise, pts.shape), truth


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_thrie_beam_seen_from_above_is_mirrored_about_fitted_crests(seed):
    # Every ridge's lower flank and the plate below the lowest crest are unseen. The mirror
    # axis is the crest's fitted height (the highest slice centre is off by several mm on the
    # flat ridge top, and the mirrored flank by twice that), and the plate's bottom edge lies
    # half a crest spacing below the lowest crest, at the valleys' depth.
    pts, truth = _thrie_seen_from_above(seed)
    rec = reconstruct_beam(pts, LENGTH, POST_R)
    assert "shadowed flanks" in rec.notes[0]
    assert abs(rec.section[0, 1] - truth[0, 1]) < 0.004
    assert _hausdorff(rec.section, truth) < 0.007
