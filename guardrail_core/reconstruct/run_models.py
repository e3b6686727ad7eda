"""A run folder's saved reconstruction read back: the run models and the parameters they came from.

The files and the format check are :class:`guardrail_core.formats.reconstruction_folder.ReconstructionFolder`'s;
this module turns the checked ``models.json`` into :class:`~guardrail_core.reconstruct.model.RunModel`
and :class:`~guardrail_core.reconstruct.pipeline.ReconstructionParams`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from guardrail_core.errors import InvalidOptionError, RunFolderError
from guardrail_core.formats.reconstruction_folder import ReconstructionFolder
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.reconstruct.model import RunModel
from guardrail_core.reconstruct.model_json import run_model_from_json
from guardrail_core.reconstruct.pipeline import ReconstructionParams


@dataclass(frozen=True)
class RunModels:
    """A saved reconstruction (``reconstruction/models.json``), checked and parsed.

    Attributes
    ----------
    runs : one model per run of guardrail points, in run id order
    params : the parameters it was made with
    seconds : wall time it took, None where not measured
    folder : the ``reconstruction/`` folder it was read from (meshes, superimposed points)
    """

    runs: tuple[RunModel, ...]
    params: ReconstructionParams
    seconds: float | None
    folder: ReconstructionFolder

    def run(self, run_id: int) -> RunModel:
        """The model of run ``run_id``.

        Raises
        ------
        KeyError
            No run of that id was reconstructed.
        """
        for run in self.runs:
            if run.run_id == run_id:
                return run
        raise KeyError(f"no reconstructed run {run_id}")

    def superimposed_points(self, run_id: int) -> np.ndarray:
        """(M, 3) float64: a run's superimposed unit points, unit coordinates (metres)."""
        return self.folder.superimposed_points(run_id)

    def superimposed_units(self, run_id: int) -> np.ndarray:
        """(M,) int64: the unit each of those points came from."""
        return self.folder.superimposed_units(run_id)


def load_run_models(run: str | Path | RunFolder) -> RunModels:
    """The reconstruction of a run folder.

    Parameters
    ----------
    run : the run folder (its path or its :class:`RunFolder`)

    Raises
    ------
    NoReconstructionError
        The run folder has no ``reconstruction/models.json``.
    ReconstructionFormatVersionError
        It was written by another format version.
    RunFolderError
        It is damaged: not JSON, a run or a parameter this version cannot read.
    """
    folder = (
        run.reconstruction if isinstance(run, RunFolder) else RunFolder(Path(run)).reconstruction
    )
    document = folder.read_models()
    where = str(document.path)
    runs = tuple(run_model_from_json(r, where=where) for r in document.runs)
    try:
        params = ReconstructionParams.from_json(document.params)
    except InvalidOptionError as exc:
        raise RunFolderError(f"{where}: parameters this version cannot read ({exc})") from exc
    return RunModels(runs=runs, params=params, seconds=document.seconds, folder=folder)
