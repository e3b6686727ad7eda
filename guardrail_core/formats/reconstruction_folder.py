"""A run folder's ``reconstruction/``: every file's name and the format check of ``models.json``.

::

    RUN_DIR/reconstruction/
      models.json         format version, parameters, seconds, every run's poles, units and model
      superimposed.npz    run_NNN_points (M, 3) float32 and run_NNN_unit (M,) int16 per run
      inventory.geojson   one LineString per run along its poles
      inventory.csv       the same rows for spreadsheets
      meshes/run_NNN.{glb,ply,obj}, meshes/guardrails.glb

The reading side lives here (the library and the app build no path of their own); the run models
themselves are parsed by :func:`guardrail_core.reconstruct.run_models.load_run_models`.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.errors import (
    GuardrailError,
    InvalidOptionError,
    NoReconstructionError,
    ReconstructionFormatVersionError,
    RunFolderError,
)
from guardrail_core.io.meshes import MESH_FORMATS, SCENE_FILE, run_file_stem

RECONSTRUCTION_DIR = "reconstruction"
RECONSTRUCTION_FORMAT_VERSION = 1
MODELS_FILE = "models.json"
SUPERIMPOSED_FILE = "superimposed.npz"
INVENTORY_GEOJSON = "inventory.geojson"
INVENTORY_CSV = "inventory.csv"
MESHES_DIR = "meshes"


def superimposed_points_key(run_id: int) -> str:
    """``run_NNN_points``: a run's superimposed unit points in ``superimposed.npz``."""
    return f"{run_file_stem(run_id)}_points"


def superimposed_unit_key(run_id: int) -> str:
    """``run_NNN_unit``: the unit each superimposed point came from, in ``superimposed.npz``."""
    return f"{run_file_stem(run_id)}_unit"


@dataclass(frozen=True)
class ModelsDocument:
    """``models.json``, its format version checked; the runs still as JSON (see
    :func:`guardrail_core.reconstruct.model_json.run_model_from_json`).

    Attributes
    ----------
    path : the file it was read from
    params : every reconstruction parameter by stage (``ReconstructionParams.to_json()``)
    seconds : wall time of the reconstruction, None where not measured
    runs : one JSON object per reconstructed run, in run id order
    """

    path: Path
    params: dict[str, Any]
    seconds: float | None
    runs: list[dict[str, Any]]


