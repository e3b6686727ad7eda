"""The review session: one drive, its run folder and its label store, shared by the REST routers,
the 3D scene and the background jobs.

Labels are the operators' (per drive point, in the label store); a segment's *effective* label is
the majority of its operator-labelled points, or the model's (corrected, §3.3) label where no
operator has looked at it.
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
from app.segment_index import SegmentIndex
from guardrail_core.errors import InvalidOptionError, RunFolderError
from guardrail_core.extract.classifier_params import ClassifierParams
from guardrail_core.extract.segment_truth import segment_truth
from guardrail_core.formats.drive import Drive, load_drive
from guardrail_core.formats.label_store import LABEL_GUARDRAIL, LABEL_OTHER, LabelChange, LabelStore
from guardrail_core.formats.run_folder import Run
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.review.run_crops import RunCrops
from guardrail_core.review.training import segment_labels

#: What the review app writes lives in this folder of the drive: labels outlive run folders.
REVIEW_DIR = "review"
LABELS_FILE = "labels.sqlite"
MODELS_DIR = "models"

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
        with another number of points.
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
        self.drive: Drive = load_drive(drive_path)
        self.folder = RunFolder.open(run_path)  # every path of the run, its format checked
        self.run: Run = self.folder.load()
        n = len(self.drive.points)
        if len(self.run.point_segment) != n:
            raise RunFolderError(
                f"{run_path}: made from a drive of {len(self.run.point_segment)} points, but "
                f"{drive_path} has {n}; serve the run with the drive it was made from"
            )
        self.review_dir = Path(review_dir) if review_dir else self.drive.root / REVIEW_DIR
        self.operator = operator
        self.lock = threading.RLock()
        self.store = LabelStore(
            self.review_dir / LABELS_FILE, n_points=n, drive_name=self.drive.root.name
        )
        self.index = SegmentIndex(self.run.point_segment, len(self.run))
        # Crops are cut from the drive's images on request; a gallery page mostly asks a few.
        self.crops = RunCrops(self.run, self.drive.root, keep_images=CROP_IMAGES_KEPT)
        # The camera images with the points on them (the run's points never change).
        self.overlay = ImageOverlay(self.drive, self.run.point_segment, self.crops.params)
        self.models = ModelRegistry(self.review_dir / MODELS_DIR, self.run, model_dir)
        self.truth: np.ndarray | None = None  # (S,) bool, synthetic drives only
        if self.drive.truth is not None:
            self.truth = segment_truth(
                self.drive.truth.point_class, self.run.point_segment, len(self.run)
            )
        self.operator_label = segment_labels(
            self.run.point_segment, len(self.run), self.store.point_labels()
        )  # (S,) int8: -1 unreviewed
        self.selection = np.zeros(0, np.int64)
        self._listeners: list[Listener] = []

    # -- state ------------------------------------------------------------------------------

    @property
    def n_segments(self) -> int:
        return len(self.run)

    def effective_label(self) -> np.ndarray:
        """(S,) bool: the operator's label where reviewed, else the model's corrected label."""
        reviewed = self.operator_label >= 0
        return np.where(reviewed, self.operator_label == 1, self.run.segments["label"])

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
                self.index.points_of(ids),
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
            ids = self.index.segments_of(change.points)
            self._refresh(ids)
        self.notify("labels", ids)
        return Relabel(change, ids)

    def _refresh(self, segments: np.ndarray) -> None:
        self.operator_label[segments] = self.index.operator_labels(
            self.store.point_labels(), segments
        )

    def point_labels(self) -> np.ndarray:
        """(N,) int8 operator label of every drive point, -1 where none."""
        return self.store.point_labels()

    def select(self, segments: Sequence[int] | np.ndarray) -> np.ndarray:
        ids = np.unique(self.check_segments(segments))
        with self.lock:
            self.selection = ids
        self.notify("selection", ids)
        return ids

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
            "n_points": len(self.drive.points),
            "n_segments": self.n_segments,
            "reviewed_segments": int((self.operator_label >= 0).sum()),
            "label_counts": counts,
            "operator": self.operator,
        }
