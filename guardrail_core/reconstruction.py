"""Runs the reconstruction stages (§4) on a drive's guardrail points and writes the results.

guardrail points -> runs -> poles (§4.1) -> units (§4.1) -> superimposition with ICP (§4.2)
-> pipes (§4.3) or beam section (§4.4) -> the unit copied between the poles -> meshes + inventory.

What it writes into a run folder::

    RUN_DIR/reconstruction/
      models.json         format version, parameters, every run: poles, unit frames, unit model
      superimposed.npz    per run the superimposed unit points (unit coordinates), for re-runs
      inventory.geojson   one LineString per run along its poles, properties = the inventory row
      inventory.csv       the same rows for spreadsheets
      meshes/run_NNN.{glb,ply,obj}, meshes/guardrails.glb
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree
from tqdm import tqdm

from guardrail_core.errors import InvalidOptionError, ReconstructionError, RunFolderError
from guardrail_core.io.meshes import write_meshes
from guardrail_core.reconstruct.assemble import run_mesh
from guardrail_core.reconstruct.beams import BeamParams, reconstruct_beam, unit_type
from guardrail_core.reconstruct.inventory import (
    inventory_rows,
    write_inventory_csv,
    write_inventory_geojson,
)
from guardrail_core.reconstruct.model import RunModel, UnitModel
from guardrail_core.reconstruct.model_json import run_model_from_json, run_model_to_json
from guardrail_core.reconstruct.pipes import PipeHistogram, PipeParams, reconstruct_pipes
from guardrail_core.reconstruct.poles import PoleParams, detect_poles
from guardrail_core.reconstruct.register import RegisterParams, Superimposition, superimpose
from guardrail_core.reconstruct.runs import RunParams, group_runs
from guardrail_core.reconstruct.sweep import SweepParams
from guardrail_core.reconstruct.units import UnitParams, order_poles, split_units

RECONSTRUCTION_DIR = "reconstruction"
RECONSTRUCTION_FORMAT_VERSION = 1
#: Ground points farther than this (m, horizontally) from every point of a run are not its ground.
GROUND_REACH_M = 1.0


@dataclass(frozen=True)
class ReconstructionParams:
    """The parameters of every reconstruction stage, each with the paper's defaults."""

    runs: RunParams = field(default_factory=RunParams)
    poles: PoleParams = field(default_factory=PoleParams)
    units: UnitParams = field(default_factory=UnitParams)
    register: RegisterParams = field(default_factory=RegisterParams)
    pipes: PipeParams = field(default_factory=PipeParams)
    beams: BeamParams = field(default_factory=BeamParams)
    sweep: SweepParams = field(default_factory=SweepParams)

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> ReconstructionParams:
        """Parameters from :meth:`to_json` output; missing keys keep their defaults.

        Raises
        ------
        InvalidOptionError
            An unknown stage or parameter, or a value the stage refuses.
        """
        stages = {f.name: f for f in dataclasses.fields(cls)}
        parts = {}
        for stage, values in data.items():
            if stage not in stages:
                raise InvalidOptionError(
                    f"unknown reconstruction stage {stage!r} (known: {', '.join(stages)})"
                )
            stage_cls = type(getattr(cls(), stage))
            names = {f.name for f in dataclasses.fields(stage_cls)}
            unknown = sorted(set(values) - names)
            if unknown:
                raise InvalidOptionError(
                    f"unknown parameter {stage}.{unknown[0]} (known: {', '.join(sorted(names))})"
                )
            defaults = dataclasses.asdict(stage_cls())
            values = {  # JSON has lists where the parameters have tuples (colours)
                k: tuple(v) if isinstance(defaults[k], tuple) and isinstance(v, list) else v
                for k, v in values.items()
            }
            try:
                parts[stage] = stage_cls(**values)
            except (TypeError, ValueError, ReconstructionError) as exc:
                raise InvalidOptionError(f"{stage}: {exc}") from exc
        return cls(**parts)

    def with_settings(self, settings: list[str]) -> ReconstructionParams:
        """These parameters with ``stage.name=value`` settings applied (the CLI's ``--set``)."""
        data = self.to_json()
        for setting in settings:
            key, sep, value = setting.partition("=")
            stage, dot, name = key.strip().partition(".")
            if not sep or not dot:
                raise InvalidOptionError(f"expected STAGE.NAME=VALUE, got {setting!r}")
            if stage not in data or name not in data[stage]:
                raise InvalidOptionError(f"unknown reconstruction parameter {key!r}")
            try:
                data[stage][name] = type(data[stage][name])(json.loads(value))
            except (ValueError, TypeError) as exc:
                raise InvalidOptionError(f"{key}: {value!r} is not a valid value") from exc
        return ReconstructionParams.from_json(data)


