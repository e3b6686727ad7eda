"""Join the parts of the processing tiles into one run folder, as the tiles end.

Segments get drive-wide numbers (tile by tile, in each tile's order), the points' segments are
written per drive tile (``points/DDDDDD.npz``) and the crops' embeddings are appended to the
run's ``embeddings.npy`` as each part is joined, so that this process holds neither (a 3 km
drive has 165 MB of embeddings; a survey day some GB). Each part's guardrail points go to the
reconstruction's :class:`~.run_stream.RunStream` as it is joined (:meth:`PartStitcher.add`
says which parts were).
"""

from __future__ import annotations

import json
import shutil
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.formats.run_folder import (
    POINT_UNPROCESSED,
    SEGMENT_FIELDS,
    write_point_tile,
)
from guardrail_core.formats.run_folder_paths import RunFolder
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


#: Where the embeddings' rows gather before their count, and so ``embeddings.npy``'s header, is
#: known (in the staging folder; gone when the stitcher finishes).
_EMBEDDING_ROWS = ".embeddings.rows"


@dataclass
class Stitched:
    """The joined run: its segment table, counts and timings (its point tiles and embeddings are
    in the staging folder).

    Attributes
    ----------
    segments : SEGMENT_FIELDS arrays, S rows
    counts : the run's counts (points of failed tiles are in ``points`` only)
    stages : per stage, seconds summed over the tiles and points
    """

    segments: dict[str, np.ndarray]
    counts: RunCounts
    stages: dict[str, dict[str, float]]


