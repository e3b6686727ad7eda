"""The route at a glance: the trajectory, every reconstructed guardrail run on it, and how far
the operators have reviewed each run.

A run's place is its poles in order (the reconstruction's ``models.json``, local metres). A
segment belongs to the run whose pole line passes nearest its centroid, within
:data:`RUN_REACH_M` horizontally: segments carry no run id (runs group guardrail points by
distance, §4.1), and a segment of a run lies on the line of its poles. The segments that count
are those the model or an operator calls guardrail, and every reviewed one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from weakref import WeakKeyDictionary

import numpy as np
from scipy.spatial import cKDTree

from app.session import ReviewSession
from guardrail_core.errors import GuardrailError
from guardrail_core.formats.drive_tiles import vehicle_station
from guardrail_core.reconstruct.inventory import inventory_rows
from guardrail_core.reconstruct.inventory_row import InventoryRow
from guardrail_core.reconstruct.model import RunModel
from guardrail_core.reconstruct.model_json import run_model_from_json
from guardrail_core.review.queue import asked_segments, segment_queue_scores, unchecked_runs
from guardrail_core.sensors.trajectory import Trajectory

#: Metres (horizontal): how far from its run's pole line a segment's centroid may lie.
RUN_REACH_M = 1.5
#: Metres between the samples of a run's pole line that segments are matched against.
LINE_STEP_M = 0.25
#: The most trajectory vertices sent (the map needs no more).
TRAJECTORY_VERTICES = 2000

#: A run's review state: nobody has labelled any of it; some of it is labelled and the queue
#: still asks about some; the queue asks nothing more about it.
UNREVIEWED, STARTED, DONE = "unreviewed", "started", "done"


@dataclass(frozen=True)
class RunPlace:
    """A reconstructed run on the map."""

    row: InventoryRow  # its inventory row
    path: np.ndarray  # (P, 2) float64, its poles in order, local metres
    station_m: float  # metres along the drive where it starts: the nearest of its poles
    station_end_m: float  # ... and where it ends


#: Per session: the run places and the ``models.json`` they were read from (its stat), so
#: they are read again only when the reconstruction is redone (the page asks after every label).
_PLACES: WeakKeyDictionary[ReviewSession, tuple[tuple[int, int] | None, list[RunPlace]]] = (
    WeakKeyDictionary()
)


def run_places(session: ReviewSession) -> list[RunPlace]:
    """Every reconstructed run with at least one pole, in order along the drive; empty for a
    run folder without a reconstruction."""
    models_file = session.folder.reconstruction.models_file
    try:
        stat = models_file.stat()
        key: tuple[int, int] | None = (stat.st_mtime_ns, stat.st_size)
    except OSError:
        key = None
    cached = _PLACES.get(session)
    if cached is not None and cached[0] == key:
        return cached[1]
    places = _read_run_places(session)
    _PLACES[session] = (key, places)
    return places


def _read_run_places(session: ReviewSession) -> list[RunPlace]:
    try:
        document = session.folder.reconstruction.read_models()
    except GuardrailError:
        return []
    models = [run_model_from_json(run) for run in document.runs]
    rows = inventory_rows(models, session.drive.origin)
    stations = run_stations(models, session.drive.trajectory)
    places = [
        RunPlace(row, np.array([p.position[:2] for p in model.poles], np.float64), *stations[k])
        for k, (model, row) in enumerate(zip(models, rows, strict=True))
        if model.poles
    ]
    return sorted(places, key=lambda p: (p.station_m, p.row.run_id))


def run_stations(runs: Sequence[RunModel], trajectory: Trajectory) -> list[tuple[float, float]]:
    """(first, last) metres along the drive of each run's poles: the vehicle's station at the
    trajectory sample nearest each pole; (-inf, inf) for a run without poles."""
    station = vehicle_station(trajectory, trajectory.time)
    tree = cKDTree(trajectory.position[:, :2])
    out = []
    for run in runs:
        if not run.poles:
            out.append((-np.inf, np.inf))
            continue
        along = station[tree.query([p.position[:2] for p in run.poles])[1]]
        out.append((float(along.min()), float(along.max())))
    return out


def segment_runs(session: ReviewSession, places: list[RunPlace]) -> np.ndarray:
    """(S,) int64: the index in ``places`` of each segment's run, -1 for none."""
    out = np.full(session.n_segments, -1, np.int64)
    if not places:
        return out
    seg = session.run.segments
    counted = np.flatnonzero(counted_segments(session))
    samples, owner = [], []
    for k, place in enumerate(places):
        line = _sampled(place.path)
        samples.append(line)
        owner.append(np.full(len(line), k))
    tree = cKDTree(np.concatenate(samples))
    distance, nearest = tree.query(seg["centroid"][counted, :2], distance_upper_bound=RUN_REACH_M)
    found = np.isfinite(distance)
    out[counted[found]] = np.concatenate(owner)[nearest[found]]
    return out


