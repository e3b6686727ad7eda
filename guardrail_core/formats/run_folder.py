"""The run folder: what ``guardrail process`` writes, readable without re-running anything.

::

    RUN_DIR/
      run.json          format version, drive, model, parameters, counts
      points/NNNNNN.npz segment (n,) int32 of every point of the drive's tile NNNNNN; -1 road
                        surface, -2 far from road, -3 not processed (its tile failed)
      segments.npz      one row per segment: geometry, chosen image and rectangle, crop status,
                        probability, raw and corrected labels (see SEGMENT_FIELDS)
      segments.csv      the same table for people and spreadsheets
      embeddings.npy    (S, 1280) float16 backbone embeddings (fast models), for quick retraining
      timings.json      points in and seconds of every stage
"""

from __future__ import annotations

import csv
import io
import json
from contextlib import ExitStack
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from guardrail_core.formats.atomic import atomic_file
from guardrail_core.formats.run_info import RunInfo

if TYPE_CHECKING:
    from guardrail_core.formats.run_folder_paths import RunFolder

#: 2: segments fused from shape and crop (features, crop_probability); 3: points/ in tiles;
#: 4: no crops/ folder (a crop is cut from the drive's image when it is needed:
#: :mod:`guardrail_core.review.run_crops`)
RUN_FORMAT_VERSION = 4
#: The files of a run folder (their paths: :class:`guardrail_core.formats.run_folder_paths.RunFolder`).
RUN_FILE = "run.json"
POINTS_DIR = "points"
SEGMENTS_FILE = "segments.npz"
SEGMENTS_CSV = "segments.csv"
TIMINGS_FILE = "timings.json"
EMBEDDINGS_FILE = "embeddings.npy"
POINT_ROAD = -1
POINT_OFF_ROAD = -2
#: A point of a processing tile that failed (``run.json`` ``tiles`` says why).
POINT_UNPROCESSED = -3

# crop_status of segments.npz: what became of a segment's crop (extract/crops.py decides).
CROP_OK = 0
CROP_NO_IMAGE = 1
"""No image contains all of the segment's points (no camera saw it whole)."""
CROP_TOO_SMALL = 2
"""The segment has too few points to be worth a crop; it stays a segment all the same."""
CROP_STATUS_NAMES = {CROP_OK: "ok", CROP_NO_IMAGE: "no_image", CROP_TOO_SMALL: "too_small"}

# Field name -> (dtype, trailing shape) of segments.npz; None: any width, the same for every row
# (the shape features' count belongs to the extraction, extract/classify/shape_features.py).
SEGMENT_FIELDS: dict[str, tuple[str, tuple[int | None, ...]]] = {
    "component": ("int32", ()),
    "slice_index": ("int64", ()),
    "n_points": ("int64", ()),
    "centroid": ("float64", (3,)),
    "bbox_min": ("float64", (3,)),
    "bbox_max": ("float64", (3,)),
    "lateral": ("float64", (2,)),
    "height": ("float64", (2,)),
    "time": ("float64", (2,)),
    "image": ("int64", ()),
    "rect": ("int32", (4,)),
    "crop_status": ("uint8", ()),
    "crop_probability": ("float32", ()),
    "features": ("float32", (None,)),
    "probability": ("float32", ()),
    "raw_label": ("bool", ()),
    "label": ("bool", ()),
}


@dataclass
class Run:
    """A run folder loaded into memory.

    Attributes
    ----------
    root : the folder
    info : run.json, typed
    segments : SEGMENT_FIELDS arrays, each with S rows
    timings : timings.json
    point_segment : (N,) int32, segment of every drive point (or POINT_ROAD / POINT_OFF_ROAD),
        read from the point tiles the first time it is asked for: a survey-scale run's reader
        (the review app) reads the tiles it needs instead (:meth:`RunFolder.point_segment_tile`)
    """

    root: Path
    info: RunInfo
    segments: dict[str, np.ndarray]
    timings: dict[str, Any]

    def __len__(self) -> int:
        return int(len(self.segments["n_points"]))

    @cached_property
    def point_segment(self) -> np.ndarray:
        return self.folder.point_segment()

    @property
    def folder(self) -> RunFolder:
        """The run folder's paths (its reconstruction's too)."""
        from guardrail_core.formats.run_folder_paths import RunFolder  # it builds on this module

        return RunFolder(self.root)

    def embeddings(self) -> np.ndarray | None:
        """(S, 1280) float16 backbone embeddings, or None when the run has none."""
        return self.folder.embeddings()


def point_tile_name(tile: int) -> str:
    """``points/NNNNNN.npz``: the segments of the points of the drive's tile ``tile``."""
    return f"{POINTS_DIR}/{tile:06d}.npz"


def write_point_tile(folder: Path, tile: int, point_segment: np.ndarray) -> None:
    """Write the segment (n,) int32 of every point of the drive's tile ``tile`` into ``folder``."""
    path = Path(folder) / point_tile_name(tile)
    path.parent.mkdir(exist_ok=True)
    np.savez_compressed(path, segment=np.asarray(point_segment, np.int32))