@dataclass(frozen=True)
class ReconstructionFolder:
    """The ``reconstruction/`` folder of a run (or its staging folder while it is written).

    Constructing one reads nothing; :meth:`read_models` checks the format.
    """

    root: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "root", Path(self.root))

    @property
    def models_file(self) -> Path:
        return self.root / MODELS_FILE

    @property
    def superimposed_file(self) -> Path:
        return self.root / SUPERIMPOSED_FILE

    @property
    def inventory_geojson(self) -> Path:
        return self.root / INVENTORY_GEOJSON

    @property
    def inventory_csv(self) -> Path:
        return self.root / INVENTORY_CSV

    @property
    def meshes_dir(self) -> Path:
        return self.root / MESHES_DIR

    @property
    def scene_file(self) -> Path:
        """``meshes/guardrails.glb``: every run in one glTF scene, a node per run."""
        return self.meshes_dir / SCENE_FILE

    def exists(self) -> bool:
        """Whether a reconstruction was written (its ``models.json`` is there)."""
        return self.models_file.is_file()

    def mesh_path(self, run_id: int, fmt: str = "glb") -> Path:
        """``meshes/run_NNN.<fmt>``: one run's mesh (it may not exist: runs without poles have none).

        Raises
        ------
        InvalidOptionError
            ``fmt`` is not one of ``glb``, ``ply``, ``obj``.
        """
        if fmt not in MESH_FORMATS:
            raise InvalidOptionError(f"mesh format: expected one of {MESH_FORMATS}, got {fmt!r}")
        return self.meshes_dir / f"{run_file_stem(run_id)}.{fmt}"

    def mesh_files(self, fmt: str = "glb") -> dict[int, Path]:
        """{run id: path} of every run mesh of that format present, by run id."""
        self.mesh_path(0, fmt)  # refuses an unknown format
        pattern = re.compile(rf"run_(\d+)\.{fmt}")  # the names run_file_stem gives
        found: dict[int, Path] = {}
        if self.meshes_dir.is_dir():
            for path in self.meshes_dir.iterdir():
                match = pattern.fullmatch(path.name)
                if match and path.is_file():
                    found[int(match[1])] = path
        return dict(sorted(found.items()))

    def output_files(self) -> dict[str, Path]:
        """{name relative to ``reconstruction/`` (POSIX): path} of the inventory and the meshes,
        the files made for people and other tools (``models.json`` and ``superimposed.npz`` are
        the tool's own), sorted by name."""
        files: dict[str, Path] = {}
        for path in (self.inventory_geojson, self.inventory_csv):
            if path.is_file():
                files[path.name] = path
        if self.meshes_dir.is_dir():
            for path in self.meshes_dir.iterdir():
                if path.is_file() and not path.name.startswith("."):
                    files[f"{MESHES_DIR}/{path.name}"] = path
        return dict(sorted(files.items()))

    def read_models(self) -> ModelsDocument:
        """``models.json``, its format version checked.

        Raises
        ------
        NoReconstructionError
            There is no ``models.json``.
        ReconstructionFormatVersionError
            It was written by another format version.
        RunFolderError
            It is not valid JSON or lacks ``params`` or ``runs``.
        """
        path = self.models_file
        if not path.is_file():
            raise NoReconstructionError(
                f"{self.root.parent}: no reconstruction (no {RECONSTRUCTION_DIR}/{MODELS_FILE}); "
                "run `guardrail reconstruct RUN_DIR`"
            )
        data = read_versioned_json(
            path,
            RECONSTRUCTION_FORMAT_VERSION,
            lambda found: ReconstructionFormatVersionError(
                f"{path}: reconstruction format {found!r}, this version reads "
                f"{RECONSTRUCTION_FORMAT_VERSION}; run `guardrail reconstruct` again"
            ),
        )
        params, runs, seconds = data.get("params"), data.get("runs"), data.get("seconds")
        if not isinstance(params, dict) or not isinstance(runs, list):
            raise RunFolderError(f"{path}: expected a 'params' object and a 'runs' list")
        return ModelsDocument(
            path=path,
            params=params,
            seconds=None if seconds is None else float(seconds),
            runs=runs,
        )

    def superimposed_points(self, run_id: int) -> np.ndarray:
        """(M, 3) float64: a run's superimposed unit points, unit coordinates (metres).

        Raises
        ------
        RunFolderError
            ``superimposed.npz`` is missing or holds no points of that run.
        """
        return self._superimposed(superimposed_points_key(run_id), np.float64, "points", run_id)

    def superimposed_units(self, run_id: int) -> np.ndarray:
        """(M,) int64: the unit each of a run's superimposed points came from.

        Raises
        ------
        RunFolderError
            ``superimposed.npz`` is missing or holds no units of that run.
        """
        return self._superimposed(superimposed_unit_key(run_id), np.int64, "units", run_id)

    def _superimposed(self, key: str, dtype: type, what: str, run_id: int) -> np.ndarray:
        """The array ``key`` of ``superimposed.npz`` as ``dtype``; the errors named above."""
        try:
            with np.load(self.superimposed_file, allow_pickle=False) as data:
                return np.asarray(data[key], dtype)
        except (OSError, KeyError, ValueError) as exc:
            raise RunFolderError(
                f"{self.superimposed_file}: no superimposed {what} of run {run_id} ({exc})"
            ) from exc


def read_versioned_json(
    path: Path, version: int, mismatch: Callable[[Any], GuardrailError]
) -> dict[str, Any]:
    """The JSON object in ``path``, whose ``format_version`` must be ``version``.

    Raises
    ------
    RunFolderError
        The file is not valid JSON.
    GuardrailError
        ``mismatch(found_version)``: the version is another (or absent, or not an object).
    """
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise RunFolderError(f"{path}: not valid JSON ({exc})") from exc
    found = data.get("format_version") if isinstance(data, dict) else None
    # type() too: True == 1 and 3.0 == 3, but neither is a format version.
    if type(found) is not int or found != version:
        raise mismatch(found)
    return data
