"""Join the parts of the processing tiles into one run folder.

Segments get drive-wide numbers (tile by tile, in each tile's order), crops are renamed to
them, the points' segments are written per drive tile (``points/DDDDDD.npz``), and the
guardrail points of all tiles are gathered in drive order for the reconstruction, which merges
runs that cross tile edges (:func:`guardrail_core.reconstruct.pipeline.split_runs`).
"""

from __future__ import annotations

import json
import os
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.formats.run_folder import (
    POINT_UNPROCESSED,
    SEGMENT_FIELDS,
    crop_name,
    write_point_tile,
)
from guardrail_core.formats.run_info import CropCounts, RunCounts
from guardrail_core.process.tile_task import PART_FILE

#: Counts a part records, summed over the parts.
_COUNT_KEYS = (
    "points",
    "road_points",
    "off_road_points",
    "segment_points",
    "segments",
    "guardrail_segments_raw",
    "guardrail_segments",
    "guardrail_points",
)


@dataclass
class Stitched:
    """The joined run: its segment table, counts and timings, and what the reconstruction needs.

    Attributes
    ----------
    segments : SEGMENT_FIELDS arrays, S rows
    embeddings : (S, 1280) float16, or None
    counts : the run's counts (points of failed tiles are in ``points`` only)
    stages : per stage, seconds summed over the tiles and points
    guardrail_xyz : (G, 3) float64 guardrail points in drive order
    ground_xyz : (R, 3) float64 road points near them, in drive order
    """

    segments: dict[str, np.ndarray]
    embeddings: np.ndarray | None
    counts: RunCounts
    stages: dict[str, dict[str, float]]
    guardrail_xyz: np.ndarray
    ground_xyz: np.ndarray


def stitch_parts(staging: Path, parts: list[Path | None], tile_points: list[int]) -> Stitched:
    """Join ``parts`` (in tile order; None for a failed tile) into the run folder ``staging``.

    Parameters
    ----------
    staging : the run folder being written
    parts : each processing tile's part folder, None where the tile failed
    tile_points : points of each of the drive's point tiles; points no part covers (those of a
        failed tile) get ``POINT_UNPROCESSED``
    """
    staging = Path(staging)
    tables: list[dict[str, np.ndarray]] = []
    embeddings: list[np.ndarray] = []
    has_embeddings = True
    pieces: dict[int, list[tuple[Path, int]]] = defaultdict(list)
    totals: dict[str, int] = dict.fromkeys(_COUNT_KEYS, 0)
    crops = {"ok": 0, "no_image": 0, "too_small": 0, "asked": 0}
    stages: dict[str, dict[str, float]] = {}
    guardrail: list[tuple[np.ndarray, np.ndarray]] = []
    ground: list[tuple[np.ndarray, np.ndarray]] = []
    offset, component_offset = 0, 0
    (staging / "crops").mkdir(exist_ok=True)
    for part in parts:
        if part is None:
            continue
        record = json.loads((part / PART_FILE).read_text())
        counts = record["counts"]
        for key in _COUNT_KEYS:
            totals[key] += int(counts.get(key, 0))
        for key in crops:
            crops[key] += int(counts.get("crops", {}).get(key, 0))
        for name, entry in record["timings"]["stages"].items():
            total = stages.setdefault(name, {"seconds": 0.0, "points": 0})
            total["seconds"] = round(total["seconds"] + float(entry["seconds"]), 4)
            total["points"] += int(entry.get("points", 0))
        with np.load(part / "segments.npz", allow_pickle=False) as data:
            table = {name: data[name] for name in SEGMENT_FIELDS}
        n = len(table["n_points"])
        if n:
            table["component"] = table["component"] + component_offset
            component_offset = int(table["component"].max()) + 1
            tables.append(table)
            for crop in sorted((part / "crops").iterdir()):
                os.replace(crop, staging / crop_name(offset + int(crop.stem)))
            if (part / "embeddings.npy").is_file():
                embeddings.append(np.load(part / "embeddings.npy"))
            else:
                has_embeddings = False
        for piece in sorted((part / "points").glob("*.npz")):
            pieces[int(piece.stem)].append((piece, offset))
        with np.load(part / "guardrail.npz", allow_pickle=False) as data:
            guardrail.append((data["index"], data["xyz"]))
            ground.append((data["ground_index"], data["ground_xyz"]))
        offset += n

    for d, n_points in enumerate(tile_points):
        segment = np.full(n_points, POINT_UNPROCESSED, np.int32)
        for piece, first in pieces.get(d, []):
            with np.load(piece, allow_pickle=False) as data:
                local = data["segment"]
                segment[data["index"]] = np.where(local >= 0, local + first, local)
        write_point_tile(staging, d, segment)

    segments = _concatenate(tables)
    counts = RunCounts(
        points=sum(tile_points),
        road_points=totals["road_points"],
        off_road_points=totals["off_road_points"],
        segment_points=totals["segment_points"],
        segments=totals["segments"],
        crops=CropCounts(**crops),
        guardrail_segments_raw=totals["guardrail_segments_raw"],
        guardrail_segments=totals["guardrail_segments"],
        guardrail_points=totals["guardrail_points"],
    )
    return Stitched(
        segments=segments,
        # As for a whole drive: embeddings where a fast model embedded at least one crop.
        embeddings=np.concatenate(embeddings) if has_embeddings and crops["ok"] else None,
        counts=counts,
        stages=stages,
        guardrail_xyz=_in_drive_order(guardrail),
        ground_xyz=_in_drive_order(ground),
    )


def _in_drive_order(pieces: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """(K, 3) float64: points of all parts sorted by their drive-wide index."""
    if not pieces:
        return np.zeros((0, 3))
    index = np.concatenate([i for i, _ in pieces])
    xyz = np.concatenate([x for _, x in pieces]).reshape(-1, 3)
    return xyz[np.argsort(index, kind="stable")]


def _concatenate(tables: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    if not tables:
        out: dict[str, Any] = {}
        for name, (dtype, shape) in SEGMENT_FIELDS.items():
            out[name] = np.zeros((0, *(0 if s is None else s for s in shape)), dtype)
        return out
    return {name: np.concatenate([t[name] for t in tables]) for name in SEGMENT_FIELDS}