def write_run_files(
    folder: Path,
    *,
    info: dict[str, Any],
    segments: dict[str, np.ndarray],
    timings: dict[str, Any],
    image_files: list[str],
    embeddings: np.ndarray | None = None,
) -> None:
    """Write the run's tables into ``folder`` (a staging folder; crops and the point tiles,
    :func:`write_point_tile`, are written by the caller)."""
    folder = Path(folder)
    n = len(segments["n_points"])
    for name, (_, shape) in SEGMENT_FIELDS.items():
        array = segments[name]
        if not _has_shape(array.shape, (n, *shape)):
            raise ValueError(f"segments[{name!r}] has shape {array.shape}, expected {(n, *shape)}")
    table: dict[str, Any] = {
        name: np.asarray(segments[name], dtype) for name, (dtype, _) in SEGMENT_FIELDS.items()
    }
    np.savez_compressed(folder / "segments.npz", **table)
    if embeddings is not None:
        np.save(folder / "embeddings.npy", np.asarray(embeddings, np.float16))
    info = {"format_version": RUN_FORMAT_VERSION, **info, "images": image_files}
    (folder / "run.json").write_text(json.dumps(info, indent=2) + "\n")
    (folder / "timings.json").write_text(json.dumps(timings, indent=2) + "\n")
    (folder / "segments.csv").write_text(_segments_csv(segments, image_files), newline="")


def replace_run_tables(
    root: str | Path, *, segments: dict[str, np.ndarray], info: dict[str, Any]
) -> None:
    """Replace a run folder's ``segments.csv``, ``segments.npz`` and ``run.json`` in place.

    Each file is written whole to a temporary file in the folder, flushed to disk and moved over
    the old one (:func:`guardrail_core.formats.atomic.atomic_file`), in the order csv, npz,
    json: a reader never sees a half-written file, and run.json (the model the run names)
    changes last. An error while writing replaces none of them.

    Parameters
    ----------
    root : the run folder
    segments : every SEGMENT_FIELDS array, each with S rows
    info : the new run.json content (``format_version`` and ``images`` included)

    Raises
    ------
    ValueError
        A segments array is missing or has the wrong shape; nothing is written then.
    """
    root = Path(root)
    n = len(segments["n_points"])
    for name, (_, shape) in SEGMENT_FIELDS.items():
        if name not in segments or not _has_shape(np.shape(segments[name]), (n, *shape)):
            got = np.shape(segments[name]) if name in segments else "nothing"
            raise ValueError(f"segments[{name!r}]: expected shape {(n, *shape)}, got {got}")
    table: dict[str, Any] = {
        name: np.asarray(segments[name], dtype) for name, (dtype, _) in SEGMENT_FIELDS.items()
    }
    # Entered json, npz, csv and left in the reverse order: all three are written before the
    # first is replaced, and run.json (the model the run names) changes last.
    with ExitStack() as stack:
        json_file, npz_file, csv_file = (
            stack.enter_context(atomic_file(root / name, overwrite=True))
            for name in ("run.json", "segments.npz", "segments.csv")
        )
        csv_file.write(_segments_csv(table, list(info["images"])).encode("utf-8"))
        np.savez_compressed(npz_file, **table)
        json_file.write((json.dumps(info, indent=2) + "\n").encode("utf-8"))


def _segments_csv(segments: dict[str, np.ndarray], image_files: list[str]) -> str:
    """segments.csv's text (lines end in CRLF, as the csv module writes them)."""

    text = io.StringIO()
    writer = csv.writer(text)
    writer.writerow(
        ["segment", "n_points", "x", "y", "z", "slice_index", "crop_status", "image"]
        + ["x0", "y0", "x1", "y1", "crop_probability", "probability", "raw_label", "label"]
    )
    for s in range(len(segments["n_points"])):
        image = int(segments["image"][s])
        crop_probability = float(segments["crop_probability"][s])
        probability = float(segments["probability"][s])
        writer.writerow(
            [s, int(segments["n_points"][s])]
            + [f"{v:.3f}" for v in segments["centroid"][s]]
            + [int(segments["slice_index"][s])]
            + [CROP_STATUS_NAMES[int(segments["crop_status"][s])]]
            + [image_files[image] if image >= 0 else ""]
            + [int(v) for v in segments["rect"][s]]
            + ["" if np.isnan(crop_probability) else f"{crop_probability:.4f}"]
            + ["" if np.isnan(probability) else f"{probability:.4f}"]
            + ["guardrail" if segments["raw_label"][s] else "other"]
            + ["guardrail" if segments["label"][s] else "other"]
        )
    return text.getvalue()


def load_run(root: str | Path) -> Run:
    """Load a run folder written by ``guardrail process``
    (:meth:`guardrail_core.formats.run_folder_paths.RunFolder.load`).

    Raises
    ------
    RunFolderError
        The folder or one of its files is missing, or written by another format version
        (:class:`~guardrail_core.errors.NotARunFolderError`,
        :class:`~guardrail_core.errors.RunFormatVersionError`).
    """
    from guardrail_core.formats.run_folder_paths import RunFolder  # it builds on this module

    return RunFolder.open(root).load()


def _has_shape(shape: tuple[int, ...], expected: tuple[int | None, ...]) -> bool:
    """Whether ``shape`` is ``expected``, where None stands for any size."""
    return len(shape) == len(expected) and all(
        e is None or s == e for s, e in zip(shape, expected, strict=True)
    )
