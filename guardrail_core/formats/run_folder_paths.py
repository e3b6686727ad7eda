"""The run folder as an object: every path of it, and its reading with the format checks.

``RunFolder(path)`` names a folder and reads nothing (a staging folder being written is one too);
``RunFolder.open(path)`` also checks that it is a run folder of this format version. The library
and the app ask it for paths (``.point_tile_path(t)``, ``.reconstruction.mesh_path(run_id, "glb")``)
instead of building their own, so the layout and its checks live in one place
(:mod:`guardrail_core.formats.run_folder` writes it; docs/run-folder.md describes it).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.errors import NotARunFolderError, RunFolderError, RunFormatVersionError
from guardrail_core.formats.reconstruction_folder import (
    RECONSTRUCTION_DIR,
    ReconstructionFolder,
    read_versioned_json,
)
from guardrail_core.formats.run_folder import (
    EMBEDDINGS_FILE,
    POINTS_DIR,
    RUN_FILE,
    RUN_FORMAT_VERSION,
    SEGMENT_FIELDS,
    SEGMENTS_CSV,
    SEGMENTS_FILE,
    TIMINGS_FILE,
    Run,
    point_tile_name,
)
from guardrail_core.formats.run_info import RunInfo


@dataclass(frozen=True)
class RunFolder:
    """A run folder (``guardrail process``'s output) by its paths.

    Parameters
    ----------
    root : the folder; nothing is read until asked (see :meth:`open`)
    """

    root: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "root", Path(self.root))

    @classmethod
    def open(cls, root: str | Path) -> RunFolder:
        """The run folder at ``root``, checked: it has a ``run.json`` of this format version.

        Raises
        ------
        NotARunFolderError
            ``root`` has no ``run.json`` (or is no folder).
        RunFormatVersionError
            Its ``run.json`` was written by another format version.
        RunFolderError
            Its ``run.json`` is not valid JSON.
        """
        folder = cls(Path(root))
        folder.read_json()
        return folder

    # -- paths ------------------------------------------------------------------------------

    @property
    def run_file(self) -> Path:
        return self.root / RUN_FILE

    @property
    def points_dir(self) -> Path:
        return self.root / POINTS_DIR

    def point_tile_path(self, tile: int) -> Path:
        """``points/NNNNNN.npz``: the segments of the points of the drive's tile ``tile``."""
        return self.root / point_tile_name(int(tile))

    @property
    def segments_file(self) -> Path:
        return self.root / SEGMENTS_FILE

    @property
    def segments_csv(self) -> Path:
        return self.root / SEGMENTS_CSV

    @property
    def timings_file(self) -> Path:
        return self.root / TIMINGS_FILE

    @property
    def embeddings_file(self) -> Path:
        return self.root / EMBEDDINGS_FILE

    @property
    def reconstruction(self) -> ReconstructionFolder:
        """Its ``reconstruction/`` folder (which may not exist)."""
        return ReconstructionFolder(self.root / RECONSTRUCTION_DIR)

    def parts(self) -> list[Path]:
        """Every file and folder ``guardrail process`` writes here but ``reconstruction/``."""
        return [
            self.run_file,
            self.points_dir,
            self.segments_file,
            self.segments_csv,
            self.timings_file,
            self.embeddings_file,
        ]

    def exists(self) -> bool:
        """Whether the folder holds a ``run.json`` (its version is not checked)."""
        return self.run_file.is_file()

    # -- reading ----------------------------------------------------------------------------

    def read_json(self) -> dict[str, Any]:
        """``run.json`` as written, its format version checked (see :meth:`open`)."""
        if not self.exists():
            raise NotARunFolderError(
                f"{self.root}: not a run folder (no {RUN_FILE}); make one with "
                "`guardrail process DRIVE --model MODEL --out RUN_DIR`"
            )
        # One version only: 0.2.0, the first release, writes format 4; older folders came from
        # versions never released (docs/deprecation.md).
        return read_versioned_json(
            self.run_file,
            RUN_FORMAT_VERSION,
            lambda found: RunFormatVersionError(
                f"{self.run_file}: run format version {found!r}, this version of the tool "
                f"reads {RUN_FORMAT_VERSION} (written by guardrail 0.2.0 and later); process the "
                "drive again with `guardrail process DRIVE --model MODEL --out RUN_DIR`"
            ),
        )

    def info(self) -> RunInfo:
        """``run.json``, typed and checked (see :meth:`open`; a missing member is a
        :class:`~guardrail_core.errors.RunFolderError`)."""
        return RunInfo.from_json(self.read_json(), where=str(self.run_file))

    def point_segment_tile(self, tile: int) -> np.ndarray:
        """(n,) int32: the segment of every point of the drive's tile ``tile`` (-1 road surface,
        -2 far from the road, -3 not processed)."""
        path = self.point_tile_path(tile)
        try:
            with np.load(path, allow_pickle=False) as data:
                return np.asarray(data["segment"])
        except (OSError, KeyError, ValueError) as exc:
            raise RunFolderError(f"{path}: missing or damaged ({exc})") from exc

    def point_tiles(self) -> int:
        """How many point tiles the run holds (the drive's tiles)."""
        return int(self.read_json().get("drive", {}).get("tiles", 1))

    def point_segment(self) -> np.ndarray:
        """(N,) int32: the segment of every drive point, all tiles in order (-1 road surface,
        -2 far from the road, -3 not processed). A survey-scale run is read tile by tile
        instead (:meth:`point_segment_tile`)."""
        tiles = [self.point_segment_tile(t) for t in range(self.point_tiles())]
        return np.concatenate(tiles) if tiles else np.zeros(0, np.int32)

    def segments(self) -> dict[str, np.ndarray]:
        """Every ``SEGMENT_FIELDS`` array of ``segments.npz``, S rows each."""
        try:
            with np.load(self.segments_file, allow_pickle=False) as data:
                return {name: data[name] for name in SEGMENT_FIELDS}
        except (OSError, KeyError, ValueError) as exc:
            raise RunFolderError(f"{self.segments_file}: missing or damaged ({exc})") from exc

    def timings(self) -> dict[str, Any]:
        """``timings.json``: ``points_in``, ``stages`` (seconds and points each), ``total_seconds``."""
        try:
            return json.loads(self.timings_file.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise RunFolderError(f"{self.timings_file}: missing or damaged ({exc})") from exc

    def embeddings(self) -> np.ndarray | None:
        """(S, 1280) float16 backbone embeddings, or None when the run has none."""
        path = self.embeddings_file
        return np.load(path, allow_pickle=False) if path.is_file() else None

    def load(self) -> Run:
        """The run's tables in memory (its per-point segments when first asked for; not its
        embeddings and reconstruction).

        Raises
        ------
        RunFolderError
            As :meth:`open`, or a file is missing or damaged (the message names it).
        """
        info = self.info()
        return Run(self.root, info, self.segments(), self.timings())
