"""Runs the reconstruction stages (§4) on a drive's guardrail points.

guardrail points -> runs -> poles (§4.1) -> units (§4.1) -> superimposition with ICP (§4.2)
-> pipes (§4.3) or beam section (§4.4) -> the unit copied between the poles -> meshes + inventory.

:mod:`guardrail_core.reconstruct.writing` writes the result into a run folder.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from guardrail_core.errors import (
    ReconstructionError,
)
from guardrail_core.io.meshes import export_mesh_files
from guardrail_core.params import ParameterError, StageParams, apply_settings
from guardrail_core.progress import progress_bar
from guardrail_core.reconstruct.assemble import run_mesh
from guardrail_core.reconstruct.beams import BeamParams, reconstruct_beam
from guardrail_core.reconstruct.model import RunModel, UnitModel
from guardrail_core.reconstruct.pipes import PipeHistogram, PipeParams, reconstruct_pipes
from guardrail_core.reconstruct.poles import PoleParams, detect_poles
from guardrail_core.reconstruct.register import RegisterParams, Superimposition, superimpose
from guardrail_core.reconstruct.runs import RunParams, group_runs
from guardrail_core.reconstruct.sweep import SweepParams
from guardrail_core.reconstruct.unit_type import unit_type
from guardrail_core.reconstruct.units import UnitParams, order_poles, split_units


@dataclass(frozen=True)
class ReconstructionParams(StageParams):
    """The parameters of every reconstruction stage, each with the paper's defaults.

    Each field is one stage's parameters: its name is the STAGE of ``--set STAGE.NAME=VALUE``
    and the key in ``models.json``'s ``params``.
    """

    runs: RunParams = field(default_factory=RunParams)
    poles: PoleParams = field(default_factory=PoleParams)
    units: UnitParams = field(default_factory=UnitParams)
    register: RegisterParams = field(default_factory=RegisterParams)
    pipes: PipeParams = field(default_factory=PipeParams)
    beams: BeamParams = field(default_factory=BeamParams)
    sweep: SweepParams = field(default_factory=SweepParams)

    @classmethod
    def stage_classes(cls) -> dict[str, type[StageParams]]:
        """Each stage's name and its parameters' class, in the order the stages run."""
        hints = typing.get_type_hints(cls)
        return {f.name: hints[f.name] for f in dataclasses.fields(cls)}

    def check_relations(self) -> None:
        for stage, kind in self.stage_classes().items():
            value = getattr(self, stage)
            if not isinstance(value, kind):
                self.fail(f"{stage} must be {kind.__name__}, got {type(value).__name__}")

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ReconstructionParams:
        """Parameters from :meth:`to_json` output (``{stage: {name: value}}``); missing stages
        and names keep their defaults.

        Raises
        ------
        ParameterError
            An unknown stage or name (naming both), or a value the stage refuses.
        """
        if not isinstance(data, Mapping):
            raise ParameterError(f"expected an object of stages, got {data!r}")
        stages = cls.stage_classes()
        parts: dict[str, Any] = {}  # each stage's class is that of its field
        for stage, values in data.items():
            if stage not in stages:
                raise ParameterError(
                    f"unknown reconstruction stage {stage!r} (known: {', '.join(stages)})"
                )
            try:
                parts[stage] = stages[stage].from_json(values)
            except ParameterError as exc:
                raise ParameterError(f"{stage}: {exc}") from exc
        return cls(**parts)

    def with_settings(self, settings: Sequence[str]) -> ReconstructionParams:
        """These parameters with ``STAGE.NAME=VALUE`` settings applied (the CLI's ``--set``):
        see :func:`~guardrail_core.params.apply_settings`."""
        return apply_settings(self, self.stage_classes(), settings, "reconstruction")


@dataclass
class Reconstruction:
    """Every reconstructed run of a drive, with what re-running a unit model needs.

    Attributes
    ----------
    runs : one model per run of guardrail points, in run id order
    superimposed : per run, the superimposed unit points (None where there were no units)
    meshes : {run id: (mesh, {format: file bytes})} of runs with poles, where they were made
        with the models (:func:`reconstruct_run_meshes`); None: :func:`write_reconstruction`
        makes them
    """

    runs: list[RunModel]
    superimposed: list[Superimposition | None]
    meshes: dict[int, tuple[trimesh.Trimesh, dict[str, bytes]]] | None = None


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
    unit_of_point: np.ndarray | None = None,
) -> UnitReconstruction:
    """The unit model of superimposed unit points: beam section or pipes (§4.3-4.4).

    This is the step the review app re-runs when an operator moves a threshold.

    Parameters
    ----------
    points : (N, 3) float64, unit coordinates (metres), pole points removed
    length : float, metres between the pole axes
    unit_of_point : (N,) int, the unit each point came from; pipes then keep only the points
        another unit confirms (:mod:`guardrail_core.reconstruct.pipes.consensus`)
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
    pipes = reconstruct_pipes(
        points, length, pole_radius, params.pipes, unit_of_point=unit_of_point
    )
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
    unit_of_point: np.ndarray | None = None,
) -> UnitModel:
    """The unit model alone (see :func:`reconstruct_unit`)."""
    return reconstruct_unit(
        points,
        length,
        pole_radius=pole_radius,
        pole_height=pole_height,
        n_units=n_units,
        params=params,
        unit_of_point=unit_of_point,
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
    # only extrapolated (unless no unit is anchored at all); nor do units with a hole (unless
    # none is whole).
    chosen = np.flatnonzero(split.anchored) if split.anchored.any() else np.arange(len(frames))
    pole_radius = float(np.median([p.radius for p in poles]))
    margin = pole_radius + params.pipes.pole_margin_m
    whole = [
        u
        for u in chosen
        if _largest_hole(unit_points[u][:, 0], margin, frames[u].length - margin)
        < params.units.max_hole_m
    ]
    if whole and len(whole) < len(chosen):
        notes.append(
            f"{len(chosen) - len(whole)} unit(s) with {params.units.max_hole_m:g} m or more "
            "without points between the poles took the model without shaping it"
        )
        chosen = np.asarray(whole, dtype=np.int64)
    if max_units is not None:
        chosen = chosen[:max_units]
    used = [unit_points[u] for u in chosen]
    length = float(np.median([f.length for f in frames]))
    if length <= 2 * (pole_radius + params.pipes.pole_margin_m):
        # Two "poles" closer than their own width and margins (stems in a bush beside a rail):
        # there is no unit between them to model.
        notes.append(
            f"poles {length:.2f} m apart: no room for a unit between them, so no unit shape "
            "was reconstructed"
        )
        return RunModel(
            run_id, poles, frames, None, np.zeros(len(frames), bool), len(xyz), notes
        ), None
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
        pole_radius=pole_radius,
        pole_height=float(np.median([p.height for p in poles])),
        n_units=len(used),
        params=params,
        unit_of_point=superimposed.unit_of_point,
    )
    return RunModel(run_id, poles, frames, model, registered, len(xyz), notes), superimposed


