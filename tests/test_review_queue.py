"""The review queue's order: corrected-away predictions first, then the most uncertain, reviewed
segments never; ties in drive order."""

from __future__ import annotations

import numpy as np

from guardrail_core.review.queue import queue_order, queue_scores, uncertainty


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
