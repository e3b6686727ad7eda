"""Live threshold tuning: re-run one run's unit model from its superimposed points (§4.3-4.4).

The sliders of the 3D scene change a few reconstruction parameters; each change re-runs
:func:`guardrail_core.reconstruction.reconstruct_unit` on the points kept in
``reconstruction/superimposed.npz`` and rebuilds that run's mesh, without touching the run folder.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from guardrail_core.reconstruct.assemble import run_mesh
from guardrail_core.reconstruct.model import RunModel
from guardrail_core.reconstruction import (
    RECONSTRUCTION_DIR,
    ReconstructionParams,
    UnitReconstruction,
    load_reconstruction,
    reconstruct_unit,
)

#: The sliders: (stage, parameter) -> (label, min, max, step).
TUNABLE: dict[tuple[str, str], tuple[str, float, float, float]] = {
    ("pipes", "histogram_factor"): ("histogram threshold (x median)", 1.0, 6.0, 0.1),
    ("pipes", "radius_share"): ("share of points for the radius", 0.5, 1.0, 0.01),
    ("pipes", "slice_interval"): ("pipe slice interval (m)", 0.01, 0.1, 0.005),
    ("pipes", "taubin_iterations"): ("smoothing passes (Taubin)", 0, 40, 1),
    ("beams", "slice_interval"): ("beam slice interval (m)", 0.005, 0.05, 0.005),
}


def with_value(
    params: ReconstructionParams, stage: str, name: str, value: float
) -> ReconstructionParams:
    """``params`` with one parameter changed (an int parameter stays an int)."""
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
    run_root : the run folder (with ``reconstruction/``)
    """

    def __init__(self, run_root: Path) -> None:
        self.runs, data = load_reconstruction(run_root)
        self.params = ReconstructionParams.from_json(data["params"])
        self._npz = Path(run_root) / RECONSTRUCTION_DIR / "superimposed.npz"
        self._points: dict[int, np.ndarray] = {}

    def tunable_runs(self) -> list[RunModel]:
        """Runs with a unit model (and so superimposed points to re-run it from)."""
        return [r for r in self.runs if r.model is not None]

    def run(self, run_id: int) -> RunModel:
        for run in self.runs:
            if run.run_id == run_id:
                return run
        raise KeyError(f"no reconstructed run {run_id}")

    def points(self, run_id: int) -> np.ndarray:
        """(M, 3) float64 superimposed points of a run, unit coordinates."""
        if run_id not in self._points:
            with np.load(self._npz, allow_pickle=False) as data:
                self._points[run_id] = data[f"run_{run_id:03d}_points"].astype(np.float64)
        return self._points[run_id]

    def retune(self, run_id: int, params: ReconstructionParams) -> Retuned:
        """Re-run the unit model of a run with ``params`` and rebuild its mesh.

        Raises
        ------
        KeyError
            No run of that id has a unit model.
        ReconstructionError
            The parameters are out of range.
        """
        clock = time.perf_counter()
        run = self.run(run_id)
        if run.model is None:
            raise KeyError(f"run {run_id} has no unit model to re-run")
        unit = reconstruct_unit(
            self.points(run_id),
            run.model.length,
            pole_radius=run.model.pole_radius,
            pole_height=run.model.pole_height,
            n_units=run.model.n_units,
            params=params,
        )
        mesh = run_mesh(dataclasses.replace(run, model=unit.model), params.sweep)
        return Retuned(unit, mesh, time.perf_counter() - clock)
