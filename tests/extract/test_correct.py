"""Label correction (§3.3): segment labels made to agree with their neighbours."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.errors import GuardrailError
from guardrail_core.extract.classify.label_correction import correct_labels, correction_reach_slices
from guardrail_core.extract.classify.label_correction_params import CorrectionParams
from guardrail_core.extract.classify.segment_extents import SegmentExtents, neighbour_pairs

#: A guardrail beam's cross-section beside the road: lateral and height extents (metres).
BEAM = (2.0, 2.1, 0.3, 1.0)
#: A curb just inside the guardrail: 10 cm away laterally (within the touch distance).
CURB = (1.7, 1.9, 0.0, 0.13)


def extents(
    *segments: tuple[int, tuple[float, float, float, float]], component=None, n_points=None
) -> SegmentExtents:
    """Extents from (slice, (lateral lo, lateral hi, height lo, height hi)) per segment, all of
    one wireframe component and of 100 points unless ``component`` and ``n_points`` (S,) say
    otherwise."""
    if not segments:
        empty = np.zeros(0, np.int64)
        return SegmentExtents(empty, np.zeros((0, 2)), np.zeros((0, 2)), empty, empty)
    slices = np.array([s for s, _ in segments], np.int64)
    box = np.array([b for _, b in segments], np.float64)
    if component is None:
        component = np.zeros(len(slices), np.int64)
    if n_points is None:
        n_points = np.full(len(slices), 100, np.int64)
    return SegmentExtents(
        slices,
        box[:, :2],
        box[:, 2:],
        np.asarray(component, np.int64),
        np.asarray(n_points, np.int64),
    )


def run(slices, box=BEAM) -> list[tuple[int, tuple[float, float, float, float]]]:
    return [(s, box) for s in slices]


def test_an_other_segment_inside_a_run_becomes_guardrail() -> None:
    labels = np.ones(10, bool)
    labels[4] = False
    corrected = correct_labels(labels, extents(*run(range(10))))
    assert corrected.dtype == bool
    np.testing.assert_array_equal(corrected, np.ones(10, bool))


def test_a_segment_the_classifier_is_sure_of_is_not_filled() -> None:
    """Holes of one and of two slices; the floor, and NaN (no answer) fillable."""
    labels = np.ones(12, bool)
    labels[[3, 7, 8]] = False
    probability = np.full(12, 0.9)
    probability[[3, 7, 8]] = [0.05, 0.3, 0.09]
    segments = extents(*run(range(12)))
    np.testing.assert_array_equal(correct_labels(labels, segments), np.ones(12, bool))
    floor = correct_labels(labels, segments, CorrectionParams(), probability)
    np.testing.assert_array_equal(np.flatnonzero(~floor), [3, 7, 8])  # a hole of two: both or none
    probability[[3, 8]] = [0.1, np.nan]
    np.testing.assert_array_equal(correct_labels(labels, segments, probability=probability), True)
    off = CorrectionParams(fill_min_probability=0.0)
    np.testing.assert_array_equal(correct_labels(labels, segments, off, probability * 0), True)
    with pytest.raises(GuardrailError, match="probabilities of shape"):
        correct_labels(labels, segments, probability=probability[:5])


def rail_band(
    rng: np.random.Generator, slices: np.ndarray, component: np.ndarray
) -> SegmentExtents:
    """Random segments of rails, posts, curbs and hedges in a narrow band beside the road, in
    ``slices`` (S,) and of ``component`` (S,): most segments touch, runs are long."""
    n = len(slices)
    lateral = rng.choice([1.7, 2.0, 2.05, 2.4], n) + rng.uniform(0.0, 0.05, n)
    height = rng.choice([0.0, 0.3, 0.6], n) + rng.uniform(0.0, 0.1, n)
    return SegmentExtents(
        slices,
        np.column_stack([lateral, lateral + rng.uniform(0.05, 0.2, n)]),
        np.column_stack([height, height + rng.uniform(0.1, 0.7, n)]),
        np.asarray(component, np.int64),
        rng.integers(1, 20, n),
    )


#: A wire row of a mesh fence 4.4 m off: a thin horizontal piece, as a pipe rail is.
WIRE = (4.40, 4.42, 0.60, 0.62)
NAN = np.nan


def test_a_short_component_whose_crops_say_other_is_other() -> None:
    """Four slices of a wire row the head called guardrail by its shape; the crops of three of
    them say other."""
    labels = np.ones(4, bool)
    segments = extents(*run(range(4), WIRE))
    crops = np.array([0.02, NAN, 0.2, 0.1])
    assert not correct_labels(labels, segments, crop_probability=crops).any()
    # Three of four crops saying other are enough if crop_veto_share asks for 0.75 (not by
    # default: one crop saying guardrail saves a component), and one crop is if one is all the
    # rule asks for.
    three = [0.02, 0.9, 0.2, 0.1]
    assert correct_labels(labels, segments, crop_probability=three).all()
    most = CorrectionParams(crop_veto_share=0.75)
    assert not correct_labels(labels, segments, most, crop_probability=three).any()
    one = CorrectionParams(crop_veto_min_crops=1)
    assert not correct_labels(labels, segments, one, crop_probability=[0.02, NAN, NAN, NAN]).any()
    # No crops, one crop, two of four saying guardrail, the rule off, a shorter limit: kept.
    kept = {
        "no crops": ([NAN] * 4, CorrectionParams()),
        "one crop": ([0.02, NAN, NAN, NAN], CorrectionParams()),
        "two of four": ([0.02, 0.9, 0.2, 0.7], most),
        "off": (crops, CorrectionParams(crop_veto_max_slices=0)),
        "longer than the limit": (crops, CorrectionParams(crop_veto_max_slices=3)),
    }
    for name, (crop_probability, params) in kept.items():
        corrected = correct_labels(labels, segments, params, crop_probability=crop_probability)
        assert corrected.all(), name
    assert correct_labels(labels, segments).all()  # no crop probabilities given: no veto
    with pytest.raises(GuardrailError, match="crop probabilities of shape"):
        correct_labels(labels, segments, crop_probability=crops[:2])


def test_a_component_longer_than_the_limit_keeps_the_label_of_its_shape() -> None:
    """A rail whose crops all say other (a design the CNN never saw): over 20 slices its shape
    decides, up to 20 its crops."""
    crops = np.full(21, 0.1)
    assert correct_labels(np.ones(21, bool), extents(*run(range(21))), crop_probability=crops).all()
    twenty = extents(*run(range(20)))
    assert not correct_labels(np.ones(20, bool), twenty, crop_probability=crops[:20]).any()


def test_the_crops_of_one_component_do_not_overrule_another() -> None:
    """A rail (component 0, 10 slices, its crops not sure but guardrail) and a bracket's piece
    inside its cross-section (component 1, slices 3-5, its crops saying other). Without the
    infill of a railing and the spare of what rests on a rail the piece is other, its middle
    slice not filled though it lies inside the rail's run; the rail keeps its label. With
    either, the piece lies wholly inside the rail's slices and is guardrail whatever its crops
    say."""
    bracket = (2.02, 2.08, 0.5, 0.6)
    segments = extents(*run(range(10)), *run(range(3, 6), bracket), component=[0] * 10 + [1] * 3)
    labels = np.ones(13, bool)
    labels[11] = False
    crops = np.r_[np.full(10, 0.6), 0.1, 0.2, 0.05]
    neither = CorrectionParams(infill_max_slices=0, crop_veto_rest_share=np.inf)
    assert correct_labels(labels, segments, neither).all()  # without crops: the hole is filled
    corrected = correct_labels(labels, segments, neither, crop_probability=crops)
    np.testing.assert_array_equal(corrected, np.r_[np.ones(10, bool), False, False, False])
    assert correct_labels(labels, segments, crop_probability=crops).all()
    no_infill = CorrectionParams(infill_max_slices=0)
    assert correct_labels(labels, segments, no_infill, crop_probability=crops).all()


#: A railing's lower part (posts, lower rails) 2.2 m off, and its top rail, 1.0-1.25 m up, that
#: the wireframe keeps apart: the side camera sees the top rail as a thin strip.
RAILING_BELOW = (2.15, 2.25, 0.11, 1.0)
TOP_RAIL = (2.17, 2.23, 1.02, 1.25)


def test_a_top_rail_resting_on_its_railing_is_spared_the_crop_veto() -> None:
    """The railing (component 0, 17 slices, crops saying guardrail) and its top rail (component
    1, the same slices, two crops saying other). The top rail rests on the railing: its crops
    do not overrule its shape. Not spared: the rule off; the top rail beside the railing rather
    than on it, wider than a rail, on a railing called other, on one its own crops veto, or
    resting on it in fewer than half its slices."""
    slices = range(17)
    component = [0] * 17 + [1] * 17
    labels = np.ones(34, bool)

    def crops_of(railing_slices: int) -> np.ndarray:
        """Two crops of the railing saying guardrail, two of the top rail saying other."""
        crops = np.full(railing_slices + 17, NAN)
        crops[[2, 3]] = 0.9
        crops[[railing_slices + 4, railing_slices + 12]] = [0.35, 0.04]
        return crops

    crops = crops_of(17)
    segments = extents(*run(slices, RAILING_BELOW), *run(slices, TOP_RAIL), component=component)
    assert correct_labels(labels, segments, crop_probability=crops).all()
    off = CorrectionParams(crop_veto_rest_share=np.inf)
    vetoed = np.r_[np.ones(17, bool), np.zeros(17, bool)]
    np.testing.assert_array_equal(
        correct_labels(labels, segments, off, crop_probability=crops), vetoed
    )
    not_spared = {
        "beside": extents(
            *run(slices, RAILING_BELOW), *run(slices, (2.35, 2.4, 1.02, 1.25)), component=component
        ),
        "too high": extents(
            *run(slices, RAILING_BELOW), *run(slices, (2.17, 2.23, 1.35, 1.6)), component=component
        ),
        "wide": extents(
            *run(slices, RAILING_BELOW), *run(slices, (2.0, 2.25, 1.02, 1.25)), component=component
        ),
        "on a third of its slices": extents(
            *run(range(6), RAILING_BELOW), *run(slices, TOP_RAIL), component=[0] * 6 + [1] * 17
        ),
    }
    for name, where in not_spared.items():
        n = len(where.slice_index)
        corrected = correct_labels(np.ones(n, bool), where, crop_probability=crops_of(n - 17))
        np.testing.assert_array_equal(corrected, np.arange(n) < n - 17, err_msg=name)
    # The railing called other by its shape, or vetoed by its own crops: no rail to rest on.
    other_below = labels.copy()
    other_below[:17] = False
    np.testing.assert_array_equal(
        correct_labels(other_below, segments, crop_probability=crops), np.zeros(34, bool)
    )
    both_other = crops.copy()
    both_other[[2, 3]] = 0.1
    np.testing.assert_array_equal(
        correct_labels(labels, segments, crop_probability=both_other), np.zeros(34, bool)
    )


@pytest.mark.parametrize("seed", [70, 71])
def test_crops_beyond_the_reach_do_not_change_a_corrected_label(seed: int) -> None:
    """Components spanning up to 7, 20 (crop_veto_max_slices) and 21 slices, raw labels and
    crop probabilities drawn again beyond the reach: what lets a processing tile ask the CNN
    only near the slices it owns."""
    params = CorrectionParams()
    reach = correction_reach_slices(params)
    rng = np.random.default_rng(seed)
    n = 900
    slices = rng.integers(0, 140, n)
    kind = rng.integers(0, 3, n)
    offset = rng.integers(0, 30, 3)  # components do not all start at slice 0
    component = kind * 1000 + (slices + offset[kind]) // np.array([7, 20, 21])[kind]
    ext = rail_band(rng, slices, component)

    def draw(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Labels and crops of ``rows``: the crops of half the components, drawn anew each
        time, all say other."""
        m = len(rows)
        other = rng.random(int(component.max()) + 1) < 0.5
        crops = np.where(other[component[rows]], 0.49, 1.0) * rng.random(m)
        return rng.random(m) < 0.7, np.where(rng.random(m) < 0.3, NAN, crops)

    core = (slices >= 60) & (slices < 80)
    near = (slices >= 60 - reach) & (slices < 80 + reach)
    vetoed = 0
    for _ in range(20):
        labels, crops = draw(np.arange(n))
        corrected = correct_labels(labels, ext, params, crop_probability=crops)
        beyond_labels, beyond_crops = draw(np.flatnonzero(~near))
        labels[~near], crops[~near] = beyond_labels, beyond_crops
        np.testing.assert_array_equal(
            correct_labels(labels, ext, params, crop_probability=crops)[core], corrected[core]
        )
        vetoed += int((corrected != correct_labels(labels, ext, params))[core].sum())
    assert vetoed > 20  # the fixture exercises the veto