@dataclass
class Reconstruction:
    """Every reconstructed run of a drive, with what re-running a unit model needs.

    Attributes
    ----------
    runs : one model per run of guardrail points, in run id order
    superimposed : per run, the superimposed unit points (None where there were no units)
    """

    runs: list[RunModel]
    superimposed: list[Superimposition | None]


@dataclass(frozen=True)
class UnitReconstruction:
    """A unit model and, for pipes, the x histogram its vertical pipes came from (Fig. 14)."""

    model: UnitModel
    histogram: PipeHistogram | None


def reconstruct_unit(
    points: np.ndarray,
    length: float,
    *,
    pole_radius: float,
    pole_height: float,
    n_units: int,
    params: ReconstructionParams = ReconstructionParams(),
) -> UnitReconstruction:
    """The unit model of superimposed unit points: beam section or pipes (§4.3-4.4).

    This is the step the review app re-runs when an operator moves a threshold.

    Parameters
    ----------
    points : (N, 3) float64, unit coordinates (metres), pole points removed
    length : float, metres between the pole axes
    """
    kind = unit_type(points, length, params.beams)
    if kind == "beam":
        beam = reconstruct_beam(points, length, pole_radius, params.beams)
        model = UnitModel(
            type="beam",
            length=length,
            section=beam.section,
            pole_radius=pole_radius,
            pole_height=pole_height,
            n_units=n_units,
            notes=tuple(beam.notes),
        )
        return UnitReconstruction(model, None)
    pipes = reconstruct_pipes(points, length, pole_radius, params.pipes)
    model = UnitModel(
        type="pipe",
        length=length,
        pipes=tuple(pipes.pipes),
        pole_radius=pole_radius,
        pole_height=pole_height,
        n_units=n_units,
        notes=tuple(pipes.notes),
    )
    return UnitReconstruction(model, pipes.histogram)


def unit_model(
    points: np.ndarray,
    length: float,
    *,
    pole_radius: float,
    pole_height: float,
    n_units: int,
    params: ReconstructionParams = ReconstructionParams(),
) -> UnitModel:
    """The unit model alone (see :func:`reconstruct_unit`)."""
    return reconstruct_unit(
        points,
        length,
        pole_radius=pole_radius,
        pole_height=pole_height,
        n_units=n_units,
        params=params,
    ).model


def reconstruct_run(
    xyz: np.ndarray,
    ground: np.ndarray,
    toward_road: np.ndarray,
    *,
    run_id: int,
    params: ReconstructionParams = ReconstructionParams(),
    max_units: int | None = None,
) -> tuple[RunModel, Superimposition | None]:
    """Reconstruct one run of guardrail points.

    Parameters
    ----------
    xyz : (N, 3) float64, metres: the run's guardrail points, local frame
    ground : (G, 3) float64: ground points near the run (for the poles' foot)
    toward_road : (3,) horizontal direction from the run toward the road
    run_id : the run's number
    max_units : superimpose only the first this many units (the experiment of §5.2)

    Returns
    -------
    The run model (whose ``notes`` say what could not be done) and the superimposition.
    """
    detection = detect_poles(xyz, ground, params.poles)
    notes: list[str] = []
    if len(detection.poles) < 2:
        notes.append(
            f"{len(detection.poles)} pole(s) detected: a unit needs two, so no unit shape "
            "was reconstructed"
        )
        return RunModel(
            run_id, list(detection.poles), [], None, np.zeros(0, bool), len(xyz), notes
        ), None
    poles = order_poles(detection.poles, toward_road)
    # Pole points belong to the poles, not to the unit shape between them.
    rails = xyz[~detection.point_is_pole]
    split = split_units(rails, poles, params.units)
    notes.extend(split.notes)
    poles, frames = split.poles, split.frames  # with virtual poles where one was missing
    unit_points = [frames[u].to_unit(rails[split.unit_of_point == u]) for u in range(len(frames))]
    unit_points = [p[p[:, 1] >= params.units.ground_clearance_m] for p in unit_points]
    # Units beyond the detected end poles take the model but do not shape it: their x is
    # only extrapolated (unless no unit is anchored at all).
    chosen = np.flatnonzero(split.anchored) if split.anchored.any() else np.arange(len(frames))
    if max_units is not None:
        chosen = chosen[:max_units]
    used = [unit_points[u] for u in chosen]
    length = float(np.median([f.length for f in frames]))
    stacked = np.concatenate(used)
    beam = len(used) > 1 and len(stacked) > 0 and unit_type(stacked, length, params.beams) == "beam"
    superimposed = superimpose(used, params.register, beam=beam)
    superimposed = dataclasses.replace(
        superimposed, unit_of_point=chosen[superimposed.unit_of_point].astype(np.int32)
    )
    unregistered = int((~superimposed.registered).sum())
    if unregistered and len(used) > 1:
        notes.append(f"{unregistered} of {len(used)} units kept their rough alignment (ICP failed)")
    if len(used) == 1:
        notes.append("a run of one unit: the model rests on a single unit's points")
    registered = np.zeros(len(frames), bool)
    registered[chosen] = superimposed.registered
    if len(superimposed.points) == 0:
        notes.append("no guardrail points between the poles")
        return RunModel(run_id, poles, frames, None, registered, len(xyz), notes), superimposed
    model = unit_model(
        superimposed.points,
        length,
        pole_radius=float(np.median([p.radius for p in poles])),
        pole_height=float(np.median([p.height for p in poles])),
        n_units=len(used),
        params=params,
    )
    return RunModel(run_id, poles, frames, model, registered, len(xyz), notes), superimposed


