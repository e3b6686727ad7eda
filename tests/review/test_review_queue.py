"""The review queue's order: corrected-away predictions and one segment of every guardrail run
nobody looked at first, then the change a decision is expected to make (uncertainty, points
moved, a run joined or split), reviewed and tiny segments never; ties in drive order."""

from __future__ import annotations

import numpy as np

from guardrail_core.review.queue import (
    asked_segments,
    odd_one_out,
    points_weight,
    queue_order,
    queue_scores,
    segment_queue_scores,
    uncertainty,
    unchecked_runs,
)


def _segments_table(
    probability: np.ndarray,
    label: np.ndarray,
    n_points: np.ndarray,
    component: np.ndarray,
    slice_index: np.ndarray,
) -> dict[str, np.ndarray]:
    """The fields of ``segments.npz`` the queue reads; the correction changed no label."""
    return {
        "probability": probability,
        "raw_label": label,
        "label": label,
        "n_points": n_points,
        "component": component,
        "slice_index": slice_index,
    }


def test_uncertainty_peaks_at_a_half_and_counts_no_probability_as_unsure() -> None:
    np.testing.assert_allclose(
        uncertainty(np.array([0.0, 0.25, 0.5, 0.9, 1.0, np.nan])), [0, 0.5, 1, 0.2, 0, 1]
    )


def test_the_queue_ranks_disagreement_then_uncertainty_and_skips_reviewed() -> None:
    probability = np.array([0.9, 0.5, 0.1, 0.6, 0.45, 0.5, 0.02])
    raw_label = probability >= 0.5
    label = raw_label.copy()
    label[2] = True  # the correction turned segment 2 (p = 0.1) into guardrail
    reviewed = np.zeros(7, bool)
    reviewed[5] = True  # as uncertain as segment 1, but an operator has seen it

    score = queue_scores(probability, raw_label, label)
    np.testing.assert_allclose(score, [0.2, 1, 1.2, 0.8, 0.9, 1, 0.04])
    assert queue_order(score, reviewed).tolist() == [2, 1, 4, 3, 0, 6]
    assert queue_order(score, np.ones(7, bool)).tolist() == []


def test_a_decision_counts_by_the_points_it_moves_and_the_run_it_changes() -> None:
    """Expected change: uncertainty weighted by log points (full at 200) and by 1.5 where the
    segment's label differs from both neighbours along its component; tiny segments skipped."""
    np.testing.assert_allclose(
        points_weight(np.array([0, 1, 10, 200, 5000])),
        [0, np.log(2) / np.log(201), np.log(11) / np.log(201), 1, 1],
    )
    #              component 0: G G O G | component 1: O G O, then a lone slice 9 of component 1
    component = np.array([0, 0, 0, 0, 1, 1, 1, 1])
    slice_index = np.array([0, 1, 2, 3, 5, 6, 7, 9])
    label = np.array([1, 1, 0, 1, 0, 1, 0, 1], bool)
    odd = odd_one_out(component, slice_index, label)
    # Segment 2 (other between guardrails) joins; 5 (lone guardrail) splits; the run ends and
    # segment 7 (slice 9: no neighbour at slice 8) are not between two others.
    assert odd.tolist() == [False, False, True, False, False, True, False, False]
    probability = np.full(8, 0.5)
    n_points = np.array([200, 200, 200, 200, 200, 200, 5, 200])
    score = queue_scores(probability, label, label, n_points=n_points, run_change=odd)
    np.testing.assert_allclose(score[[0, 2, 5]], [1.0, 1.5, 1.5])
    np.testing.assert_allclose(score[6], points_weight(np.array([5]))[0])
    order = queue_order(score, np.zeros(8, bool), n_points=n_points)
    assert order.tolist() == [2, 5, 0, 1, 3, 4, 7]  # 6 (5 points) left out; ties in drive order
    assert 6 in queue_order(score, np.zeros(8, bool), n_points=n_points, min_points=5).tolist()
    table = _segments_table(probability, label, n_points, component, slice_index)
    np.testing.assert_allclose(segment_queue_scores(table), score)