#: A mesh fence 4.4 m off, 1.2 m tall: thin beside the road, as the wire rows within it.
FENCE = (4.39, 4.43, 0.05, 1.2)


def long_object_with_a_stretch_called_guardrail(
    stretch: range, box=FENCE, length: int = 40
) -> tuple[np.ndarray, SegmentExtents]:
    """One component of ``length`` slices of ``box``, called other but in ``stretch``."""
    labels = np.isin(np.arange(length), list(stretch))
    return labels, extents(*run(range(length), box))


def test_a_few_slices_of_a_long_object_called_other_are_other() -> None:
    """Slices 18-21 of a 40-slice fence called guardrail: 4 of the 41 slices around them (at
    most 0.25); a run of four, which the paper's rules keep."""
    labels, segments = long_object_with_a_stretch_called_guardrail(range(18, 22))
    assert not correct_labels(labels, segments).any()
    off = CorrectionParams(object_window_slices=0)
    np.testing.assert_array_equal(correct_labels(labels, segments, off), labels)
    # 11 of the 41 slices (0.27) are too many, and near a short fence's end 14 other slices
    # around (15 are asked for) too few; 15 are enough.
    for stretch, length in ((range(15, 26), 40), (range(14, 18), 18)):
        labels, segments = long_object_with_a_stretch_called_guardrail(stretch, length=length)
        np.testing.assert_array_equal(correct_labels(labels, segments), labels)
    labels, segments = long_object_with_a_stretch_called_guardrail(range(14, 18), length=19)
    assert not correct_labels(labels, segments).any()