def reconstruct_guardrails(
    xyz: np.ndarray,
    guardrail: np.ndarray,
    ground: np.ndarray,
    trajectory: np.ndarray,
    *,
    params: ReconstructionParams = ReconstructionParams(),
    max_units: int | None = None,
    progress: bool = False,
) -> Reconstruction:
    """Reconstruct every guardrail run of a drive.

    Parameters
    ----------
    xyz : (N, 3) float64, metres: every point of the drive, local frame
    guardrail : (N,) bool: the points labelled guardrail
    ground : (N,) bool: the points of the road surface (the ground of the poles)
    trajectory : (T, 3) float64: the vehicle's positions (which side the road is on)
    max_units : superimpose only the first this many units of each run (§5.2)
    """
    xyz = np.asarray(xyz, np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ReconstructionError(f"points must be (N, 3), got {xyz.shape}")
    points = xyz[np.asarray(guardrail, bool)]
    if not np.isfinite(points).all():
        raise ReconstructionError("guardrail points contain NaN or infinity")
    run_of_point = group_runs(points, params.runs)
    n_runs = int(run_of_point.max()) + 1 if len(run_of_point) else 0
    ground_xyz = xyz[np.asarray(ground, bool)]
    ground_tree = cKDTree(ground_xyz[:, :2]) if len(ground_xyz) else None
    track = np.asarray(trajectory, np.float64)[:, :2]
    track_tree = cKDTree(track)
    runs, superimposed = [], []
    for r in tqdm(range(n_runs), desc="reconstruct", unit="run", disable=not progress):
        run_xyz = points[run_of_point == r]
        near_ground = np.zeros((0, 3))
        if ground_tree is not None:
            lists = ground_tree.query_ball_point(run_xyz[::10, :2], GROUND_REACH_M)
            index = np.unique(np.concatenate([np.asarray(i, np.int64) for i in lists]))
            near_ground = ground_xyz[index]
        centre = run_xyz.mean(axis=0)
        toward = np.zeros(3)
        toward[:2] = track[track_tree.query(centre[:2])[1]] - centre[:2]
        model, sup = reconstruct_run(
            run_xyz, near_ground, toward, run_id=r, params=params, max_units=max_units
        )
        runs.append(model)
        superimposed.append(sup)
    return Reconstruction(runs, superimposed)


def guardrail_mask(point_segment: np.ndarray, label: np.ndarray) -> np.ndarray:
    """(N,) bool: points of segments labelled guardrail (after label correction)."""
    point_segment = np.asarray(point_segment)
    out = np.zeros(len(point_segment), bool)
    inside = point_segment >= 0
    out[inside] = np.asarray(label, bool)[point_segment[inside]]
    return out


def write_reconstruction(
    folder: Path,
    reconstruction: Reconstruction,
    *,
    params: ReconstructionParams,
    origin: np.ndarray,
    crs: str,
    seconds: float | None = None,
) -> dict[str, Any]:
    """Write models, superimposed points, inventory and meshes into ``folder`` (a new folder).

    Returns
    -------
    A summary: counts of runs by status and the files written.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=False)
    runs = reconstruction.runs
    (folder / "models.json").write_text(
        json.dumps(
            {
                "format_version": RECONSTRUCTION_FORMAT_VERSION,
                "params": params.to_json(),
                "seconds": seconds,
                "runs": [run_model_to_json(r) for r in runs],
            },
            indent=1,
        )
        + "\n"
    )
    arrays: dict[str, Any] = {}
    for run, sup in zip(runs, reconstruction.superimposed, strict=True):
        if sup is not None:
            arrays[f"run_{run.run_id:03d}_points"] = sup.points.astype(np.float32)
            arrays[f"run_{run.run_id:03d}_unit"] = sup.unit_of_point.astype(np.int16)
    np.savez_compressed(folder / "superimposed.npz", **arrays)
    rows = inventory_rows(runs, origin)
    write_inventory_geojson(folder / "inventory.geojson", rows, runs, origin, crs)
    write_inventory_csv(folder / "inventory.csv", rows)
    meshes = {run.run_id: run_mesh(run, params.sweep) for run in runs if run.poles}
    files = write_meshes(folder / "meshes", meshes)
    status = [row["status"] for row in rows]
    return {
        "runs": len(runs),
        "reconstructed": status.count("reconstructed"),
        "poles_only": status.count("poles only"),
        "not_reconstructed": status.count("not reconstructed"),
        "files": ["models.json", "superimposed.npz", "inventory.geojson", "inventory.csv"]
        + [f"meshes/{f}" for f in files],
    }


def load_reconstruction(run_dir: str | Path) -> tuple[list[RunModel], dict[str, Any]]:
    """The run models and ``models.json`` content of a run folder's reconstruction.

    Raises
    ------
    RunFolderError
        The run folder has no reconstruction, or one of another format version.
    """
    path = Path(run_dir) / RECONSTRUCTION_DIR / "models.json"
    if not path.is_file():
        raise RunFolderError(
            f"{run_dir}: no reconstruction (no {RECONSTRUCTION_DIR}/models.json); run "
            "`guardrail reconstruct RUN_DIR`"
        )
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise RunFolderError(f"{path}: not valid JSON ({exc})") from exc
    if data.get("format_version") != RECONSTRUCTION_FORMAT_VERSION:
        raise RunFolderError(
            f"{path}: reconstruction format {data.get('format_version')!r}, this version reads "
            f"{RECONSTRUCTION_FORMAT_VERSION}; run `guardrail reconstruct` again"
        )
    return [run_model_from_json(r, where=str(path)) for r in data["runs"]], data


def reconstruct_into(
    run_dir: Path,
    xyz: np.ndarray,
    point_segment: np.ndarray,
    label: np.ndarray,
    trajectory: np.ndarray,
    *,
    origin: np.ndarray,
    crs: str,
    params: ReconstructionParams = ReconstructionParams(),
    progress: bool = False,
) -> dict[str, Any]:
    """Reconstruct a run's guardrails and (re)place ``run_dir/reconstruction`` whole.

    The new reconstruction is written beside the old one and swapped in only when complete, so
    a failure leaves the previous reconstruction as it was.
    """
    from guardrail_core.run_folder import POINT_ROAD

    start = time.perf_counter()
    reconstruction = reconstruct_guardrails(
        xyz,
        guardrail_mask(point_segment, label),
        np.asarray(point_segment) == POINT_ROAD,
        trajectory,
        params=params,
        progress=progress,
    )
    seconds = round(time.perf_counter() - start, 4)
    run_dir = Path(run_dir)
    target = run_dir / RECONSTRUCTION_DIR
    staging = run_dir / f".{RECONSTRUCTION_DIR}.partial"
    if staging.exists():
        shutil.rmtree(staging)
    try:
        summary = write_reconstruction(
            staging, reconstruction, params=params, origin=origin, crs=crs, seconds=seconds
        )
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    old = run_dir / f".{RECONSTRUCTION_DIR}.old"
    if target.exists():
        if old.exists():
            shutil.rmtree(old)
        target.rename(old)
    staging.rename(target)
    if old.exists():
        shutil.rmtree(old)
    return {**summary, "seconds": seconds}
