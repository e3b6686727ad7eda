"""The 3D scene's *Reconstruction* panel: choose a guardrail run (the scene flies to it), move
the sliders of its kind (pipes or beams) and see its unit model re-run with its x histogram or
beam section, the reconstruction's own mesh ghosted; *Apply to the whole drive* reconstructs it
all in a background job and says when it is done.

:class:`TuningPanel` is a part of :class:`app.scene.viewer.ReviewScene`: it uses the scene's
server, session, tuner, jobs and meshes.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import trimesh
import viser

from app import review_jobs
from app.jobs import JobBusyError, JobRunner
from app.run_tuning import TUNABLE, RunTuner, slider_value, unit_numbers, with_value
from app.scene.latest_only import LatestOnly
from app.session import ReviewSession
from guardrail_core.errors import GuardrailError
from guardrail_core.io.meshes import run_file_stem
from guardrail_core.reconstruct.assemble import run_mesh
from guardrail_core.reconstruct.pipeline import ReconstructionParams

#: Mesh colours: the reconstruction, a retuned run, and the ghost of its previous mesh.
#: Lime and cyan: apart from the points' orange, blue and grey and the selection's magenta.
MESH_COLOUR = (200, 235, 40)
TUNED_COLOUR = (0, 215, 235)
GHOST_COLOUR = (150, 150, 150)
GHOST_OPACITY = 0.3
#: The scene folder of the reconstructed meshes.
MESH_NODES = "/reconstruction"


class TuningPanel:
    """The tuning half of the review scene (a mixin of :class:`~app.scene.viewer.ReviewScene`)."""

    # What the scene holds and this panel uses (set by ReviewScene.__init__).
    server: viser.ViserServer
    session: ReviewSession
    jobs: JobRunner | None
    vehicle_station: np.ndarray
    _tuner: RunTuner | None
    _tune_runner: LatestOnly
    _tune_lock: threading.Lock
    _quiet_sliders: bool
    _meshes: dict[int, viser.GlbHandle | viser.MeshHandle]
    _shown_mesh: dict[int, trimesh.Trimesh]
    _ghosts: dict[int, viser.MeshHandle]
    last_tune_seconds: float | None
    layers: dict[str, bool]

    def _fly_to_place(self, target: np.ndarray, station: float, distance_m: float = 8.0) -> None:
        raise NotImplementedError  # the scene's

    def fly_to_run(self, run_id: int) -> None:
        """Move the window and every browser's camera to a guardrail run's middle pole."""
        if self._tuner is None:
            return
        poles = self._tuner.run(run_id).poles
        if not poles:
            return
        target = np.asarray(poles[len(poles) // 2].position, np.float64)
        trajectory = self.session.drive.trajectory.position
        nearest = int(np.argmin(np.linalg.norm(trajectory - target, axis=1)))
        distance = max(12.0, 0.5 * float(np.linalg.norm(poles[-1].position - poles[0].position)))
        self._fly_to_place(target, float(self.vehicle_station[nearest]), min(distance, 40.0))

    def _build_tuning_gui(self, gui: Any) -> None:
        """The *Reconstruction* folder: a run to tune, its sliders, its plot, *Apply*."""
        with gui.add_folder("Reconstruction", expand_by_default=False):
            self._run_choice = gui.add_dropdown("Guardrail run", ("none",), initial_value="none")
            self._sliders: dict[tuple[str, str], Any] = {}
            defaults = ReconstructionParams()
            for (stage, name), (label, lo, hi, step) in TUNABLE.items():
                value = getattr(getattr(defaults, stage), name)
                slider = gui.add_slider(label, min=lo, max=hi, step=step, initial_value=value)
                slider.on_update(lambda _: self._schedule_tune())
                self._sliders[(stage, name)] = slider
            self._histogram = gui.add_uplot(
                data=(np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2)),
                series=(
                    {"label": "x (m)"},
                    {"label": "points per bin", "stroke": "#4e79a7", "fill": "#4e79a733"},
                    {"label": "threshold", "stroke": "#e15759", "dash": (6.0, 4.0)},
                    {"label": "vertical pipes", "stroke": "#f28e2b", "fill": "#f28e2b88"},
                ),
                title="x histogram (vertical pipes)",
                scales={"x": {"time": False}},  # metres, not a time axis
                # Named axes with room for their numbers and labels: the y label was clipped.
                axes=(
                    {"label": "x along the unit (m)", "size": 44},
                    {"label": "points per bin", "size": 56},
                ),
                aspect=1.3,
            )
            self._section = gui.add_uplot(
                data=(np.zeros(2), np.zeros(2)),
                series=(
                    {"label": "height y (m)"},
                    {"label": "depth z (m)", "stroke": "#4e79a7", "width": 2.0},
                ),
                title="beam section (depth by height)",
                scales={"x": {"time": False}},
                axes=({"label": "height y (m)", "size": 44}, {"label": "depth z (m)", "size": 56}),
                aspect=1.3,
                visible=False,
            )
            self._tune_text = gui.add_markdown("")
            apply = gui.add_button("Apply to the whole drive")

        self._run_choice.on_update(lambda _: self._on_run_chosen())
        apply.on_click(lambda _: self.apply_tuning())

    def _update_tuning_runs(self) -> None:
        """Offer the runs with a unit model and set the sliders to their parameters, without
        re-running anything (no operator moved them)."""
        self._quiet_sliders = True
        try:
            runs = self._tuner.tunable_runs() if self._tuner is not None else []
            options = tuple(
                f"run {r.run_id} ({r.model.type}, {len(r.units)} units)"
                for r in runs
                if r.model is not None
            ) or ("none",)
            chosen = self._run_choice.value
            self._run_choice.options = options
            # A reconstruction redone (Apply) keeps the run the operator was tuning.
            self._run_choice.value = chosen if chosen in options else options[0]  # type: ignore[misc]
            if self._tuner is not None:
                params = self._tuner.params
                for (stage, name), slider in self._sliders.items():
                    slider.value = getattr(getattr(params, stage), name)
        finally:
            self._quiet_sliders = False
        self.show_unit_plot()

    def _chosen_run(self) -> int | None:
        value = self._run_choice.value
        return None if value == "none" else int(value.split()[1])

    def _schedule_tune(self) -> None:
        if self._quiet_sliders:
            return
        self._tune_runner.request()

    def slider_params(self) -> ReconstructionParams:
        """The reconstruction parameters with the sliders' values."""
        tuner = self._tuner
        params = tuner.params if tuner is not None else ReconstructionParams()
        for (stage, name), slider in self._sliders.items():
            default = float(getattr(getattr(params, stage), name))
            value = slider_value((stage, name), slider.value, default)
            params = with_value(params, stage, name, value)
        return params

    def retune(self) -> float | None:
        """Re-run the chosen run's unit model with the sliders' values, plot it, and show its
        mesh beside the reconstruction's own, ghosted; returns the seconds the re-run took."""
        with self._tune_lock:
            return self._retune()

    def _retune(self) -> float | None:
        run_id = self._chosen_run()
        if self._tuner is None or run_id is None:
            return None
        params = self.slider_params()
        clock = time.perf_counter()
        try:
            unit = self._tuner.unit(run_id, params)
        except (GuardrailError, ValueError) as exc:
            self._tune_text.content = f"**Not re-run:** {exc}"
            return None
        # The plot answers the slider: it goes out at once. The meshes follow; a browser takes
        # far longer to draw them, and a slider moved meanwhile skips them.
        seconds = time.perf_counter() - clock
        self.last_tune_seconds = seconds
        self._plot_unit(unit_numbers(run_id, unit, params), seconds)
        self.server.flush()
        if self._tune_runner.pending:
            return seconds
        self._show_tuned_mesh(run_id, self._tuner.mesh(run_id, unit, params))
        return seconds

    def _show_tuned_mesh(self, run_id: int, mesh: trimesh.Trimesh) -> None:
        """Show a run's re-run mesh in place of its reconstruction's, which stays as a ghost."""
        assert self._tuner is not None
        if run_id not in self._ghosts:  # first re-run of this run: ghost its reconstruction
            ghost = run_mesh(self._tuner.run(run_id), self._tuner.params.sweep)
            self._ghosts[run_id] = self.server.scene.add_mesh_simple(
                mesh_node(run_id, ghost=True),
                vertices=ghost.vertices.astype(np.float32),
                faces=ghost.faces.astype(np.uint32),
                color=GHOST_COLOUR,
                opacity=GHOST_OPACITY,
                visible=self.layers["meshes"],
            )
        previous = self._meshes.pop(run_id, None)
        if previous is not None:
            previous.remove()
        self._meshes[run_id] = self.server.scene.add_mesh_simple(  # type: ignore[assignment]
            mesh_node(run_id),
            vertices=mesh.vertices.astype(np.float32),
            faces=mesh.faces.astype(np.uint32),
            color=TUNED_COLOUR,
            visible=self.layers["meshes"],
        )
        self._shown_mesh[run_id] = mesh

    def _on_run_chosen(self) -> None:
        """Plot the chosen run's histogram (or section) as its model has it, then re-run it
        with the sliders' values."""
        if not self._quiet_sliders:
            run_id = self._chosen_run()
            if run_id is not None:
                self.fly_to_run(run_id)
            self.show_unit_plot()
            self._schedule_tune()

    def show_unit_plot(self) -> None:
        """Plot the chosen run's x histogram with its threshold and vertical pipes (pipes) or
        its section curve (beams), with the sliders' values; no mesh changes."""
        run_id = self._chosen_run()
        if self._tuner is None or run_id is None:
            return
        params = self.slider_params()
        try:
            unit = self._tuner.unit(run_id, params)
        except (GuardrailError, ValueError, KeyError) as exc:
            self._tune_text.content = f"**Not re-run:** {exc}"
            return
        self._plot_unit(unit_numbers(run_id, unit, params), None)

    def _plot_unit(self, numbers: dict[str, Any], seconds: float | None) -> None:
        """Show ``unit_numbers``: the histogram or the section, and a line of text."""
        run_id = numbers["run_id"]
        if numbers["x_m"] is not None:
            x = np.asarray(numbers["x_m"], np.float64)
            counts = np.asarray(numbers["counts"], np.float64)
            half = 0.5 * numbers["bin_m"]
            marked = np.zeros(len(x))
            for pipe in numbers["pipes"]:
                if pipe["kind"] == "vertical":
                    inside = (x >= pipe["x_min_m"] - half) & (x <= pipe["x_max_m"] + half)
                    marked[inside] = counts[inside]
            self._histogram.data = (x, counts, np.full(len(x), numbers["threshold"]), marked)
        if numbers["section"] is not None:
            section = np.asarray(numbers["section"], np.float64).reshape(-1, 2)  # [z, y]
            order = np.argsort(section[:, 1], kind="stable")
            self._section.data = (section[order, 1], section[order, 0])
        self._histogram.visible = numbers["x_m"] is not None
        self._section.visible = numbers["section"] is not None
        for (stage, _), slider in self._sliders.items():  # a beam has no pipes to tune
            slider.visible = stage == ("pipes" if numbers["type"] == "pipe" else "beams")
        pipes = numbers["pipes"]
        if numbers["type"] == "pipe":
            kinds = sorted({p["kind"] for p in pipes})
            what = f"{len(pipes)} pipes: " + ", ".join(
                _pipe_kind(kind, [1000 * p["radius_m"] for p in pipes if p["kind"] == kind])
                for kind in kinds
            )
        else:
            n = 0 if numbers["section"] is None else len(numbers["section"])
            what = f"beam section of {n} points"
        if numbers["threshold"] is not None:
            what += (
                f" · threshold {numbers['threshold']:.1f} points/bin "
                f"(factor {numbers['histogram_factor']:.1f})"
            )
        timing = "" if seconds is None else f" · {1000 * seconds:.0f} ms"
        self._tune_text.content = f"run {run_id}: {what}{timing}"

    def apply_tuning(self) -> None:
        """Reconstruct the whole drive with the sliders' values (a background job); the new
        parameters are saved in ``reconstruction/models.json``."""
        if self._tuner is None or self.jobs is None:
            return
        params = self.slider_params()
        try:
            job = self.jobs.submit(
                "reconstruct", review_jobs.reconstruct(self.session, params), on_end=self._applied
            )
        except JobBusyError as exc:
            self._tune_text.content = f"not now: {exc}"
            return
        self._tune_text.content = f"reconstructing the drive (job {job.id})…"

    def _applied(self, job: Any) -> None:
        """Say how "Apply to the whole drive" ended (the run chosen stays chosen)."""
        if job.status == "done":
            self._tune_text.content = (
                f"**Applied:** the whole drive was reconstructed (job {job.id})"
            )
        else:
            self._tune_text.content = f"**Not applied** ({job.status}): {job.error or job.message}"


def _pipe_kind(kind: str, radii_mm: list[float]) -> str:
    """``"15 vertical r10-11 mm"``: the pipes of one kind and their radii."""
    lo, hi = round(min(radii_mm)), round(max(radii_mm))
    return f"{len(radii_mm)} {kind} r{lo}{'' if lo == hi else f'-{hi}'} mm"


def mesh_node(run_id: int, *, ghost: bool = False) -> str:
    """The scene node of a run's mesh (``MESH_NODES/run_NNN``, named as its file and its GLB
    node) or of the ghost of its previous mesh (``MESH_NODES/ghost_NNN``)."""
    if ghost:
        return f"{MESH_NODES}/ghost_{run_id:03d}"
    return f"{MESH_NODES}/{run_file_stem(run_id)}"
