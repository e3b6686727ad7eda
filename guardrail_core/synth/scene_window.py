"""The scene near each stretch of a drive, so that memory does not grow with the drive's length.

The drive is cut into windows of ``window_m`` metres of driving (a property of the simulation,
not of the drive's tiles): each window's scan chunks and camera shots are made against the
parts of the scene (:mod:`.scene_parts`) within the scanner's reach of the vehicle's poses in
that window, and nothing else. A ray's nearest hit within the scanner's range is then the one
it would meet in the whole scene, so the points do not depend on the windows; camera images
show the scene out to that reach at least.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from guardrail_core.formats.drive_tiles import vehicle_station
from guardrail_core.sensors.trajectory import Trajectory
from guardrail_core.synth.mesh import SceneMesh, join_meshes
from guardrail_core.synth.scene_parts import ScenePart


@dataclass(frozen=True)
class DriveWindow:
    """A stretch of the drive scanned and photographed against one build of the scene near it.

    Attributes
    ----------
    chunks : the scan chunks (indices into the scan plan) scanned in it
    span : (first, last) GPS seconds whose vehicle poses its scene must serve
    shots_before : GPS seconds; camera shots from the previous window's bound up to this one
        (exclusive; inf for the last window) are taken in it
    """

    chunks: range
    span: tuple[float, float]
    shots_before: float


def drive_windows(
    trajectory: Trajectory, chunk_spans: np.ndarray, window_m: float
) -> list[DriveWindow]:
    """Group the scan chunks (``chunk_spans`` (C, 2) GPS seconds of each one's first and last
    pulse, in time order) by the ``window_m`` metres of driving their first pulse falls in."""
    t_first, t_last = float(trajectory.time[0]), float(trajectory.time[-1])
    if len(chunk_spans) == 0:
        return [DriveWindow(range(0), (t_first, t_last), np.inf)]
    key = np.floor(vehicle_station(trajectory, chunk_spans[:, 0]) / window_m)
    starts = np.flatnonzero(np.concatenate([[True], np.diff(key) != 0]))
    ends = np.append(starts[1:], len(chunk_spans))
    windows = []
    for w, (a, b) in enumerate(zip(starts, ends, strict=True)):
        lo = t_first if w == 0 else float(chunk_spans[a, 0])
        last = w + 1 == len(starts)
        bound = t_last if last else float(chunk_spans[b, 0])
        hi = max(float(chunk_spans[b - 1, 1]), bound)
        windows.append(DriveWindow(range(int(a), int(b)), (lo, hi), np.inf if last else bound))
    return windows


def window_positions(trajectory: Trajectory, span: tuple[float, float]) -> tuple[np.ndarray, float]:
    """The vehicle's positions (S, 3) over ``span`` (GPS s): its trajectory samples and both
    ends; and the largest gap (m) between consecutive ones (a pose between two samples lies
    within half of it of one of them)."""
    lo, hi = span
    inside = trajectory.time[(trajectory.time > lo) & (trajectory.time < hi)]
    times = np.concatenate([[lo], inside, [hi]])
    positions, _ = trajectory.interpolate(times)
    gaps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    return positions, float(gaps.max(initial=0.0))


class SceneWindows:
    """Meshes of the parts of a scene near a set of positions, built as they are needed.

    On creation every part is built once, alone, for its horizontal bounds and its truth record
    (:attr:`objects`, in object-id order), and dropped. :meth:`mesh_near` then joins the parts
    whose bounds come within ``reach_m`` of a position, building those the previous call did
    not hold and dropping the others: consecutive windows share most of their parts.

    Parameters
    ----------
    parts : the scene's parts (:attr:`~guardrail_core.synth.scene.SceneLayout.parts`)
    reach_m : metres (horizontal) from a position within which a part is needed; inf: all parts
    progress : called with 1 per part built in the first pass
    """

    def __init__(
        self,
        parts: Sequence[ScenePart],
        reach_m: float,
        *,
        progress: Callable[[int], None] | None = None,
    ) -> None:
        self.parts = list(parts)
        self.reach_m = float(reach_m)
        self.objects: list[dict] = []
        self._lo = np.full((len(self.parts), 2), np.inf)
        self._hi = np.full((len(self.parts), 2), -np.inf)
        for i, part in enumerate(self.parts):
            mesh, record = part.mesh()
            if record is not None:
                self.objects.append(record)
            if mesh.n_faces:  # a part without faces is never needed
                self._lo[i] = mesh.vertices[:, :2].min(axis=0)
                self._hi[i] = mesh.vertices[:, :2].max(axis=0)
            if progress is not None:
                progress(1)
        self._held: dict[int, SceneMesh] = {}

    def near(self, positions: np.ndarray, slack_m: float = 0.0) -> np.ndarray:
        """(K,) int64 sorted indices of the parts within ``reach_m + slack_m`` (horizontally)
        of any of ``positions`` (S, 3)."""
        xy = np.asarray(positions, np.float64).reshape(-1, 3)[:, :2]
        has_faces = np.all(self._lo <= self._hi, axis=1)
        reach = self.reach_m + slack_m
        if not np.isfinite(reach) or len(xy) == 0:
            return np.flatnonzero(has_faces) if len(xy) else np.zeros(0, np.int64)
        # Boxes against the positions' box first, then box-to-point distances.
        box_lo, box_hi = xy.min(axis=0) - reach, xy.max(axis=0) + reach
        candidates = np.flatnonzero(
            has_faces & np.all(self._lo <= box_hi, axis=1) & np.all(self._hi >= box_lo, axis=1)
        )
        near = np.zeros(len(candidates), bool)
        for start in range(0, len(candidates), 256):  # bounded (256, S) temporaries
            part = candidates[start : start + 256]
            d = np.maximum(self._lo[part, None, :] - xy[None], xy[None] - self._hi[part, None, :])
            d2 = (np.maximum(d, 0.0) ** 2).sum(axis=2)
            near[start : start + 256] = d2.min(axis=1) <= reach**2
        return candidates[near]

    def mesh_near(self, positions: np.ndarray, slack_m: float = 0.0) -> SceneMesh:
        """The parts :meth:`near` the positions as one mesh, in part order."""
        needed = self.near(positions, slack_m)
        held = {}
        for i in needed.tolist():
            mesh = self._held.get(i)
            held[i] = mesh if mesh is not None else self.parts[i].mesh()[0]
        self._held = held
        return join_meshes([held[i] for i in needed.tolist()])
