"""A run's crops as the classifier takes them: cut from the drive's images when they are needed,
and their backbone embeddings completed on demand.

The run keeps, per segment, its chosen image and the rectangle around its projected points
(``segments.npz`` ``image``, ``rect``) and the crop parameters (``run.json``); a crop is cut
from those exactly as ``guardrail process`` cut it (:func:`~guardrail_core.extract.crops.
cut_crops`), at any size. No crop is stored: a 3 km drive has some 57,000, a survey day millions.

``guardrail process`` asks the CNN only where a segment's shape leaves its label open
(:mod:`guardrail_core.extract.classify.segment_scores`), so the crops it did not ask have NaN
rows in ``embeddings.npy``. Retraining and re-predicting need every crop's embedding: the first
time they do, the missing rows are computed from the crops (about 5 ms a crop on one core of the
development machine) and written back into the run, so that happens once per run.
"""

from __future__ import annotations

import io
import threading
from collections import OrderedDict
from pathlib import Path

import cv2
import numpy as np

from guardrail_core.errors import MissingDriveFileError, RunFolderError
from guardrail_core.extract.crops import CROP_OK, CropParams, cut_crops
from guardrail_core.formats.atomic import atomic_write
from guardrail_core.formats.run_folder import CROP_STATUS_NAMES, Run
from guardrail_core.params import ParameterError

#: JPEG quality of a crop sent to the app (the crops the run once stored had the same).
JPEG_QUALITY = 92


