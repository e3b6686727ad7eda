"""The review session: one drive, its run folder and its label store, shared by the REST routers,
the 3D scene and the background jobs.

Labels are the operators' (per drive point, in the label store); a segment's *effective* label is
the majority of its operator-labelled points, or the model's (corrected, §3.3) label where no
operator has looked at it.

The session holds the run's per-segment tables and nothing per drive point: the points, their
segments and their labels are read for the segments and the windows asked for
(:mod:`app.run_tiles`, :meth:`LabelStore.labels_at`), so a survey's run opens as fast as a
street's.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.image_overlay import ImageOverlay
from app.model_registry import ModelRegistry
from app.run_tiles import RunTiles
from app.version_watch import VersionWatch
from guardrail_core.errors import InvalidOptionError
from guardrail_core.extract.classify.crop_classifier_params import ClassifierParams
from guardrail_core.formats.drive import DriveSource, open_drive
from guardrail_core.formats.label_store import LABEL_GUARDRAIL, LABEL_OTHER, LabelChange, LabelStore
from guardrail_core.formats.run_folder import Run
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.review.model_lineage import FINE_TUNED_MODELS_DIR
from guardrail_core.review.run_crops import RunCrops

#: What the review app writes lives in this folder of the drive: labels outlive run folders.
REVIEW_DIR = "review"
LABELS_FILE = "labels.sqlite"

LABEL_VALUES = {"other": LABEL_OTHER, "guardrail": LABEL_GUARDRAIL}

#: px, the side of the crops the app shows: the classifier's input (what it saw).
CROP_PX = ClassifierParams().input_size_px
#: Decoded drive images kept for the next crop (a gallery page's crops come from a few images).
CROP_IMAGES_KEPT = 8

#: Listeners hear ``(event, segments)``: "labels" (their effective labels changed),
#: "selection", "predictions" (a model was activated) or "reconstruction" (it was redone).
Listener = Callable[[str, np.ndarray], None]


@dataclass(frozen=True)
class Relabel:
    """What one relabelling (or undo) did."""

    change: LabelChange | None
    segments: np.ndarray  # (K,) int64, segments whose effective label may have changed


class ReviewSession:
    """A drive and its run under review.

    Parameters
    ----------
    drive_path, run_path : the drive folder and the run folder ``guardrail process`` made of it
    review_dir : where labels and retrained models go (default ``DRIVE/review``)
    operator : the default name recorded with each label
    model_dir : the folder of the model that made the run, so it can be activated again

    Raises
    ------
    RunFolderError
        ``run_path`` is not a run folder of this format version, or it was made from a drive
        with another number of points or tiles.
    """

    def __init__(
        self,
        drive_path: str | Path,
        run_path: str | Path,
        *,
        review_dir: str | Path | None = None,
        operator: str = "operator",
        model_dir: str | Path | None = None,
    ) -> None:
        # The drive without its points and the run's tables: the points are read a tile at a
        # time as a request needs them (a survey's do not fit in memory).
        self.drive: DriveSource = open_drive(drive_path)
        self.folder = RunFolder.open(run_path)  # every path of the run, its format checked
        self.run: Run = self.folder.load()
        self.tiles = RunTiles(self.drive, self.folder, self.run.segments["time"])
        self.review_dir = Path(review_dir) if review_dir else self.drive.root / REVIEW_DIR
        self.operator = operator
        self.lock = threading.RLock()
        self.store = LabelStore(
            self.review_dir / LABELS_FILE,
            n_points=self.tiles.n_points,
            drive_name=self.drive.root.name,
        )
        # Crops are cut from the drive's images on request; a gallery page mostly asks a few.
        self.crops = RunCrops(self.run, self.drive.root, keep_images=CROP_IMAGES_KEPT)
        # The camera images with the points on them (the run's points never change).
        self.overlay = ImageOverlay(self.drive, self.tiles, self.crops.params)
        self.models = ModelRegistry(self.review_dir / FINE_TUNED_MODELS_DIR, self.run, model_dir)
        self.operator_label = np.full(len(self.run), -1, np.int8)  # (S,) -1 unreviewed
        segments, label = self.tiles.operator_labels(*self.store.labelled())
        self.operator_label[segments] = label
        self.selection = np.zeros(0, np.int64)
        self.lasso = np.zeros(0, np.int64)  # (L,) drive points of the last lasso, or none
        # Bumped on every change of the selection or lasso: the page's long poll waits on it.
        self.selection_watch = VersionWatch()
        self._listeners: list[Listener] = []

    # -- state ------------------------------------------------------------------------------

    @property
    def n_segments(self) -> int:
        return len(self.run)

    def effective_label(self) -> np.ndarray:
        """(S,) bool: the operator's label where reviewed, else the model's corrected label."""
        reviewed = self.operator_label >= 0
        return np.where(reviewed, self.operator_label == 1, self.run.segments["label"])

    def truth(self, segments: Sequence[int] | np.ndarray) -> np.ndarray | None:
        """(K,) bool simulated truth of ``segments`` (checked ids), or None for a real drive."""
        return self.tiles.truth(self.check_segments(segments))

    def check_segments(self, segments: Sequence[int] | np.ndarray) -> np.ndarray:
        """(K,) int64 segment ids, checked to exist.

        Raises
        ------
        KeyError
            An id is not a segment of the run (the routers answer 404).
        """
        ids = np.asarray(segments, np.int64).ravel()
        bad = ids[(ids < 0) | (ids >= self.n_segments)]
        if len(bad):
            raise KeyError(f"no segment {int(bad[0])} (the run has {self.n_segments})")
        return ids

    def subscribe(self, listener: Listener) -> None:
        self._listeners.append(listener)

    def unsubscribe(self, listener: Listener) -> None:
        if listener in self._listeners:
            self._listeners.remove(listener)

    def notify(self, event: str, segments: np.ndarray) -> None:
        for listener in list(self._listeners):
            listener(event, segments)

    # -- labels -----------------------------------------------------------------------------

    def relabel(
        self,
        segments: Sequence[int] | np.ndarray,
        label: str,
        *,
        who: str | None = None,
        expand: str = "none",
    ) -> Relabel:
        """Give every point of ``segments`` the operator label ``label`` in one batch.

        ``expand="component"`` takes the whole connected run (wireframe component, §3.1) of each
        segment instead, as when an operator relabels a guardrail at once.
        """
        if label not in LABEL_VALUES:
            raise InvalidOptionError(f"label: expected 'guardrail' or 'other', got {label!r}")
        ids = self.check_segments(segments)
        if expand == "component":
            component = self.run.segments["component"]
            ids = np.flatnonzero(np.isin(component, component[ids])).astype(np.int64)
        elif expand != "none":
            raise InvalidOptionError(f"expand: expected 'none' or 'component', got {expand!r}")
        ids = np.unique(ids)
        with self.lock:
            change = self.store.set_labels(
                self.tiles.points_of(ids),
                LABEL_VALUES[label],
                who=who or self.operator,
                model_version=self.models.active_version,
                segments=[int(s) for s in ids],
            )
            self._refresh(ids)
        self.notify("labels", ids)
        return Relabel(change, ids)

    def undo(self, *, who: str | None = None) -> Relabel:
        """Revert the operator's last labelling (any operator's when ``who`` is None)."""
        with self.lock:
            change = self.store.undo(who=who)
            if change is None:
                return Relabel(None, np.zeros(0, np.int64))
            ids = self.tiles.segments_of(change.points)
            self._refresh(ids)
        self.notify("labels", ids)
        return Relabel(change, ids)

    def _refresh(self, segments: np.ndarray) -> None:
        points = self.tiles.points_of(segments)
        self.operator_label[segments] = -1
        labelled, label = self.tiles.operator_labels(points, self.store.labels_at(points))
        self.operator_label[labelled] = label

    def labels_at(self, points: np.ndarray) -> np.ndarray:
        """(K,) int8 operator label of each drive point of ``points``, -1 where none."""
        return self.store.labels_at(points)

    def select(self, segments: Sequence[int] | np.ndarray) -> np.ndarray:
        """Select whole segments (a lasso's points are let go)."""
        ids = np.unique(self.check_segments(segments))
        with self.lock:
            self.selection = ids
            self.lasso = np.zeros(0, np.int64)
        self.selection_watch.bump()  # the page first: the 3D view's redraw takes longer
        self.notify("selection", ids)
        return ids

    def select_points(self, points: np.ndarray) -> np.ndarray:
        """Select the drive points a lasso took (points in no segment are left out); the
        selection becomes their segments. Returns the segments."""
        points = np.unique(np.asarray(points, np.int64))
        segment = self.tiles.segment_of(points)
        ids = np.unique(segment[segment >= 0]).astype(np.int64)
        with self.lock:
            self.lasso = points[segment >= 0]
            self.selection = ids
        self.selection_watch.bump()
        self.notify("selection", ids)
        return ids

    def cancel_lasso(self) -> np.ndarray:
        """Let go of a lasso: the points one took (its segments stay selected), and one being
        drawn in the 3D view (the scene ends it on the event). Returns the selection."""
        with self.lock:
            self.lasso = np.zeros(0, np.int64)
            ids = self.selection
        self.selection_watch.bump()
        self.notify("lasso_cancelled", ids)
        return ids

    def relabel_lasso(self, label: str, *, who: str | None = None) -> Relabel:
        """Give the lasso's points (not their whole segments) the operator label ``label``.

        Raises
        ------
        InvalidOptionError
            No lasso is selected, or the label is not guardrail or other.
        """
        if label not in LABEL_VALUES:
            raise InvalidOptionError(f"label: expected 'guardrail' or 'other', got {label!r}")
        with self.lock:
            points = self.lasso
            if len(points) == 0:
                raise InvalidOptionError("no lasso is selected: draw one in the 3D view first")
            ids = self.tiles.segments_of(points)
            change = self.store.set_labels(
                points,
                LABEL_VALUES[label],
                who=who or self.operator,
                model_version=self.models.active_version,
                segments=[int(s) for s in ids],
                note=f"lasso of {len(points)} points",
            )
            self._refresh(ids)
        self.notify("labels", ids)
        return Relabel(change, ids)

    # -- models -----------------------------------------------------------------------------

    def crop_jpeg(self, segment: int) -> bytes:
        """The segment's crop (JPEG, :data:`CROP_PX` px), cut from the drive's image.

        Raises
        ------
        RunFolderError
            The segment has no crop.
        MissingDriveFileError
            Its image has gone from the drive folder.
        """
        return self.crops.jpeg(segment, CROP_PX)

    def reload_run(self) -> None:
        """Read the run folder again (after a model's predictions were written into it)."""
        with self.lock:
            self.run = self.folder.load()
            self.models.run = self.run
            self.crops = RunCrops(self.run, self.drive.root, keep_images=CROP_IMAGES_KEPT)
        self.notify("predictions", np.arange(self.n_segments))

    def close(self) -> None:
        self.store.close()

    def describe(self) -> dict[str, Any]:
        counts = self.store.counts()
        return {
            "drive": str(self.drive.root),
            "run": str(self.run.root),
            "n_points": self.tiles.n_points,
            "n_segments": self.n_segments,
            "reviewed_segments": int((self.operator_label >= 0).sum()),
            "label_counts": counts,
            "operator": self.operator,
        }