def test_a_rail_joined_to_a_long_curb_stays_guardrail() -> None:
    """A 10-slice rail (slices 15-24) of the same component as a 40-slice curb below it: the
    curb does not reach the rail's mid-height, so the rail is not a piece of it. A hedge as
    long, reaching above the rail, takes it (10 of 50 segments around are guardrail)."""
    for below, kept in ((CURB, True), (HEDGE, False)):
        segments = extents(*run(range(40), below), *run(range(15, 25)))
        labels = np.r_[np.zeros(40, bool), np.ones(10, bool)]
        corrected = correct_labels(labels, segments)
        np.testing.assert_array_equal(corrected[40:], kept)


def wire_inside_a_fence(
    host_probability: float = 0.01, host=FENCE, host_slices: int = 30
) -> tuple[np.ndarray, SegmentExtents, np.ndarray]:
    """A fence (component 0, ``host_slices``, called other with ``host_probability``) and a
    wire row come apart from it (component 1, slices 10-13, called guardrail, P 0.99)."""
    segments = extents(
        *run(range(host_slices), host),
        *run(range(10, 14), WIRE),
        component=[0] * host_slices + [1] * 4,
    )
    labels = np.r_[np.zeros(host_slices, bool), np.ones(4, bool)]
    probability = np.r_[np.full(host_slices, host_probability), np.full(4, 0.99)]
    return labels, segments, probability


def test_a_short_piece_within_a_fences_outline_is_other() -> None:
    labels, segments, probability = wire_inside_a_fence()
    assert not correct_labels(labels, segments, probability=probability).any()
    # Without the probabilities the rule does not apply, nor when it is off.
    np.testing.assert_array_equal(correct_labels(labels, segments), labels)
    off = CorrectionParams(inside_max_slices=0)
    np.testing.assert_array_equal(correct_labels(labels, segments, off, probability), labels)
    kept = {
        "the fence not sure": wire_inside_a_fence(host_probability=0.2),
        "a wide host: a hedge": wire_inside_a_fence(host=(4.2, 4.8, 0.0, 1.6)),
        "a short host": wire_inside_a_fence(host_slices=9),
        "outside the outline": wire_inside_a_fence(host=(4.39, 4.43, 0.7, 1.2)),
    }
    for name, (labels, segments, probability) in kept.items():
        corrected = correct_labels(labels, segments, probability=probability)
        np.testing.assert_array_equal(corrected, labels, err_msg=name)
    # A piece of a component longer than inside_max_slices is not a piece.
    labels, segments, probability = wire_inside_a_fence()
    three = CorrectionParams(inside_max_slices=3)
    np.testing.assert_array_equal(correct_labels(labels, segments, three, probability), labels)