class RunCrops:
    """The crops of a run's segments, cut from its drive's images.

    Parameters
    ----------
    run : the run folder
    drive_root : the drive folder the run was made from; None: ``run.json``'s ``drive.path``
        (the app passes the drive it serves, which may have moved since)
    keep_images : decoded images kept for the next crops (the app's gallery asks for crops one
        by one, mostly from a few images); 0 keeps none

    Thread-safe: the app's request threads share one.
    """

    def __init__(self, run: Run, drive_root: str | Path | None = None, *, keep_images: int = 0):
        self.run = run
        self.drive_root = Path(drive_root if drive_root is not None else run.info.drive.path)
        try:
            self.params = CropParams.from_json(run.info.params.get("crops", {}))
        except ParameterError as exc:
            raise RunFolderError(f"{run.root / 'run.json'}: params.crops: {exc}") from exc
        self._keep = int(keep_images)
        self._images: OrderedDict[int, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()

    def has_crop(self, segment: int) -> bool:
        """Whether the segment has a crop (status ok); False for an id out of range."""
        status = self.run.segments["crop_status"]
        return 0 <= segment < len(status) and int(status[segment]) == CROP_OK

    def cut(self, segments: np.ndarray, size: int, *, progress: bool = False) -> np.ndarray:
        """(K, size, size, 3) uint8 RGB crops of the segments (K,), each image decoded once.

        Raises
        ------
        RunFolderError
            A segment has no crop (its status is not ok) or is not one of the run's.
        MissingDriveFileError
            An image the crops lie in is missing or unreadable.
        """
        from guardrail_core.progress import progress_bar

        segments = np.asarray(segments, np.int64).reshape(-1)
        table = self.run.segments
        bad = (segments < 0) | (segments >= len(self.run))
        if bad.any():
            raise RunFolderError(
                f"{self.run.root}: segment {int(segments[bad][0])} is not one of the run's "
                f"{len(self.run)}"
            )
        status = table["crop_status"][segments]
        if (status != CROP_OK).any():
            s = int(segments[status != CROP_OK][0])
            name = CROP_STATUS_NAMES.get(int(table["crop_status"][s]), "?")
            raise RunFolderError(f"{self.run.root}: segment {s} has no crop (status {name})")
        with progress_bar(
            total=len(segments), desc="cutting crops", unit="crop", enabled=progress
        ) as bar:
            return cut_crops(
                self._image,
                table["image"][segments],
                table["rect"][segments],
                size,
                self.params,
                progress=bar.update,
            )

    def jpeg(self, segment: int, size: int) -> bytes:
        """The crop of one segment as JPEG bytes (see :meth:`cut` for the errors)."""
        crop = self.cut(np.array([segment]), size)[0]
        ok, data = cv2.imencode(
            ".jpg", cv2.cvtColor(crop, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]
        )
        if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
            raise RunFolderError(f"segment {segment}: its crop could not be encoded")
        return bytes(data)

    def _image(self, index: int) -> np.ndarray:
        """Image ``index`` of ``run.json``'s ``images``, (H, W, 3) uint8 RGB."""
        with self._lock:
            if index in self._images:
                self._images.move_to_end(index)
                return self._images[index]
        images = self.run.info.images
        if not 0 <= index < len(images):
            raise RunFolderError(
                f"{self.run.root}: segments.npz names image {index}, run.json lists {len(images)}"
            )
        path = self.drive_root / images[index]
        picture = cv2.imread(str(path), cv2.IMREAD_COLOR) if path.is_file() else None
        if picture is None:
            raise MissingDriveFileError(
                f"{path}: image missing or unreadable (the run's crops are cut from its drive's "
                "images)"
            )
        picture = np.ascontiguousarray(picture[:, :, ::-1])  # BGR -> RGB
        if self._keep:
            with self._lock:
                self._images[index] = picture
                while len(self._images) > self._keep:
                    self._images.popitem(last=False)
        return picture


def read_crops(
    run: Run, segments: np.ndarray, input_size: int, *, drive_root: str | Path | None = None
) -> np.ndarray:
    """(K, input_size, input_size, 3) uint8 RGB crops of the given segments, cut from the drive's
    images (:class:`RunCrops`; ``drive_root`` as there).

    Raises
    ------
    RunFolderError
        A segment has no crop.
    MissingDriveFileError
        An image is missing or unreadable.
    """
    return RunCrops(run, drive_root).cut(segments, input_size)


def complete_embeddings(
    run: Run,
    input_size: int,
    *,
    rows: np.ndarray | None = None,
    drive_root: str | Path | None = None,
    progress: bool = False,
) -> np.ndarray | None:
    """(S, 1280) float16 backbone embeddings of the run's segments, finite for every segment with
    a crop: the rows the run lacks are embedded from the crops (cut from the drive's images) and
    saved into the run.

    Parameters
    ----------
    run : the run folder
    input_size : px, the model's crop size
    rows : (K,) int64, the segments whose embeddings are needed; None: every segment with a crop
    drive_root : the drive folder (see :class:`RunCrops`)
    progress : a bar while embedding

    Returns
    -------
    The embeddings (finite at least in ``rows``), or None when the run has none (a full model's
    run), or not one per segment.

    Raises
    ------
    MissingDriveFileError
        An image a missing row's crop lies in is missing or unreadable.
    """
    from guardrail_core.extract.classify.backbone import EMBEDDING_DIM, embed_crops  # torch

    stored = run.embeddings()
    if stored is None or stored.shape != (len(run), EMBEDDING_DIM):
        return None
    has_crop = run.segments["crop_status"] == CROP_OK
    if not has_crop.any():
        return stored
    wanted = has_crop.copy()
    if rows is not None:
        wanted[:] = False
        wanted[np.asarray(rows, np.int64)] = True
        wanted &= has_crop
    missing = np.flatnonzero(wanted & ~np.isfinite(stored).all(axis=1))
    if len(missing) == 0:
        return stored
    stored = stored.copy()
    crops = RunCrops(run, drive_root).cut(missing, input_size, progress=progress)
    stored[missing] = embed_crops(crops, progress=progress).astype(np.float16)
    buffer = io.BytesIO()
    np.save(buffer, stored)
    atomic_write(run.folder.embeddings_file, buffer.getvalue(), overwrite=True)
    return stored