class PartStitcher:
    """Joins the parts into the run folder as their tiles end, in any order: each part is
    joined once the parts before it are, and each drive tile's points are written as soon as
    every part that may own some of them is joined (so the work overlaps the tiles still
    running, and the pieces of a written drive tile are let go).

    Parameters
    ----------
    staging : the run folder being written
    tile_points : points of each of the drive's point tiles
    n_parts : the processing tiles
    reads : per processing tile, the drive tiles its window reads (the only ones it can own
        points of); None: any, so the points are written by :meth:`finish`
    """

    def __init__(
        self,
        staging: Path,
        tile_points: list[int],
        n_parts: int,
        reads: list[list[int]] | None = None,
    ) -> None:
        self.staging = Path(staging)
        self.tile_points = list(tile_points)
        self.reads = reads
        self._arrived: dict[int, Path | None] = {}
        self._next = 0
        self._n_parts = n_parts
        # Parts still to be joined that may own points of each drive tile.
        self._waiting = [0] * len(tile_points)
        for tiles in reads or []:
            for d in tiles:
                self._waiting[d] += 1
        self._written = [False] * len(tile_points)
        self._tables: list[dict[str, np.ndarray]] = []
        self._embedding_rows = self.staging / _EMBEDDING_ROWS
        self._embedding_width: int | None = None
        self._has_embeddings = True
        self._pieces: dict[int, list[tuple[Path, int]]] = defaultdict(list)
        self._totals: dict[str, int] = dict.fromkeys(_COUNT_KEYS, 0)
        self._crops = {"ok": 0, "no_image": 0, "too_small": 0, "asked": 0}
        self._stages: dict[str, dict[str, float]] = {}
        self._offset = 0
        self._component_offset = 0

    @property
    def joined(self) -> int:
        """Parts joined so far: parts 0 .. ``joined`` - 1."""
        return self._next

    def add(self, k: int, part: Path | None) -> list[Path]:
        """Part ``k`` has ended (None: it failed); join what can be joined, and return the
        parts joined now, in order (those that did not fail)."""
        self._arrived[k] = part
        done = []
        while self._next in self._arrived:
            joined = self._arrived.pop(self._next)
            if joined is not None:
                self._join(joined)
                done.append(joined)
            if self.reads is not None:
                for d in self.reads[self._next]:
                    self._waiting[d] -= 1
                    if self._waiting[d] == 0:
                        self._write_points(d)
            self._next += 1
        return done

    def finish(self) -> Stitched:
        """The joined run, once every part has been added."""
        if self._next != self._n_parts:
            raise ValueError(f"stitching: {self._n_parts - self._next} parts have not ended")
        for d in range(len(self.tile_points)):
            if not self._written[d]:
                self._write_points(d)
        totals, crops = self._totals, self._crops
        counts = RunCounts(
            points=sum(self.tile_points),
            road_points=totals["road_points"],
            off_road_points=totals["off_road_points"],
            segment_points=totals["segment_points"],
            segments=totals["segments"],
            crops=CropCounts(**crops),
            guardrail_segments_raw=totals["guardrail_segments_raw"],
            guardrail_segments=totals["guardrail_segments"],
            guardrail_points=totals["guardrail_points"],
        )
        # As for a whole drive: embeddings where a fast model embedded at least one crop.
        if self._has_embeddings and crops["ok"] and self._embedding_width is not None:
            self._write_embeddings(totals["segments"], self._embedding_width)
        self._embedding_rows.unlink(missing_ok=True)
        return Stitched(
            segments=_concatenate(self._tables),
            counts=counts,
            stages=self._stages,
        )

    def _join(self, part: Path) -> None:
        record = json.loads((part / PART_FILE).read_text())
        counts = record["counts"]
        for key in _COUNT_KEYS:
            self._totals[key] += int(counts.get(key, 0))
        for key in self._crops:
            self._crops[key] += int(counts.get("crops", {}).get(key, 0))
        for name, entry in record["timings"]["stages"].items():
            total = self._stages.setdefault(name, {"seconds": 0.0, "points": 0})
            total["seconds"] = round(total["seconds"] + float(entry["seconds"]), 4)
            total["points"] += int(entry.get("points", 0))
        with np.load(part / "segments.npz", allow_pickle=False) as data:
            table = {name: data[name] for name in SEGMENT_FIELDS}
        n = len(table["n_points"])
        if n:
            table["component"] = table["component"] + self._component_offset
            self._component_offset = int(table["component"].max()) + 1
            self._tables.append(table)
            if (part / "embeddings.npy").is_file():
                if self._has_embeddings:
                    self._add_embeddings(np.load(part / "embeddings.npy"), n)
            else:
                self._has_embeddings = False
        for piece in sorted((part / "points").glob("*.npz")):
            self._pieces[int(piece.stem)].append((piece, self._offset))
        self._offset += n

    def _add_embeddings(self, rows: np.ndarray, n: int) -> None:
        """Append a part's (n, E) embeddings to the rows gathered so far."""
        width = self._embedding_width if self._embedding_width is not None else rows.shape[-1]
        if rows.shape != (n, width):
            raise ValueError(
                f"stitching: a part's embeddings are {rows.shape}, expected {(n, width)}"
            )
        self._embedding_width = width
        with open(self._embedding_rows, "ab") as out:
            out.write(np.ascontiguousarray(rows, np.float16).tobytes())

    def _write_embeddings(self, n: int, width: int) -> None:
        """``embeddings.npy``, (n, width) float16: the header ``np.save`` writes, then the rows
        gathered, copied as they are."""
        header: dict[str, Any] = {
            "descr": np.lib.format.dtype_to_descr(np.dtype(np.float16)),
            "fortran_order": False,
            "shape": (n, width),
        }
        with (
            open(RunFolder(self.staging).embeddings_file, "wb") as out,
            open(self._embedding_rows, "rb") as rows,
        ):
            np.lib.format.write_array_header_1_0(out, header)
            shutil.copyfileobj(rows, out)

    def _write_points(self, d: int) -> None:
        """Drive tile ``d``'s point segments from the pieces of the parts (drive-wide segment
        numbers; ``POINT_UNPROCESSED`` where no part owned a point)."""
        segment = np.full(self.tile_points[d], POINT_UNPROCESSED, np.int32)
        for piece, first in self._pieces.pop(d, []):
            with np.load(piece, allow_pickle=False) as data:
                local = data["segment"]
                segment[data["index"]] = np.where(local >= 0, local + first, local)
        write_point_tile(self.staging, d, segment)
        self._written[d] = True


def _concatenate(tables: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    if not tables:
        out: dict[str, Any] = {}
        for name, (dtype, shape) in SEGMENT_FIELDS.items():
            out[name] = np.zeros((0, *(0 if s is None else s for s in shape)), dtype)
        return out
    return {name: np.concatenate([t[name] for t in tables]) for name in SEGMENT_FIELDS}