def counted_segments(session: ReviewSession) -> np.ndarray:
    """(S,) bool: the segments that count for a run: those the model or an operator calls
    guardrail, and every reviewed one."""
    labels = session.run.segments["label"]
    return labels | session.effective_label() | (session.operator_label >= 0)


def _sampled(path: np.ndarray) -> np.ndarray:
    """(K, 2) points every :data:`LINE_STEP_M` along a polyline (P, 2), its vertices included."""
    if len(path) == 1:
        return path
    parts = []
    for a, b in zip(path[:-1], path[1:], strict=True):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / LINE_STEP_M)))
        parts.append(a + (b - a) * np.linspace(0.0, 1.0, n, endpoint=False)[:, None])
    return np.concatenate([*parts, path[-1:]])


def route_overview(session: ReviewSession) -> dict:
    """The map and the inventory of the review app's route view (``GET /api/overview``)."""
    places = run_places(session)
    owner = segment_runs(session, places)
    seg = session.run.segments
    reviewed = session.operator_label >= 0
    changed = reviewed & ((session.operator_label == 1) != seg["label"])
    score = segment_queue_scores(seg)
    unchecked = unchecked_runs(seg["component"], seg["label"], seg["n_points"], reviewed, score)
    asked = asked_segments(seg, reviewed, unchecked=unchecked)
    runs = []
    for k, place in enumerate(places):
        mine = np.flatnonzero(owner == k)
        n_reviewed = int(reviewed[mine].sum())
        n_changed = int(changed[mine].sum())
        n_asked = int(asked[mine].sum())
        todo = mine[~reviewed[mine]]
        # Where "fly to" goes: the run's most doubtful unreviewed segment, else its first.
        target = todo[np.argmax(score[todo])] if len(todo) else (mine[0] if len(mine) else None)
        row = place.row
        runs.append(
            {
                "run_id": row.run_id,
                "status": row.status,
                "type": row.type,
                "signature": row.signature,
                "length_m": row.length_m,
                "poles": row.pole_count,
                "station_m": round(place.station_m, 1),
                "path": np.round(place.path, 2).tolist(),
                "segments": len(mine),
                "reviewed": n_reviewed,
                "changed": n_changed,
                "asked": n_asked,
                # Of what the queue asks or asked about, the share labelled: one label on a
                # run of forty doubtful segments is 1/40, not "reviewed".
                "progress": round(n_reviewed / (n_reviewed + n_asked), 4) if n_asked else 1.0,
                "state": DONE if not n_asked else STARTED if n_reviewed else UNREVIEWED,
                "segment": None if target is None else int(target),
            }
        )
    position = session.drive.trajectory.position
    step = max(1, int(np.ceil(len(position) / TRAJECTORY_VERTICES)))
    path = np.concatenate([position[::step, :2], position[-1:, :2]])
    length = vehicle_station(session.drive.trajectory, session.drive.trajectory.time[-1:])
    counted = counted_segments(session)
    return {
        "trajectory": np.round(path, 2).tolist(),
        "length_m": round(float(length[0]), 1),
        "runs": runs,
        "segments_off_runs": int((counted & (owner < 0)).sum()),
        "asked": int(asked.sum()),
        "reviewed": int(reviewed.sum()),
    }