@pytest.mark.parametrize("seed", [72, 73])
def test_long_objects_beyond_the_reach_do_not_change_a_corrected_label(seed: int) -> None:
    """Long components called other but for a few slices, short pieces within them, labels
    and probabilities drawn again beyond the reach."""
    params = CorrectionParams()
    reach = correction_reach_slices(params)
    rng = np.random.default_rng(seed)
    n = 1500
    slices = rng.integers(0, 160, n)
    kind = rng.integers(0, 3, n)
    component = kind * 1000 + slices // np.array([5, 40, 90])[kind]
    ext = rail_band(rng, slices, component)
    lateral = ext.lateral.copy()
    lateral[:, 1] = np.minimum(lateral[:, 1], lateral[:, 0] + 0.15)  # thin hosts among them
    ext = SegmentExtents(ext.slice_index, lateral, ext.height, ext.component, ext.n_points)
    core = (slices >= 70) & (slices < 90)
    near = (slices >= 70 - reach) & (slices < 90 + reach)

    def draw(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = len(rows)
        return rng.random(m) < 0.15, rng.random(m) * 0.3

    removed = 0
    for _ in range(20):
        labels, probability = draw(np.arange(n))
        corrected = correct_labels(labels, ext, params, probability)
        beyond_labels, beyond_probability = draw(np.flatnonzero(~near))
        labels[~near], probability[~near] = beyond_labels, beyond_probability
        np.testing.assert_array_equal(
            correct_labels(labels, ext, params, probability)[core], corrected[core]
        )
        off = CorrectionParams(object_window_slices=0, inside_max_slices=0)
        removed += int((corrected != correct_labels(labels, ext, off, probability))[core].sum())
    assert removed > 20  # the fixture exercises the rules


#: A hedge 0.3 m behind BEAM, as tall as a person.
HEDGE = (2.4, 2.9, 0.0, 1.6)


def rail_and(behind: tuple[float, float, float, float], slices=range(10), **params):
    """Corrected labels of a rail (component 0, slices 0-9) and what stands behind it
    (component 1, ``slices``), all labelled guardrail: (rail labels, labels behind)."""
    segments = run(range(10)) + run(slices, behind)
    component = [0] * 10 + [1] * len(slices)
    labels = correct_labels(
        np.ones(len(segments), bool),
        extents(*segments, component=component),
        CorrectionParams(**params),
    )
    return labels[:10], labels[10:]


def test_what_stands_behind_a_rail_becomes_other() -> None:
    rail, hedge = rail_and(HEDGE)
    assert rail.all() and not hedge.any()
    left = tuple(-v for v in (HEDGE[1], HEDGE[0])) + HEDGE[2:]  # the left side of the path
    beam_left = (-BEAM[1], -BEAM[0], *BEAM[2:])
    segments = run(range(10), beam_left) + run(range(10), left)
    labels = correct_labels(np.ones(20, bool), extents(*segments, component=[0] * 10 + [1] * 10))
    np.testing.assert_array_equal(labels, [True] * 10 + [False] * 10)


def test_a_hedge_touching_the_back_of_a_rail_becomes_other() -> None:
    """A hedge cut from the back of a rail (``SegmentParams.front_layer_m``): no gap between
    them, but it spans 0.1 m or more across (``behind_wide_m``), as does the 0.15 m face of
    one seen from across the road; a thinner thing touching the rail's back, or the rule for
    wide things off, keeps it."""
    hedge_back, hedge_face = (2.1, 2.8, 0.1, 1.3), (2.1, 2.25, 0.1, 1.0)
    for touching in (hedge_back, hedge_face):
        rail, hedge = rail_and(touching)
        assert rail.all() and not hedge.any()
    for narrow, params in (((2.1, 2.17, 0.1, 1.3), {}), (hedge_face, {"behind_wide_m": np.inf})):
        rail, other = rail_and(narrow, **params)
        assert rail.all() and other.all()


def test_a_rails_own_parts_behind_it_stay_guardrail() -> None:
    """A post with its blockout behind a beam (touching it), or the back rail of a
    double-sided barrier (0.3 m behind, 8 cm deep), is of the beam's component and stays."""
    for behind in ((2.1, 2.3, 0.0, 1.0), (2.4, 2.48, 0.3, 1.0)):
        segments = run(range(10)) + run(range(10), behind)
        assert correct_labels(np.ones(20, bool), extents(*segments)).all()  # all component 0


def test_a_hedge_grown_into_a_rails_back_becomes_other() -> None:
    """A hedge of the rail's own component (grown into its back), cut from the rail's slices
    as segments of their own, 0.3 m behind and 0.5 m deep (``behind_own_wide_m``)."""
    segments = run(range(10)) + run(range(10), HEDGE)
    labels = correct_labels(np.ones(20, bool), extents(*segments))  # all component 0
    np.testing.assert_array_equal(labels, np.r_[np.ones(10, bool), np.zeros(10, bool)])
    off = CorrectionParams(behind_own_wide_m=np.inf)
    assert correct_labels(np.ones(20, bool), extents(*segments), off).all()
    # Narrower than 0.3 m, or within behind_gap_m of the rail's back: kept.
    for behind in ((2.4, 2.65, 0.0, 1.6), (2.15, 2.9, 0.0, 1.6)):
        segments = run(range(10)) + run(range(10), behind)
        assert correct_labels(np.ones(20, bool), extents(*segments)).all()


@pytest.mark.parametrize(
    "behind, slices, params",
    [
        ((2.15, 2.22, 0.3, 1.0), range(10), {}),  # 5 cm behind, narrower than behind_wide_m
        ((-2.9, -2.4, 0.0, 1.6), range(10), {}),  # across the path
        (HEDGE, range(10), {"behind_gap_m": float("inf")}),  # the rule off
        ((3.2, 3.4, 0.5, 1.1), range(10), {}),  # a barrier of its own, 1.1 m behind
    ],
)
def test_what_is_not_behind_a_rail_stays(behind, slices, params) -> None:
    rail, other = rail_and(behind, slices, **params)
    assert rail.all() and other.all()


def test_a_gap_behind_a_rail_not_under_its_maximum_is_a_named_error() -> None:
    with pytest.raises(GuardrailError, match="behind_gap_m"):
        CorrectionParams(behind_gap_m=1.0, behind_max_m=1.0)
    CorrectionParams(behind_gap_m=float("inf"), behind_max_m=1.0)  # off


def test_a_short_false_alarm_in_front_does_not_take_the_rail_behind_it() -> None:
    """Three slices of a curb called guardrail (under behind_front_min_slices) before a rail."""
    curb = (1.2, 1.4, 0.0, 0.15)
    segments = run(range(3), curb) + run(range(10))
    labels = correct_labels(np.ones(13, bool), extents(*segments, component=[1] * 3 + [0] * 10))
    assert labels.all()
    longer = run(range(4), curb) + run(range(10))
    labels = correct_labels(np.ones(14, bool), extents(*longer, component=[1] * 4 + [0] * 10))
    np.testing.assert_array_equal(labels, [True] * 4 + [False] * 4 + [True] * 6)


def test_a_fragment_of_a_rail_does_not_stand_in_front_of_the_rest() -> None:
    """A multi-beam scan: a rail's slice in fragments of a few points, one 15 cm nearer."""
    fragment = (1.8, 1.85, 0.6, 0.6)
    segments = run(range(10), fragment) + run(range(10))
    component, points = [1] * 10 + [0] * 10, [4] * 10 + [6] * 10
    labels = correct_labels(
        np.ones(20, bool), extents(*segments, component=component, n_points=points)
    )
    assert labels.all()
    points = [5] * 10 + [6] * 10  # behind_front_min_points: a front seen well enough
    labels = correct_labels(
        np.ones(20, bool), extents(*segments, component=component, n_points=points)
    )
    np.testing.assert_array_equal(labels, [True] * 10 + [False] * 10)


def test_what_is_left_of_a_run_behind_a_rail_is_isolated() -> None:
    """A fence beyond the rail's end keeps one slice: isolated, it becomes other too (one that
    touches the rail's end stays in its run)."""
    fence = (2.6, 2.7, 0.0, 1.8)
    rail, hedge = rail_and(fence, range(11))
    assert rail.all() and not hedge.any()
    rail, hedge = rail_and(fence, range(12))  # two slices beyond the rail: a run of its own
    np.testing.assert_array_equal(hedge, [False] * 10 + [True] * 2)


def test_what_stands_behind_a_rail_does_not_widen_a_hole_for_the_fill() -> None:
    """A rail (component 0) in slices 0-4 and 6-9; in slice 5 the rail with a hedge grown
    into it, called other, 0.4 m deep; in slice 4 a piece of the hedge behind the rail
    (component 1) called guardrail. With the piece counted the hole fitted the cross-section and
    was filled; it stands behind the rail's run of 4 slices (1-4), so it does not count, unless
    slice 1 is other and the run in front too short: a raw label 4 slices from the hole
    (``behind_front_min_slices``) decides, within the reach."""
    slot = (2.0, 2.45, 0.3, 1.0)
    piece = (2.4, 2.6, 0.3, 1.0)
    segments = [*run(range(5)), (5, slot), *run(range(6, 10)), (4, piece)]
    ext = extents(*segments, component=[0] * 10 + [1])
    raw = np.r_[np.ones(5, bool), False, np.ones(4, bool), True]
    corrected = correct_labels(raw, ext)
    assert not corrected[5] and not corrected[10]
    raw[1] = False
    assert correct_labels(raw, ext)[5]
    assert correction_reach_slices() >= 4


def test_a_lone_guardrail_segment_becomes_other() -> None:
    """Alone, and among other segments that touch it: a run of one slice is isolated."""
    np.testing.assert_array_equal(correct_labels(np.array([True]), extents((3, BEAM))), [False])
    labels = np.array([False, False, True, False, False])
    corrected = correct_labels(labels, extents(*run(range(5))))
    np.testing.assert_array_equal(corrected, np.zeros(5, bool))


def test_two_guardrail_segments_in_adjacent_slices_stay() -> None:
    corrected = correct_labels(np.array([True, True]), extents(*run([7, 8])))
    np.testing.assert_array_equal(corrected, [True, True])


def test_two_guardrail_segments_of_one_slice_are_isolated() -> None:
    """A pipe and a beam cut from the same slice span one slice: fewer than min_run_slices."""
    pipe = (2.0, 2.1, 0.9, 1.0)
    beam = (2.0, 2.1, 0.4, 0.7)
    corrected = correct_labels(np.array([True, True]), extents((5, pipe), (5, beam)))
    np.testing.assert_array_equal(corrected, [False, False])


def test_guardrail_segments_that_do_not_touch_are_isolated() -> None:
    """Adjacent slices, but 1 m apart across the road (farther than touch_distance_m)."""
    far = (3.1, 3.2, 0.3, 1.0)
    corrected = correct_labels(np.array([True, True]), extents((0, BEAM), (1, far)))
    np.testing.assert_array_equal(corrected, [False, False])


def test_min_run_slices_comes_from_the_params() -> None:
    params = CorrectionParams(min_run_slices=3)
    two = correct_labels(np.ones(2, bool), extents(*run([0, 1])), params)
    three = correct_labels(np.ones(3, bool), extents(*run([0, 1, 2])), params)
    np.testing.assert_array_equal(two, [False, False])
    np.testing.assert_array_equal(three, [True, True, True])


def test_a_curb_beside_the_run_stays_other() -> None:
    """The curb in slice 4 touches the guardrail segments around it but lies outside their
    cross-section (lateral 1.7 < 2.0 - fill_margin_m), so it stays other; the guardrail
    segment of slice 4, labelled other too, is filled."""
    segments = run(range(10)) + [(4, CURB)]
    labels = np.ones(11, bool)
    labels[[4, 10]] = False
    ext = extents(*segments)
    pairs = {tuple(p) for p in neighbour_pairs(ext).tolist()}
    assert {(3, 10), (4, 10), (10, 5)} <= pairs  # the curb is the run's neighbour

    corrected = correct_labels(labels, ext)

    expected = np.ones(11, bool)
    expected[10] = False
    np.testing.assert_array_equal(corrected, expected)


def test_a_segment_slightly_wider_than_the_run_within_the_margin_is_filled() -> None:
    wider = (1.96, 2.14, 0.27, 1.04)  # 4 cm beyond the run on every side: within 5 cm
    segments = run(range(4)) + [(4, wider)] + run(range(5, 10))
    labels = np.ones(10, bool)
    labels[4] = False
    np.testing.assert_array_equal(correct_labels(labels, extents(*segments)), np.ones(10, bool))


#: Two pipe rails seen across the road (lateral 2.0-2.03 m, 0.5-0.9 m up) and a slice with one
#: of their posts: it stands on the ground and 9 cm behind the rails, a little above the top one.
RAILS = (2.0, 2.03, 0.5, 0.9)
POST = (2.0, 2.12, 0.12, 0.94)


def _rails_with_posts(other: tuple[float, float, float, float] | None = None):
    """Ten rail slices with posts at slices 2 and 6 labelled other, and ``other`` in slice 4."""
    segments = [(s, POST if s in (2, 6) else RAILS) for s in range(10)]
    labels = np.ones(10, bool)
    labels[[2, 6]] = False
    if other is not None:
        segments.append((4, other))
        labels = np.append(labels, False)
    return labels, extents(*segments)


def test_a_post_between_rails_becomes_guardrail() -> None:
    """The post reaches 0.38 m below the rails and 9 cm behind them: outside their
    cross-section, but a post (within post_width_m, at least halfway up the rails)."""
    labels, ext = _rails_with_posts()
    np.testing.assert_array_equal(correct_labels(labels, ext), np.ones(10, bool))
    narrow = CorrectionParams(post_width_m=0.05)
    np.testing.assert_array_equal(correct_labels(labels, ext, narrow), labels)


@pytest.mark.parametrize(
    "other",
    [
        (2.0, 2.1, 0.0, 0.2),  # a curb under the rails: not halfway up
        (1.7, 1.9, 0.0, 0.75),  # a bollard 10 cm in front of the rails: too far beside them
        (2.0, 2.1, 0.0, 2.5),  # a sign post in line with the rails: above their top
        (2.0, 2.4, 0.1, 0.9),  # a hedge behind the rails: too deep
        (2.05, 2.12, 0.45, 0.84),  # a bicycle rack's bars just behind the rails: off the ground
    ],
)
def test_what_is_not_a_post_stays_other(other: tuple[float, float, float, float]) -> None:
    labels, ext = _rails_with_posts(other)
    corrected = correct_labels(labels, ext)
    expected = np.ones(11, bool)
    expected[10] = False
    np.testing.assert_array_equal(corrected, expected)


#: A low pipe rail (0.45-0.6 m up) and the stub of a post under it: the rest of the post is of
#: the rail's segment, and the stub stops 8 cm under the rail.
LOW_RAIL = (2.0, 2.03, 0.45, 0.6)
STUB = (2.0, 2.1, 0.12, 0.37)


def _low_rail_and(other: tuple[float, float, float, float]) -> np.ndarray:
    """Corrected labels of ten slices of LOW_RAIL and ``other`` in slice 4, called other."""
    segments = [*run(range(10), LOW_RAIL), (4, other)]
    return correct_labels(np.r_[np.ones(10, bool), False], extents(*segments))


def test_the_stub_of_a_post_under_a_low_rail_becomes_guardrail() -> None:
    assert _low_rail_and(STUB).all()
    segments = extents(*run(range(10), LOW_RAIL), (4, STUB))
    labels = np.r_[np.ones(10, bool), False]
    off = CorrectionParams(post_stub_gap_m=0)
    np.testing.assert_array_equal(correct_labels(labels, segments, off), labels)


@pytest.mark.parametrize(
    "other",
    [
        (2.0, 2.1, 0.0, 0.2),  # a curb under the rail: not as high as a stub
        (2.0, 2.1, 0.12, 0.3),  # 15 cm under the rail: not a stub
        (2.0, 2.1, 0.35, 0.42),  # off the ground
        (1.7, 1.82, 0.0, 0.37),  # a bollard in front of the rail: too far beside it
    ],
)
def test_what_is_not_a_stub_under_a_low_rail_stays_other(
    other: tuple[float, float, float, float],
) -> None:
    np.testing.assert_array_equal(_low_rail_and(other), np.r_[np.ones(10, bool), False])


def test_a_hole_of_two_slices_is_filled() -> None:
    labels = np.ones(10, bool)
    labels[[4, 5]] = False
    ext = extents(*run(range(10)))
    np.testing.assert_array_equal(correct_labels(labels, ext), np.ones(10, bool))
    one = CorrectionParams(max_hole_slices=1)
    np.testing.assert_array_equal(correct_labels(labels, ext, one), labels)


def test_a_hole_of_three_slices_is_not_filled() -> None:
    labels = np.ones(10, bool)
    labels[[4, 5, 6]] = False
    np.testing.assert_array_equal(correct_labels(labels, extents(*run(range(10)))), labels)


def test_two_lone_segments_three_slices_apart_do_not_make_a_run() -> None:
    """Slices 3 and 6 are guardrail alone: the two other slices between them are no hole of a
    run, and both lone segments become other."""
    labels = np.zeros(10, bool)
    labels[[3, 6]] = True
    corrected = correct_labels(labels, extents(*run(range(10))))
    np.testing.assert_array_equal(corrected, np.zeros(10, bool))


def test_a_hole_of_two_next_to_a_filled_hole_of_one_is_filled() -> None:
    """G . G . . G G: the run before the hole of two is a run once its hole of one is filled."""
    labels = np.array([True, False, True, False, False, True, True])
    corrected = correct_labels(labels, extents(*run(range(7))))
    np.testing.assert_array_equal(corrected, np.ones(7, bool))


def test_max_hole_slices_other_than_one_or_two_is_a_named_error() -> None:
    with pytest.raises(GuardrailError, match="max_hole_slices"):
        correct_labels(
            np.ones(3, bool), extents(*run(range(3))), CorrectionParams(max_hole_slices=3)
        )


def test_a_segment_at_the_end_of_a_run_stays_other() -> None:
    """Other segments at slices 10 and -1 have guardrail neighbours on one side only."""
    segments = run(range(10)) + [(10, BEAM), (-1, BEAM)]
    labels = np.ones(12, bool)
    labels[[10, 11]] = False
    expected = labels.copy()
    np.testing.assert_array_equal(correct_labels(labels, extents(*segments)), expected)


def test_a_gap_between_runs_on_different_sides_is_not_filled() -> None:
    """A guardrail on the left up to slice 3 and one on the right from slice 5: the other
    segment of slice 4 on the left has guardrail neighbours before it only."""
    right = (-2.1, -2.0, 0.3, 1.0)
    segments = run(range(4)) + [(4, BEAM)] + run(range(5, 10), right)
    labels = np.ones(10, bool)
    labels[4] = False
    np.testing.assert_array_equal(correct_labels(labels, extents(*segments)), labels)


def test_empty_input_returns_empty() -> None:
    corrected = correct_labels(np.zeros(0, bool), extents())
    assert corrected.shape == (0,) and corrected.dtype == bool
    assert neighbour_pairs(extents()).shape == (0, 2)


def test_labels_are_not_modified_in_place() -> None:
    labels = np.array([True, True, True, False, True, True])  # a lone one and a hole
    before = labels.copy()
    segments = [(0, BEAM)] + run(range(5, 10))
    corrected = correct_labels(labels, extents(*segments))
    np.testing.assert_array_equal(labels, before)
    assert corrected is not labels
    np.testing.assert_array_equal(corrected, [False, True, True, True, True, True])


@pytest.mark.parametrize("hole", [1, 8])
def test_a_hole_next_to_the_end_of_a_run_is_filled(hole: int) -> None:
    """The same single misclassification that is filled at slice 4 is filled one slice from
    either end of the run too, and does not cost the run its end segment."""
    labels = np.ones(10, bool)
    labels[hole] = False
    corrected = correct_labels(labels, extents(*run(range(10))))
    np.testing.assert_array_equal(corrected, np.ones(10, bool))


@pytest.mark.parametrize(("gap", "touch"), [(0.29, True), (0.31, False)])
def test_touch_distance(gap: float, touch: bool) -> None:
    """Lateral gap of ``gap`` metres between two segments of adjacent slices; the height
    intervals 0.29 m apart touch in both cases."""
    a = (2.0, 2.1, 0.3, 1.0)
    b = (2.1 + gap, 2.5 + gap, 1.29, 1.5)
    pairs = neighbour_pairs(extents((0, a), (1, b)))
    assert pairs.tolist() == ([[0, 1]] if touch else [])
    assert pairs.dtype == np.int64


def random_extents(seed: int, n: int = 120) -> tuple[np.ndarray, SegmentExtents]:
    """Segments over 15 slices, 0-3 per slice on average, scattered beside the road."""
    rng = np.random.default_rng(seed)
    slices = rng.integers(-3, 12, n)
    lo = np.column_stack([rng.uniform(-4.0, 4.0, n), rng.uniform(-0.5, 1.5, n)])
    size = rng.uniform(0.05, 0.6, (n, 2))
    labels = rng.random(n) < 0.6
    return labels, SegmentExtents(
        slices,
        np.column_stack([lo[:, 0], lo[:, 0] + size[:, 0]]),
        np.column_stack([lo[:, 1], lo[:, 1] + size[:, 1]]),
        rng.integers(0, 4, n),
        rng.integers(1, 50, n),
    )


@pytest.mark.parametrize("seed", [50, 51])
def test_neighbour_pairs_equal_a_brute_force_search(seed: int) -> None:
    _, ext = random_extents(seed)
    gap = CorrectionParams().touch_distance_m
    pairs = neighbour_pairs(ext)

    expected = set()
    n = len(ext.slice_index)
    for i in range(n):
        for j in range(n):
            if i == j or not 0 <= ext.slice_index[j] - ext.slice_index[i] <= 1:
                continue
            if ext.slice_index[i] == ext.slice_index[j] and j < i:
                continue
            if (
                ext.lateral[i, 0] <= ext.lateral[j, 1] + gap
                and ext.lateral[j, 0] <= ext.lateral[i, 1] + gap
                and ext.height[i, 0] <= ext.height[j, 1] + gap
                and ext.height[j, 0] <= ext.height[i, 1] + gap
            ):
                expected.add((i, j))
    got = [tuple(p) for p in pairs.tolist()]
    assert len(got) == len(set(got))  # each pair once
    assert set(got) == expected
    assert len(expected) > 20  # the fixture has neighbours to find


@pytest.mark.parametrize("seed", [52, 53])
def test_correction_does_not_depend_on_segment_order(seed: int) -> None:
    labels, ext = random_extents(seed)
    corrected = correct_labels(labels, ext)
    order = np.random.default_rng(seed).permutation(len(labels))
    shuffled = SegmentExtents(
        ext.slice_index[order],
        ext.lateral[order],
        ext.height[order],
        ext.component[order],
        ext.n_points[order],
    )
    np.testing.assert_array_equal(correct_labels(labels[order], shuffled), corrected[order])
    assert (corrected != labels).any()  # the fixture exercises the rules


def behind_fixture(
    seed: int, widest: float
) -> tuple[np.ndarray, SegmentExtents, np.ndarray, np.ndarray]:
    """400 random segments over 12 slices, some straddling the path, up to ``widest`` metres
    across: labels (60 % guardrail), extents, neighbour pairs and the fronts (as the rules of
    what stands behind a rail define them)."""
    from guardrail_core.extract.classify.segment_extents import run_span

    rng = np.random.default_rng(seed)
    n = 400
    lo = rng.uniform(-3.0, 3.0, n)
    ext = SegmentExtents(
        rng.integers(0, 12, n),
        np.column_stack([lo, lo + rng.uniform(0.02, widest, n)]),
        np.column_stack([np.zeros(n), rng.uniform(0.2, 1.2, n)]),
        rng.integers(0, 5, n),
        rng.integers(1, 10, n),
    )
    labels = rng.random(n) < 0.6
    params = CorrectionParams()
    pairs = neighbour_pairs(ext, params)
    front = labels & (ext.n_points >= params.behind_front_min_points)
    front &= run_span(labels, pairs, ext.slice_index) >= params.behind_front_min_slices
    return labels, ext, pairs, front


@pytest.mark.parametrize("seed", [54, 55, 56])
def test_what_stands_behind_a_rail_equals_a_brute_force_search(seed: int) -> None:
    from guardrail_core.extract.classify.behind_a_rail import behind_a_run

    labels, ext, pairs, front = behind_fixture(seed, widest=0.6)  # some behind_wide_m wide
    params = CorrectionParams()
    expected = np.zeros(len(labels), bool)
    for i in np.flatnonzero(labels):
        for sign in (1, -1):  # the right side, then the left
            a = min(sign * ext.lateral[i])
            if a <= 0:
                continue
            for c in set(ext.component.tolist()) - {ext.component[i]}:
                # The fronts of component c in i's slice, wholly on i's side.
                ends = [
                    sorted(sign * ext.lateral[j])
                    for j in np.flatnonzero(front)
                    if ext.slice_index[j] == ext.slice_index[i] and ext.component[j] == c
                ]
                ends = [d for near, d in ends if near > 0]
                if not ends:
                    continue
                behind = a - max(ends)
                wide = ext.lateral[i][1] - ext.lateral[i][0] >= params.behind_wide_m
                if (params.behind_gap_m < behind or (wide and behind >= 0)) and (
                    behind <= params.behind_max_m
                ):
                    expected[i] = True
    got = behind_a_run(labels, pairs, ext, params)
    np.testing.assert_array_equal(got, expected)
    assert 5 < expected.sum() < labels.sum()  # the fixture has both
    narrow_only = CorrectionParams(behind_wide_m=np.inf)
    assert (behind_a_run(labels, pairs, ext, narrow_only) != got).any()  # and wide ones


@pytest.mark.parametrize("seed", [57, 58])
def test_what_stands_behind_its_own_rail_equals_a_brute_force_search(seed: int) -> None:
    from guardrail_core.extract.classify.behind_a_rail import behind_its_own_rail

    labels, ext, pairs, front = behind_fixture(seed, widest=0.8)  # some behind_own_wide_m wide
    params = CorrectionParams()
    expected = np.zeros(len(labels), bool)
    for i in np.flatnonzero(labels):
        if ext.lateral[i][1] - ext.lateral[i][0] < params.behind_own_wide_m:
            continue
        for sign in (1, -1):
            near_i = min(sign * ext.lateral[i])
            if near_i <= 0:
                continue
            for j in np.flatnonzero(front):
                same = ext.slice_index[j] == ext.slice_index[i]
                same &= ext.component[j] == ext.component[i]
                near_j, far_j = sorted(sign * ext.lateral[j])
                if j == i or not same or near_j <= 0:
                    continue
                behind = near_i - far_j
                if params.behind_gap_m < behind <= params.behind_max_m:
                    expected[i] = True
    got = behind_its_own_rail(labels, pairs, ext, params)
    np.testing.assert_array_equal(got, expected)
    assert 3 < expected.sum() < labels.sum()  # the fixture has both


def test_labels_and_extents_of_different_lengths_is_a_named_error() -> None:
    with pytest.raises(GuardrailError):
        correct_labels(np.ones(5, bool), extents(*run(range(3))))


def test_the_reach_covers_a_run_in_front_made_long_by_fills() -> None:
    """A hedge behind a rail's first slice; the rail's run reaches 8 slices (the front's
    minimum here) only if the raw label 8 slices away lets a hole before it be filled: rail
    0-2, a hole of two, 5-6, a hole of one, 8. The rules without the rule behind a rail reach
    2 m + 3 = 7 slices."""
    params = CorrectionParams(behind_front_min_slices=8)
    segments = run(range(9)) + [(0, HEDGE)]
    ext = extents(*segments, component=[0] * 9 + [1])
    raw = np.array([1, 1, 1, 0, 0, 1, 1, 0, 1, 1], bool)
    assert not correct_labels(raw, ext, params)[9]  # the run spans 0-8: the hedge is behind it
    raw[8] = False
    assert correct_labels(raw, ext, params)[9]  # the run spans 0-6: too short to stand behind
    assert 8 <= correction_reach_slices(params)


@pytest.mark.parametrize("min_run_slices", [1, 2, 3, 4])
@pytest.mark.parametrize("max_hole_slices", [1, 2])
@pytest.mark.parametrize("behind_front_min_slices", [1, 4])
def test_raw_labels_beyond_the_reach_do_not_change_a_corrected_label(
    min_run_slices: int, max_hole_slices: int, behind_front_min_slices: int
) -> None:
    """What lets a processing tile ask the CNN only near the slices it owns."""
    params = CorrectionParams(
        min_run_slices=min_run_slices,
        max_hole_slices=max_hole_slices,
        behind_front_min_slices=behind_front_min_slices,
    )
    no_behind = CorrectionParams(
        min_run_slices=min_run_slices, max_hole_slices=max_hole_slices, behind_gap_m=float("inf")
    )
    reach = correction_reach_slices(params)
    rng = np.random.default_rng(60 + min_run_slices + 10 * max_hole_slices)
    n = 700
    slices = rng.integers(0, 100, n)
    ext = rail_band(rng, slices, rng.integers(0, 3, n))  # rails, posts, what stands behind
    core = (slices >= 40) & (slices < 60)
    near = (slices >= 40 - reach) & (slices < 60 + reach)
    corrections = behind = 0
    for _ in range(20):
        labels = rng.random(n) < 0.7
        corrected = correct_labels(labels, ext, params)
        beyond = labels.copy()
        beyond[~near] = rng.random(int((~near).sum())) < 0.7
        np.testing.assert_array_equal(correct_labels(beyond, ext, params)[core], corrected[core])
        corrections += int((corrected[core] != labels[core]).sum())
        behind += int((corrected != correct_labels(labels, ext, no_behind))[core].sum())
    assert corrections > 20  # the fixture exercises the rules
    assert behind > 5  # the rule of what stands behind a rail among them


#: A pipe railing's slice: its rails and posts, 0.2-0.95 m high, 8 cm across.
RAILING = (2.0, 2.08, 0.2, 0.95)
#: An arch between its rails, a thin pipe whose hits the wireframe did not link to them.
ARCH = (2.02, 2.05, 0.4, 0.8)


def railing_and(piece=ARCH, piece_slices=range(4, 6), railing_slices=range(10), railing=RAILING):
    """A railing (component 0, called guardrail) and a piece in some of its slices
    (component 1, called other with P 0.01, its crops saying other): raw labels, extents, the
    segment head's probabilities and the crops' probabilities."""
    k, m = len(railing_slices), len(piece_slices)
    segments = extents(
        *run(railing_slices, railing), *run(piece_slices, piece), component=[0] * k + [1] * m
    )
    labels = np.r_[np.ones(k, bool), np.zeros(m, bool)]
    probability = np.r_[np.full(k, 0.99), np.full(m, 0.01)]
    crops = np.r_[np.full(k, 0.9), np.full(m, 0.02)]
    return labels, segments, probability, crops


def test_a_short_piece_inside_a_railings_slices_becomes_guardrail() -> None:
    """However sure the classifier and the crops are that it is other: one that never saw the
    design's arches judges them as short pieces of their own."""
    labels, segments, probability, crops = railing_and()
    corrected = correct_labels(labels, segments, probability=probability, crop_probability=crops)
    assert corrected.all()
    off = CorrectionParams(infill_max_slices=0)
    corrected = correct_labels(labels, segments, off, probability, crops)
    np.testing.assert_array_equal(corrected, labels)


@pytest.mark.parametrize(
    "case",
    [
        {"piece": (2.0, 2.4, 0.4, 0.8)},  # a shrub reaching behind the railing
        {"piece": (1.7, 2.05, 0.4, 0.8)},  # or in front of it
        {"piece": (2.02, 2.05, 0.4, 1.3)},  # above its top
        {"piece": (2.02, 2.05, 0.0, 0.6)},  # down to the ground: a curb, a post's own foot
        {"piece_slices": range(1, 8)},  # a component longer than infill_max_slices
        {"railing_slices": range(3, 6)},  # a railing of fewer than behind_front_min_slices
        {"railing": (2.0, 2.3, 0.0, 0.95)},  # a beam's slice with its posts: no infill
    ],
)
def test_what_is_not_inside_a_railings_slices_stays_other(case) -> None:
    labels, segments, probability, crops = railing_and(**case)
    corrected = correct_labels(labels, segments, probability=probability, crop_probability=crops)
    np.testing.assert_array_equal(corrected[-len(case.get("piece_slices", range(4, 6))) :], False)


def test_a_piece_inside_a_railing_called_other_stays_other() -> None:
    labels, segments, probability, crops = railing_and()
    labels[:10] = False
    assert not correct_labels(labels, segments, probability=probability).any()


@pytest.mark.parametrize("seed", [74, 75])
def test_the_infill_beyond_the_reach_does_not_change_a_corrected_label(seed: int) -> None:
    """Short pieces inside long rails, raw labels drawn again beyond the reach."""
    params = CorrectionParams()
    reach = correction_reach_slices(params)
    rng = np.random.default_rng(seed)
    n = 900
    slices = rng.integers(0, 140, n)
    kind = rng.integers(0, 2, n)
    component = kind * 1000 + slices // np.array([3, 200])[kind]
    box = np.where(kind[:, None] == 0, ARCH, RAILING) + rng.uniform(-0.02, 0.02, (n, 4))
    ext = extents(*zip(slices.tolist(), map(tuple, box), strict=True), component=component)
    core = (slices >= 60) & (slices < 80)
    near = (slices >= 60 - reach) & (slices < 80 + reach)
    off = CorrectionParams(infill_max_slices=0)
    probability = np.where(kind == 0, 0.01, 0.9)  # the pieces too sure to be filled as holes
    filled = 0
    for _ in range(20):
        labels = rng.random(n) < np.where(kind == 0, 0.1, 0.7)
        corrected = correct_labels(labels, ext, params, probability)
        beyond = labels.copy()
        beyond[~near] = rng.random(int((~near).sum())) < 0.7
        np.testing.assert_array_equal(
            correct_labels(beyond, ext, params, probability)[core], corrected[core]
        )
        filled += int((corrected != correct_labels(labels, ext, off, probability))[core].sum())
    assert filled > 20  # the fixture exercises the infill
