"""Guardrail runs closed as the tiles end, so that their reconstruction overlaps the tiles still
running and this process holds only the runs still open.

The guardrail points (and the road points near them) of each joined part are added to the
stream; :meth:`RunStream.close` then hands out every run that no point still to come can change:
those whose points lie farther than :attr:`RunStream.reach_m` from every box where points may
still come (the bounding boxes of the drive tiles that the parts not joined yet read). Such a
run is the very run :func:`~guardrail_core.reconstruct.pipeline.split_runs` finds in the whole
drive's points: a point outside that reach can neither join it nor move a voxel it is linked
through (:func:`~guardrail_core.reconstruct.runs.link_reach_m`), nor be ground near it. Runs
are numbered as in the whole drive once all are known (:meth:`RunStream.final_ids`).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.reconstruct.pipeline import ReconstructionParams, RunInput, run_inputs
from guardrail_core.reconstruct.runs import is_run, link_components, link_reach_m


class RunStream:
    """Guardrail points gathered part by part, and runs handed out once they are closed.

    Parameters
    ----------
    trajectory : (T, 3) float64, the vehicle's positions (local frame)
    params : the reconstruction's parameters (its ``runs``)
    """

    def __init__(self, trajectory: np.ndarray, params: ReconstructionParams) -> None:
        self.trajectory = np.asarray(trajectory, np.float64)
        self.params = params
        runs = params.runs
        #: Metres: points farther than this from a run cannot change it or be its ground.
        self.reach_m = max(link_reach_m(runs), runs.ground_reach_m) * (1 + 1e-9) + 1e-9
        self._index = np.zeros(0, np.int64)
        self._xyz = np.zeros((0, 3))
        self._ground_index = np.zeros(0, np.int64)
        self._ground_xyz = np.zeros((0, 3))
        self._first: list[int] = []  # drive-wide index of each handed-out run's first point
        #: Guardrail points added so far.
        self.points_added = 0

    @property
    def open_points(self) -> int:
        """Guardrail points held: those of runs not closed yet."""
        return len(self._index)

    def add(
        self, index: np.ndarray, xyz: np.ndarray, ground_index: np.ndarray, ground_xyz: np.ndarray
    ) -> None:
        """A part's guardrail points and the road points near them, each (K,) drive-wide
        indices and (K, 3) float64 coordinates."""
        self.points_added += len(index)
        self._index = np.concatenate([self._index, np.asarray(index, np.int64)])
        self._xyz = np.concatenate([self._xyz, np.asarray(xyz, np.float64).reshape(-1, 3)])
        self._ground_index = np.concatenate(
            [self._ground_index, np.asarray(ground_index, np.int64)]
        )
        self._ground_xyz = np.concatenate(
            [self._ground_xyz, np.asarray(ground_xyz, np.float64).reshape(-1, 3)]
        )

    def close(self, open_boxes: np.ndarray | None = None) -> list[RunInput]:
        """Hand out the runs no point still to come can change, and let their points go.

        Parameters
        ----------
        open_boxes : (B, 4) float64 [x_min, y_min, x_max, y_max], local frame: where points may
            still come; None: nowhere (every run is closed)

        Returns
        -------
        The closed runs, with provisional ``run_id`` numbers in the order they are handed out
        (:meth:`final_ids` gives their final ones).
        """
        if len(self._index) == 0:
            return []
        order = np.argsort(self._index, kind="stable")  # drive order, as in a whole drive
        index, xyz = self._index[order], self._xyz[order]
        ground_order = np.argsort(self._ground_index, kind="stable")
        ground_index, ground_xyz = self._ground_index[ground_order], self._ground_xyz[ground_order]
        comp, n_comp = link_components(xyz, self.params.runs)
        closed = np.ones(n_comp, bool)
        boxes = self._boxes_near(open_boxes, xyz, ground_xyz)
        if boxes is not None:
            lo = np.full((n_comp, 2), np.inf)
            hi = np.full((n_comp, 2), -np.inf)
            for k in range(2):
                np.minimum.at(lo[:, k], comp, xyz[:, k])
                np.maximum.at(hi[:, k], comp, xyz[:, k])
            near = (
                (lo[:, None, 0] - self.reach_m <= boxes[None, :, 2])
                & (hi[:, None, 0] + self.reach_m >= boxes[None, :, 0])
                & (lo[:, None, 1] - self.reach_m <= boxes[None, :, 3])
                & (hi[:, None, 1] + self.reach_m >= boxes[None, :, 1])
            )
            closed = np.logical_not(near.any(axis=1))
        out = closed & is_run(xyz, comp, n_comp, self.params.runs)
        # Within the batch, runs in the order of their first point (as in a whole drive).
        first = np.full(n_comp, len(xyz), np.int64)
        np.minimum.at(first, comp, np.arange(len(xyz)))
        ready = np.flatnonzero(out)
        ready = ready[np.argsort(first[ready], kind="stable")]
        local = np.full(n_comp, -1, np.int64)
        local[ready] = np.arange(len(ready))
        runs = run_inputs(
            xyz,
            local[comp],
            self._ground_within(ground_xyz, xyz[out[comp], :2]),
            self.trajectory,
            self.params,
            len(self._first),
        )
        self._first.extend(int(index[first[c]]) for c in ready)
        # Keep the points of open runs, and the ground that an open or later run may need.
        keep = ~closed[comp]
        self._index, self._xyz = index[keep], xyz[keep]
        need = np.zeros(len(ground_xyz), bool)
        if boxes is not None:
            for box in boxes:
                need |= (
                    (ground_xyz[:, 0] >= box[0] - self.reach_m)
                    & (ground_xyz[:, 0] <= box[2] + self.reach_m)
                    & (ground_xyz[:, 1] >= box[1] - self.reach_m)
                    & (ground_xyz[:, 1] <= box[3] + self.reach_m)
                )
        rest = np.flatnonzero(~need)  # the ground the open boxes do not keep already
        if keep.any() and len(rest):
            distance, _ = cKDTree(self._xyz[:, :2]).query(
                ground_xyz[rest, :2], distance_upper_bound=self.reach_m
            )
            need[rest[np.isfinite(distance)]] = True
        self._ground_index, self._ground_xyz = ground_index[need], ground_xyz[need]
        return runs

    def _ground_within(self, ground_xyz: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """The ground points (G', 3), in their order, inside the bounding box of ``xy`` (N, 2)
        widened by the reach: all a closed run made of those points can take in (its ground
        lies within ``runs.ground_reach_m`` of its points), so its search tree is smaller."""
        if len(xy) == 0 or len(ground_xyz) == 0:
            return ground_xyz[:0]
        lo, hi = xy.min(axis=0) - self.reach_m, xy.max(axis=0) + self.reach_m
        inside = np.all((ground_xyz[:, :2] >= lo) & (ground_xyz[:, :2] <= hi), axis=1)
        return ground_xyz[inside]

    def _boxes_near(
        self, open_boxes: np.ndarray | None, xyz: np.ndarray, ground_xyz: np.ndarray
    ) -> np.ndarray | None:
        """(B', 4): the open boxes within reach of the bounding box of the points held,
        ``xyz`` (N, 3) and ``ground_xyz`` (G, 3) (most boxes of a survey lie far ahead); None
        if there are none."""
        if open_boxes is None or len(open_boxes) == 0:
            return None
        boxes = np.asarray(open_boxes, np.float64).reshape(-1, 4)
        held = [a[:, :2] for a in (xyz, ground_xyz) if len(a)]
        lo = np.min([a.min(axis=0) for a in held], axis=0) - self.reach_m
        hi = np.max([a.max(axis=0) for a in held], axis=0) + self.reach_m
        near = (
            (boxes[:, 0] <= hi[0])
            & (boxes[:, 2] >= lo[0])
            & (boxes[:, 1] <= hi[1])
            & (boxes[:, 3] >= lo[1])
        )
        return boxes[near] if near.any() else None

    def final_ids(self) -> np.ndarray:
        """(R,) int64: the final number of each run handed out (by provisional number): runs
        numbered by their first point in drive order, as in a whole drive."""
        first = np.asarray(self._first, np.int64)
        final = np.empty(len(first), np.int64)
        final[np.argsort(first, kind="stable")] = np.arange(len(first))
        return final
