"""The labelled points of a drive, held sparsely: memory follows what operators labelled, not the
drive's length (a survey of hundreds of millions of points has a few million labels at most)."""

from __future__ import annotations

import numpy as np

from guardrail_core.formats.label_store.schema import UNLABELLED


class SparseLabels:
    """Labels of some points of a drive; every other point is :data:`UNLABELLED`.

    Parameters
    ----------
    points : (L,) int64, unique labelled point indices (any order)
    labels : (L,) int, their labels (0 other, 1 guardrail)
    """

    def __init__(self, points: np.ndarray, labels: np.ndarray) -> None:
        order = np.argsort(points, kind="stable")
        self.points = np.asarray(points, np.int64)[order]  # (L,) sorted
        self.labels = np.asarray(labels, np.int8)[order]  # (L,)

    def __len__(self) -> int:
        return len(self.points)

    def at(self, points: np.ndarray) -> np.ndarray:
        """(K,) int8 label of each of ``points`` (K,), :data:`UNLABELLED` where none."""
        points = np.asarray(points, np.int64)
        out = np.full(len(points), UNLABELLED, np.int8)
        if len(self.points) == 0 or len(points) == 0:
            return out
        where = np.minimum(np.searchsorted(self.points, points), len(self.points) - 1)
        found = self.points[where] == points
        out[found] = self.labels[where[found]]
        return out

    def assign(self, points: np.ndarray, labels: np.ndarray) -> None:
        """Give ``points`` (K,) unique the ``labels`` (K,); :data:`UNLABELLED` removes a label."""
        points = np.asarray(points, np.int64)
        labels = np.asarray(labels, np.int8)
        kept = ~np.isin(self.points, points)
        new = labels != UNLABELLED
        merged = np.concatenate([self.points[kept], points[new]])
        order = np.argsort(merged, kind="stable")
        self.points = merged[order]
        self.labels = np.concatenate([self.labels[kept], labels[new]])[order]

    def dense(self, n_points: int) -> np.ndarray:
        """(n_points,) int8: every point's label, :data:`UNLABELLED` where none."""
        out = np.full(n_points, UNLABELLED, np.int8)
        out[self.points] = self.labels
        return out

    def copy(self) -> SparseLabels:
        return SparseLabels(self.points.copy(), self.labels.copy())
