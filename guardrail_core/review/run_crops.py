"""A run's crops as the classifier takes them: their JPEGs, and their backbone embeddings
completed on demand.

``guardrail process`` asks the CNN only where a segment's shape leaves its label open
(:mod:`guardrail_core.extract.segment_scores`), so the crops it did not ask have NaN rows in
``embeddings.npy``. Retraining and re-predicting need every crop's embedding: the first time
they do, the missing rows are computed from the crops' JPEGs (about 5 ms a crop on one core of
the development machine) and written back into the run, so that happens once per run.
"""

from __future__ import annotations

import io

import cv2
import numpy as np

from guardrail_core.errors import RunFolderError
from guardrail_core.extract.crops import CROP_OK
from guardrail_core.formats.atomic import atomic_write
from guardrail_core.formats.run_folder import Run


def read_crops(run: Run, segments: np.ndarray, input_size: int) -> np.ndarray:
    """(K, input_size, input_size, 3) uint8 RGB crops of the given segments, from their JPEGs.

    Raises :class:`RunFolderError` for a missing or unreadable JPEG or one of another size.
    """
    out = np.empty((len(segments), input_size, input_size, 3), np.uint8)
    for i, s in enumerate(np.asarray(segments, np.int64).tolist()):
        out[i] = _read_crop(run, s, input_size)
    return out


def complete_embeddings(
    run: Run, input_size: int, *, rows: np.ndarray | None = None, progress: bool = False
) -> np.ndarray | None:
    """(S, 1280) float16 backbone embeddings of the run's segments, finite for every segment with
    a crop: the rows the run lacks are embedded from the crops' JPEGs and saved into the run.

    Parameters
    ----------
    run : the run folder
    input_size : px, the model's crop size; the run's crops must have it
    rows : (K,) int64, the segments whose embeddings are needed; None: every segment with a crop
    progress : a bar while embedding

    Returns
    -------
    The embeddings (finite at least in ``rows``), or None when the run has none (a full model's
    run), or not one per segment.

    Raises
    ------
    RunFolderError
        A crop JPEG is missing, unreadable or not ``input_size`` px.
    """
    from guardrail_core.extract.backbone import EMBEDDING_DIM, embed_crops  # torch

    stored = run.embeddings()
    if stored is None or stored.shape != (len(run), EMBEDDING_DIM):
        return None
    has_crop = run.segments["crop_status"] == CROP_OK
    if not has_crop.any():
        return stored
    _read_crop(run, int(np.argmax(has_crop)), input_size)  # embeddings are of this crop size
    wanted = has_crop.copy()
    if rows is not None:
        wanted[:] = False
        wanted[np.asarray(rows, np.int64)] = True
        wanted &= has_crop
    missing = np.flatnonzero(wanted & ~np.isfinite(stored).all(axis=1))
    if len(missing) == 0:
        return stored
    stored = stored.copy()
    stored[missing] = embed_crops(read_crops(run, missing, input_size), progress=progress).astype(
        np.float16
    )
    buffer = io.BytesIO()
    np.save(buffer, stored)
    atomic_write(run.folder.embeddings_file, buffer.getvalue(), overwrite=True)
    return stored


def _read_crop(run: Run, segment: int, input_size: int) -> np.ndarray:
    path = run.crop_path(segment)
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise RunFolderError(f"{path}: the crop of segment {segment} is missing or unreadable")
    if image.shape != (input_size, input_size, 3):
        raise RunFolderError(
            f"{path}: expected a {input_size} x {input_size} px crop (the model's input size), "
            f"got {image.shape[1]} x {image.shape[0]} px"
        )
    return image[:, :, ::-1]  # BGR -> RGB