def _largest_hole(x: np.ndarray, x0: float, x1: float) -> float:
    """Metres: the longest stretch of [``x0``, ``x1``] (metres along a unit) that no value of
    ``x`` (K,) falls in: all of it when none does, 0 when ``x1 <= x0``."""
    if x1 <= x0:
        return 0.0
    inside = np.sort(x[(x > x0) & (x < x1)])
    return float(np.diff(np.concatenate([[x0], inside, [x1]])).max())


@dataclass(frozen=True)
class RunInput:
    """What :func:`reconstruct_run` needs for one run: its points, the ground near it and the
    direction of the road (small arrays: a run is a task of its own on a survey).

    Attributes
    ----------
    run_id : the run's number
    xyz : (N, 3) float64, metres: the run's guardrail points
    ground : (G, 3) float64: road-surface points near them
    toward_road : (3,) horizontal direction from the run toward the trajectory
    """

    run_id: int
    xyz: np.ndarray
    ground: np.ndarray
    toward_road: np.ndarray


def split_runs(
    points: np.ndarray,
    ground_xyz: np.ndarray,
    trajectory: np.ndarray,
    params: ReconstructionParams = ReconstructionParams(),
) -> list[RunInput]:
    """Group guardrail points into runs (§4.1) and give each the ground near it.

    Parameters
    ----------
    points : (N, 3) float64, metres: the guardrail points of a drive, in drive order
    ground_xyz : (G, 3) float64: road-surface points (all of them, or at least those within
        ``params.runs.ground_reach_m`` of a guardrail point), in drive order
    trajectory : (T, 3) float64: the vehicle's positions (which side the road is on)
    """
    points = np.asarray(points, np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ReconstructionError(f"points must be (N, 3), got {points.shape}")
    if not np.isfinite(points).all():
        raise ReconstructionError("guardrail points contain NaN or infinity")
    return run_inputs(points, group_runs(points, params.runs), ground_xyz, trajectory, params)


def run_inputs(
    points: np.ndarray,
    run_of_point: np.ndarray,
    ground_xyz: np.ndarray,
    trajectory: np.ndarray,
    params: ReconstructionParams = ReconstructionParams(),
    first_id: int = 0,
) -> list[RunInput]:
    """The :class:`RunInput` of each run of grouped guardrail points.

    Parameters
    ----------
    points : (N, 3) float64, metres: guardrail points, in drive order
    run_of_point : (N,) int: each point's run, 0 .. R-1 (-1: in none)
    ground_xyz : (G, 3) float64: road-surface points (at least those within
        ``params.runs.ground_reach_m`` of the runs' points), in drive order
    trajectory : (T, 3) float64: the vehicle's positions
    first_id : the ``run_id`` of run 0 (the others follow)
    """
    ground_xyz = np.asarray(ground_xyz, np.float64).reshape(-1, 3)
    n_runs = int(run_of_point.max()) + 1 if len(run_of_point) else 0
    ground_tree = cKDTree(ground_xyz[:, :2]) if len(ground_xyz) else None
    track = np.asarray(trajectory, np.float64)[:, :2]
    track_tree = cKDTree(track)
    order = np.argsort(run_of_point, kind="stable")
    starts = np.searchsorted(run_of_point[order], np.arange(n_runs + 1))
    runs = []
    for r in range(n_runs):
        run_xyz = points[order[starts[r] : starts[r + 1]]]
        near_ground = np.zeros((0, 3))
        if ground_tree is not None:
            index = _ground_near(ground_tree, run_xyz[:: params.runs.ground_query_step, :2], params)
            near_ground = ground_xyz[index]
        centre = run_xyz.mean(axis=0)
        toward = np.zeros(3)
        toward[:2] = track[track_tree.query(centre[:2])[1]] - centre[:2]
        runs.append(RunInput(first_id + r, run_xyz, near_ground, toward))
    return runs


def _ground_near(
    ground_tree: cKDTree, sample_xy: np.ndarray, params: ReconstructionParams
) -> np.ndarray:
    """(G,) int64, ascending: the ground points within ``runs.ground_reach_m`` (horizontally) of
    any of a run's sampled points (K, 2): those whose nearest sampled point is that close, among
    the ground points of a disc around the run (one ball query, not one per sampled point)."""
    reach = params.runs.ground_reach_m
    lo, hi = sample_xy.min(axis=0), sample_xy.max(axis=0)
    candidates = np.asarray(
        ground_tree.query_ball_point((lo + hi) / 2, float(np.hypot(*(hi - lo))) / 2 + reach),
        np.int64,
    )
    if len(candidates) == 0:
        return candidates
    candidates.sort()
    # distance_upper_bound excludes its own value; query_ball_point includes its radius.
    distance, _ = cKDTree(sample_xy).query(
        ground_tree.data[candidates], distance_upper_bound=np.nextafter(reach, np.inf)
    )
    return candidates[distance <= reach]


def reconstruct_run_input(
    run: RunInput,
    params: ReconstructionParams = ReconstructionParams(),
    max_units: int | None = None,
) -> tuple[RunModel, Superimposition | None]:
    """:func:`reconstruct_run` of one :class:`RunInput`."""
    return reconstruct_run(
        run.xyz, run.ground, run.toward_road, run_id=run.run_id, params=params, max_units=max_units
    )


def reconstruct_run_meshes(
    run: RunInput, params: ReconstructionParams = ReconstructionParams()
) -> tuple[RunModel, Superimposition | None, tuple[trimesh.Trimesh, dict[str, bytes]] | None]:
    """:func:`reconstruct_run_input`, and the run's mesh with its files (None without poles):
    a task of ``guardrail process``, so that the workers make the meshes too."""
    model, superimposed = reconstruct_run_input(run, params)
    if not model.poles:
        return model, superimposed, None
    mesh = run_mesh(model, params.sweep)
    return model, superimposed, (mesh, export_mesh_files(mesh))


def reconstruct_guardrails(
    xyz: np.ndarray,
    guardrail: np.ndarray,
    ground: np.ndarray,
    trajectory: np.ndarray,
    *,
    params: ReconstructionParams = ReconstructionParams(),
    max_units: int | None = None,
    progress: bool = False,
    on_run: Callable[[int, int], None] | None = None,
) -> Reconstruction:
    """Reconstruct every guardrail run of a drive.

    Parameters
    ----------
    xyz : (N, 3) float64, metres: every point of the drive, local frame
    guardrail : (N,) bool: the points labelled guardrail
    ground : (N,) bool: the points of the road surface (the ground of the poles)
    trajectory : (T, 3) float64: the vehicle's positions (which side the road is on)
    max_units : superimpose only the first this many units of each run (§5.2)
    on_run : called with (runs done, runs) before the first run and after each (what it raises
        stops the reconstruction: a cancelled job)
    """
    xyz = np.asarray(xyz, np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ReconstructionError(f"points must be (N, 3), got {xyz.shape}")
    runs = split_runs(
        xyz[np.asarray(guardrail, bool)], xyz[np.asarray(ground, bool)], trajectory, params
    )
    results = []
    for done, run in enumerate(
        progress_bar(runs, desc="reconstruct", unit="run", enabled=progress)
    ):
        if on_run is not None:
            on_run(done, len(runs))
        results.append(reconstruct_run_input(run, params, max_units))
    if on_run is not None:
        on_run(len(runs), len(runs))
    return Reconstruction([m for m, _ in results], [s for _, s in results])


def guardrail_mask(point_segment: np.ndarray, label: np.ndarray) -> np.ndarray:
    """(N,) bool: points of segments labelled guardrail (after label correction)."""
    point_segment = np.asarray(point_segment)
    out = np.zeros(len(point_segment), bool)
    inside = point_segment >= 0
    out[inside] = np.asarray(label, bool)[point_segment[inside]]
    return out
