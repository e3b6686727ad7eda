"""The run folder: what ``guardrail process`` writes, readable without re-running anything.

::

    RUN_DIR/
      run.json          format version, drive, model, parameters, counts
      points.npz        segment (N,) int32 of every drive point; -1 road surface, -2 far from road
      segments.npz      one row per segment: geometry, chosen image and rectangle, crop status,
                        probability, raw and corrected labels (see SEGMENT_FIELDS)
      segments.csv      the same table for people and spreadsheets
      crops/NNNNNN.jpg  the crop the classifier saw, per segment with a crop
      embeddings.npy    (S, 1280) float16 backbone embeddings (fast models), for quick retraining
      timings.json      points in and seconds of every stage
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.errors import RunFolderError
from guardrail_core.extract.shape_features import SEGMENT_FEATURE_DIM

RUN_FORMAT_VERSION = 2  # 2: segments fused from shape and crop (features, crop_probability)
POINT_ROAD = -1
POINT_OFF_ROAD = -2

# Field name -> (dtype, trailing shape) of segments.npz.
SEGMENT_FIELDS: dict[str, tuple[str, tuple[int, ...]]] = {
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
    "features": ("float32", (SEGMENT_FEATURE_DIM,)),
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
    info : run.json
    point_segment : (N,) int32, segment of every drive point (or POINT_ROAD / POINT_OFF_ROAD)
    segments : SEGMENT_FIELDS arrays, each with S rows
    timings : timings.json
    """

    root: Path
    info: dict[str, Any]
    point_segment: np.ndarray
    segments: dict[str, np.ndarray]
    timings: dict[str, Any]

    def __len__(self) -> int:
        return int(len(self.segments["n_points"]))

    def crop_path(self, segment: int) -> Path:
        return self.root / crop_name(segment)

    def embeddings(self) -> np.ndarray | None:
        """(S, 1280) float16 backbone embeddings, or None when the run has none."""
        path = self.root / "embeddings.npy"
        return np.load(path, allow_pickle=False) if path.is_file() else None


def crop_name(segment: int) -> str:
    return f"crops/{segment:06d}.jpg"


def write_run_files(
    folder: Path,
    *,
    info: dict[str, Any],
    point_segment: np.ndarray,
    segments: dict[str, np.ndarray],
    timings: dict[str, Any],
    image_files: list[str],
    embeddings: np.ndarray | None = None,
) -> None:
    """Write the run's tables into ``folder`` (a staging folder; crops are written by the caller)."""
    folder = Path(folder)
    n = len(segments["n_points"])
    for name, (_, shape) in SEGMENT_FIELDS.items():
        array = segments[name]
        if array.shape != (n, *shape):
            raise ValueError(f"segments[{name!r}] has shape {array.shape}, expected {(n, *shape)}")
    np.savez_compressed(folder / "points.npz", segment=np.asarray(point_segment, np.int32))
    table: dict[str, Any] = {
        name: np.asarray(segments[name], dtype) for name, (dtype, _) in SEGMENT_FIELDS.items()
    }
    np.savez_compressed(folder / "segments.npz", **table)
    if embeddings is not None:
        np.save(folder / "embeddings.npy", np.asarray(embeddings, np.float16))
    info = {"format_version": RUN_FORMAT_VERSION, **info, "images": image_files}
    (folder / "run.json").write_text(json.dumps(info, indent=2) + "\n")
    (folder / "timings.json").write_text(json.dumps(timings, indent=2) + "\n")
    _write_csv(folder / "segments.csv", segments, image_files)


def replace_run_tables(
    root: str | Path, *, segments: dict[str, np.ndarray], info: dict[str, Any]
) -> None:
    """Replace a run folder's ``segments.csv``, ``segments.npz`` and ``run.json`` in place.

    Each file is written whole to a temporary file in the folder, flushed to disk and moved over
    the old one with :func:`os.replace` (atomic), in the order csv, npz, json: a reader never sees
    a half-written file, and run.json (the model the run names) changes last.

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
        if name not in segments or np.shape(segments[name]) != (n, *shape):
            got = np.shape(segments[name]) if name in segments else "nothing"
            raise ValueError(f"segments[{name!r}]: expected shape {(n, *shape)}, got {got}")
    table: dict[str, Any] = {
        name: np.asarray(segments[name], dtype) for name, (dtype, _) in SEGMENT_FIELDS.items()
    }
    text = json.dumps(info, indent=2) + "\n"
    staged: list[tuple[Path, Path]] = []
    try:
        for name in ("segments.csv", "segments.npz", "run.json"):
            tmp = root / f".{name}.tmp{os.getpid()}"
            staged.append((tmp, root / name))
            if name == "segments.csv":
                _write_csv(tmp, table, list(info["images"]))
            elif name == "segments.npz":
                with tmp.open("wb") as f:
                    np.savez_compressed(f, **table)
            else:
                tmp.write_text(text)
            with tmp.open("rb+") as f:
                os.fsync(f.fileno())
        for tmp, target in staged:
            os.replace(tmp, target)
    finally:
        for tmp, _ in staged:
            tmp.unlink(missing_ok=True)


def _write_csv(path: Path, segments: dict[str, np.ndarray], image_files: list[str]) -> None:
    from guardrail_core.extract.crops import CROP_STATUS_NAMES

    with path.open("w", newline="") as f:
        writer = csv.writer(f)
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


def load_run(root: str | Path) -> Run:
    """Load a run folder written by ``guardrail process``.

    Raises
    ------
    RunFolderError
        The folder or one of its files is missing, or written by another format version.
    """
    root = Path(root)
    if not (root / "run.json").is_file():
        raise RunFolderError(f"{root}: not a run folder (no run.json); run `guardrail process`")
    try:
        info = json.loads((root / "run.json").read_text())
    except json.JSONDecodeError as exc:
        raise RunFolderError(f"{root / 'run.json'}: not valid JSON ({exc})") from exc
    if info.get("format_version") != RUN_FORMAT_VERSION:
        raise RunFolderError(
            f"{root}: run format version {info.get('format_version')!r}, this version of the "
            f"tool reads {RUN_FORMAT_VERSION}; process the drive again"
        )
    try:
        with np.load(root / "points.npz", allow_pickle=False) as data:
            point_segment = data["segment"]
        with np.load(root / "segments.npz", allow_pickle=False) as data:
            segments = {name: data[name] for name in SEGMENT_FIELDS}
        timings = json.loads((root / "timings.json").read_text())
    except (OSError, KeyError, ValueError) as exc:
        raise RunFolderError(f"{root}: incomplete or damaged run folder ({exc})") from exc
    return Run(root, info, point_segment, segments, timings)