def test_every_guardrail_run_nobody_looked_at_gets_one_segment_in_front() -> None:
    """A fence the model is sure of (P 0.9999) would wait behind every doubtful slice; one of its
    segments comes first until an operator has looked at any segment of it."""
    #            rail (0): 6 slices, P 0.6-0.8 | fence (1): 5 slices, P 0.9999 | piece (2): 4
    #            slices | rail (3): 6 slices, one reviewed | other (4): 6 slices, P 0.3
    component = np.repeat([0, 1, 2, 3, 4], [6, 5, 4, 6, 6])
    slice_index = np.concatenate(
        [np.arange(6), np.arange(5), np.arange(4), np.arange(6), np.arange(6)]
    )
    probability = np.concatenate(
        [[0.8, 0.7, 0.6, 0.6, 0.7, 0.8], [0.9999] * 5, [0.9] * 4, [0.6] * 6, [0.3] * 6]
    )
    label = probability >= 0.5
    n_points = np.full(len(label), 200)
    n_points[1] = 5  # too small to judge: the rail keeps 5 segments of 10 points or more
    reviewed = np.zeros(len(label), bool)
    reviewed[17] = True
    table = _segments_table(probability, label, n_points, component, slice_index)
    base = segment_queue_scores(table)
    unchecked = unchecked_runs(component, label, n_points, reviewed, base)
    # The rail's most doubtful slices (2 and 3, P 0.6) tie: the first along the drive; the fence's
    # first slice; not the 4-slice piece, the reviewed rail, or what is labelled other.
    assert np.flatnonzero(unchecked).tolist() == [2, 6]
    np.testing.assert_allclose(segment_queue_scores(table, reviewed), base + unchecked)
    np.testing.assert_array_equal(segment_queue_scores(table), base)
    before = queue_order(base, reviewed, n_points=n_points)
    assert before.tolist().index(6) > 15  # sure of itself: after every doubtful slice
    now = queue_order(segment_queue_scores(table, reviewed), reviewed, n_points=n_points)
    assert now[:2].tolist() == [2, 6]
    # Once any segment of the fence is reviewed, it is checked; a 4-slice piece never is.
    reviewed[9] = True
    assert np.flatnonzero(unchecked_runs(component, label, n_points, reviewed, base)).tolist() == [
        2
    ]
    assert not unchecked_runs(component, label, n_points, reviewed, base, min_segments=6)[2]
    assert unchecked_runs(component, label, n_points, reviewed, base, min_segments=4)[11]


def test_the_queue_asks_only_what_it_doubts_and_ends() -> None:
    """Asked: P between 5 % and 95 %, a label the correction changed, or a run nobody looked at;
    never a reviewed or tiny segment; nothing left once those are labelled."""
    #            rail (0): 6 slices, P 0.99 | doubtful (1): P 0.04, 0.06, 0.5, 0.94, 0.96, NaN
    component = np.repeat([0, 1], 6)
    slice_index = np.concatenate([np.arange(6), np.arange(6) * 3])
    probability = np.array([0.99] * 6 + [0.04, 0.06, 0.5, 0.94, 0.96, np.nan])
    label = probability >= 0.5
    n_points = np.full(12, 50)
    table = _segments_table(probability, label, n_points, component, slice_index)
    table["raw_label"] = label.copy()
    table["raw_label"][6] = True  # the correction changed it: asked however sure
    reviewed = np.zeros(12, bool)
    asked = asked_segments(table, reviewed)
    # The rail's first slice stands for it (unchecked); 0.04 and 0.96 lie outside the band.
    assert np.flatnonzero(asked).tolist() == [0, 6, 7, 8, 9, 11]
    n_points[7] = 9  # too small to judge
    assert np.flatnonzero(asked_segments(table, reviewed)).tolist() == [0, 6, 8, 9, 11]
    reviewed[[0, 6, 8, 9, 11]] = True  # one look at the rail checks it all
    assert not asked_segments(table, reviewed).any()
