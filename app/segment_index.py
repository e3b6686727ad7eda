"""Which drive points make each segment: a compressed index built once per run."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


class SegmentIndex:
    """The points of every segment, in CSR form.

    Parameters
    ----------
    point_segment : (N,) int, the segment of every drive point (negative: in no segment)
    n_segments : S
    """

    def __init__(self, point_segment: np.ndarray, n_segments: int) -> None:
        point_segment = np.asarray(point_segment)
        in_segment = np.flatnonzero(point_segment >= 0)
        order = np.argsort(point_segment[in_segment], kind="stable")
        self.points = in_segment[order].astype(np.int64)  # (M,) drive points, by segment
        counts = np.bincount(point_segment[in_segment], minlength=n_segments)
        self.starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)  # (S + 1,)
        self.point_segment = point_segment
        self.n_segments = int(n_segments)

    def points_of(self, segments: Sequence[int] | np.ndarray) -> np.ndarray:
        """(K,) int64 drive points of the given segments, in segment order."""
        segments = np.asarray(segments, np.int64).ravel()
        if len(segments) == 0:
            return np.zeros(0, np.int64)
        parts = [self.points[self.starts[s] : self.starts[s + 1]] for s in segments]
        return np.concatenate(parts)

    def segments_of(self, points: np.ndarray) -> np.ndarray:
        """(K,) int64 sorted unique segments holding any of ``points`` (points in none skipped)."""
        segment = self.point_segment[np.asarray(points, np.int64)]
        return np.unique(segment[segment >= 0]).astype(np.int64)

    def operator_labels(self, point_labels: np.ndarray, segments: np.ndarray) -> np.ndarray:
        """(K,) int8 operator label of each segment: -1 when none of its points carries one,
        else the majority (ties: guardrail) of its labelled points."""
        out = np.full(len(segments), -1, np.int8)
        for i, s in enumerate(np.asarray(segments, np.int64)):
            labels = point_labels[self.points[self.starts[s] : self.starts[s + 1]]]
            labels = labels[labels >= 0]
            if len(labels):
                out[i] = 1 if 2 * int(labels.sum()) >= len(labels) else 0
        return out
