"""Live threshold tuning: re-run one run's unit model from its superimposed points (§4.3-4.4).

The sliders of the 3D scene (:mod:`app.scene.tuning_panel`) and ``GET /api/runs/{id}/histogram``
change a few reconstruction parameters; each change re-runs
:func:`guardrail_core.reconstruct.pipeline.reconstruct_unit` on the points kept in
``reconstruction/superimposed.npz`` and rebuilds that run's mesh, without touching the run folder.
It imports no part of the viser scene.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.reconstruct.assemble import run_mesh
from guardrail_core.reconstruct.model import RunModel
from guardrail_core.reconstruct.pipeline import (
    ReconstructionParams,
    UnitReconstruction,
    reconstruct_unit,
)
from guardrail_core.reconstruct.run_models import load_run_models


def _sliders() -> dict[tuple[str, str], tuple[str, float, float, float]]:
    """The reconstruction's parameters that declare a :class:`~guardrail_core.params.Slider`,
    in the order the stages run: (stage, parameter) -> (label, min, max, step)."""
    return {
        (stage, spec.name): (spec.slider.label, spec.slider.low, spec.slider.high, spec.slider.step)
        for stage, kind in ReconstructionParams.stage_classes().items()
        for spec in kind.specs()
        if spec.slider is not None
    }


#: The tuning panel's sliders, from the parameters' own declarations.
TUNABLE = _sliders()


def slider_value(key: tuple[str, str], value: object, default: float) -> float:
    """A slider's value as the reconstruction takes it: within the slider's own range. A scene
    client sends what it likes (a slider at 0.5 whose maximum is 0.1), so the value is clamped
    to the range, and one that is not a finite number gives ``default``."""
    _, lo, hi, _ = TUNABLE[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return default
    return min(max(float(value), lo), hi)


def with_value(
    params: ReconstructionParams, stage: str, name: str, value: float
) -> ReconstructionParams:
    """``params`` with one parameter changed (an int parameter stays an int).

    Raises :class:`~guardrail_core.params.ParameterError` for a value outside its range.
    """
    part = getattr(params, stage)
    kind = type(getattr(part, name))
    return dataclasses.replace(params, **{stage: dataclasses.replace(part, **{name: kind(value)})})


@dataclass(frozen=True)
class Retuned:
    """One re-run: the unit, the run's new mesh (local frame, metres) and the time it took."""

    unit: UnitReconstruction
    mesh: trimesh.Trimesh
    seconds: float


class RunTuner:
    """The reconstructed runs of a run folder and their superimposed points.

    Parameters
    ----------
    run : the run folder (with ``reconstruction/``), or its path

    Raises
    ------
    RunFolderError
        The run has no reconstruction, or one this version cannot read
        (:func:`guardrail_core.reconstruct.run_models.load_run_models`).
    """

    def __init__(self, run: RunFolder | str | os.PathLike) -> None:
        self._models = load_run_models(run if isinstance(run, RunFolder) else RunFolder(Path(run)))
        self.runs = list(self._models.runs)
        self.params = self._models.params
        self._points: dict[int, np.ndarray] = {}
        self._units: dict[int, np.ndarray] = {}

    def tunable_runs(self) -> list[RunModel]:
        """Runs with a unit model (and so superimposed points to re-run it from)."""
        return [r for r in self.runs if r.model is not None]

    def run(self, run_id: int) -> RunModel:
        """The model of run ``run_id``; KeyError where none was reconstructed."""
        return self._models.run(run_id)

    def points(self, run_id: int) -> np.ndarray:
        """(M, 3) float64 superimposed points of a run, unit coordinates."""
        if run_id not in self._points:
            self._points[run_id] = self._models.superimposed_points(run_id)
        return self._points[run_id]

    def units(self, run_id: int) -> np.ndarray:
        """(M,) the unit each of those points came from."""
        if run_id not in self._units:
            self._units[run_id] = self._models.superimposed_units(run_id)
        return self._units[run_id]

    def retune(self, run_id: int, params: ReconstructionParams) -> Retuned:
        """Re-run the unit model of a run with ``params`` and rebuild its mesh.

        Raises
        ------
        KeyError
            No run of that id has a unit model.
        ReconstructionError
            The unit model cannot be re-run from these points (parameters out of range are
            refused earlier, when they are made: :class:`~guardrail_core.params.ParameterError`).
        """
        clock = time.perf_counter()
        unit = self.unit(run_id, params)
        return Retuned(unit, self.mesh(run_id, unit, params), time.perf_counter() - clock)

    def mesh(
        self, run_id: int, unit: UnitReconstruction, params: ReconstructionParams
    ) -> trimesh.Trimesh:
        """The mesh of run ``run_id`` with ``unit``'s model (:meth:`unit`) copied along it."""
        return run_mesh(dataclasses.replace(self.run(run_id), model=unit.model), params.sweep)

    def unit(self, run_id: int, params: ReconstructionParams) -> UnitReconstruction:
        """The unit model of a run re-run with ``params``, and its x histogram (pipes); the
        errors of :meth:`retune`."""
        run = self.run(run_id)
        if run.model is None:
            raise KeyError(f"run {run_id} has no unit model to re-run")
        return reconstruct_unit(
            self.points(run_id),
            run.model.length,
            pole_radius=run.model.pole_radius,
            pole_height=run.model.pole_height,
            n_units=run.model.n_units,
            params=params,
            unit_of_point=self.units(run_id),
        )


def unit_numbers(run_id: int, unit: UnitReconstruction, params: ReconstructionParams) -> dict:
    """The numbers behind a run's unit-model thresholds (§4.3, Fig. 14), as
    ``GET /api/runs/{run_id}/histogram`` sends them and the tuning panel plots them: the x
    histogram's bin centres, counts and threshold with the pipes found (pipes), or the section
    curve (beams)."""
    histogram = unit.histogram
    model = unit.model
    return {
        "run_id": run_id,
        "type": model.type,
        "histogram_factor": params.pipes.histogram_factor,
        "bin_m": params.pipes.histogram_bin_m,
        "x_m": None
        if histogram is None
        else (0.5 * (histogram.edges[:-1] + histogram.edges[1:])).tolist(),
        "counts": None if histogram is None else histogram.counts.astype(int).tolist(),
        "threshold": None if histogram is None else float(histogram.threshold),
        "pipes": [
            {
                "kind": pipe.kind,
                "x_min_m": float(np.min(pipe.axis[:, 0])),
                "x_max_m": float(np.max(pipe.axis[:, 0])),
                "radius_m": float(pipe.radius),
            }
            for pipe in model.pipes
        ],
        "section": None if model.section is None else np.asarray(model.section).tolist(),
    }
