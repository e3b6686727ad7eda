"""The 3D scene of the review app, built with viser.

The scene shows a window of the drive (points within a budget, coloured by label, prediction,
probability or truth), the trajectory, the cameras, and the reconstructed guardrails. A click
picks the segment under the cursor (the server finds it from the click ray: viser has no
per-point picking), a rectangle (shift + drag) picks many. The GUI owns the view (colours, the
window along the drive) and the reconstruction's thresholds, tuned live; labelling and the review
queue belong to the page beside it (one control for one action), which shows the selection's
crop, camera image and history.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
import viser
import viser.transforms as vtf

from app import review_jobs
from app.jobs import JobBusyError, JobRunner
from app.route_overview import run_stations
from app.run_tiles import TilePoints
from app.scene.colours import COLOUR_MODES, SELECTED, point_colours
from app.scene.picking import in_polygon, in_rectangle, pick_along_ray, project_to_screen
from app.scene.tuning import TUNABLE, RunTuner, slider_value, unit_numbers, with_value
from app.scene.window import window_points
from app.session import ReviewSession
from guardrail_core.errors import GuardrailError, RunFolderError
from guardrail_core.formats.drive_tiles import vehicle_station
from guardrail_core.io.meshes import run_file_stem
from guardrail_core.reconstruct.assemble import run_mesh
from guardrail_core.reconstruct.pipeline import ReconstructionParams

#: The selection panel without a selection: picking is the scene's, labelling the page's.
NO_SELECTION = "Click a point to select its segment (shift + drag: many); label it on the page."
#: Mesh colours: the reconstruction, a retuned run, and the ghost of its previous mesh.
MESH_COLOUR = (230, 230, 235)
TUNED_COLOUR = (60, 200, 120)
GHOST_COLOUR = (150, 150, 150)
GHOST_OPACITY = 0.3
#: Seconds to wait after the last slider move before re-running (sliders fire on every step).
DEBOUNCE_S = 0.15
#: The scene folder of the reconstructed meshes.
MESH_NODES = "/reconstruction"
#: The lasso being drawn: its node, colour, and how far in front of the camera (metres).
LASSO_NODE = "/lasso"
LASSO_COLOUR = (255, 0, 220)
LASSO_DRAW_M = 2.0
LASSO_HELP = (
    "**Lasso:** click the corners of a polygon around the points, then *Close the lasso*; "
    "the page labels the points inside (g, o)."
)


class ReviewScene:
    """The viser scene and GUI of one review session.

    Parameters
    ----------
    session : the drive and run under review
    server : the viser server to build on
    window_m : metres of trajectory shown at once
    point_budget : the most points sent to the browser
    jobs : where "apply to the whole drive" runs the reconstruction
    """

    def __init__(
        self,
        session: ReviewSession,
        server: viser.ViserServer,
        *,
        window_m: float = 100.0,
        point_budget: int = 400_000,
        jobs: JobRunner | None = None,
    ) -> None:
        self.session = session
        self.jobs = jobs
        self.server = server
        self.window_m = float(window_m)
        self.point_budget = int(point_budget)
        trajectory = session.drive.trajectory
        # The window runs along what the vehicle drove: nothing per point is worked out ahead.
        self.vehicle_station = vehicle_station(trajectory, trajectory.time)  # (T,) metres
        self.station_range = (float(self.vehicle_station[0]), float(self.vehicle_station[-1]))
        self.start_m = self.station_range[0]
        self.shown = TilePoints.concatenate([])  # the drive points now shown
        self.mode = "label"
        self._lock = threading.RLock()
        self._cloud: viser.PointCloudHandle | None = None
        self._frusta: list[viser.CameraFrustumHandle] = []
        self._meshes: dict[int, viser.GlbHandle | viser.MeshHandle] = {}
        self._mesh_files: dict[int, Path] = {}  # run id -> its GLB, read when near the window
        self._mesh_stations: dict[int, tuple[float, float]] = {}  # metres along the drive
        self._shown_mesh: dict[int, trimesh.Trimesh] = {}  # per run: the mesh now shown
        self._ghosts: dict[int, viser.MeshHandle] = {}
        self._fly_on_select = True
        self._quiet_sliders = False  # set while the code, not an operator, moves the sliders
        self._tuner: RunTuner | None = None
        self._tune_timer: threading.Timer | None = None
        # One re-run at a time: a debounced one still running when another starts would
        # otherwise draw its older sliders' plot over the newer one's.
        self._tune_lock = threading.Lock()
        self.last_tune_seconds: float | None = None
        # A lasso being drawn: its corners (screen position, drawn point) and the view.
        self._lasso: list[tuple[np.ndarray, np.ndarray]] | None = None
        self._lasso_camera: tuple[np.ndarray, float, float] | None = None
        self._lasso_line: viser.LineSegmentsHandle | None = None

        server.scene.set_up_direction("+z")
        self._build_gui()
        self.show_window(self.start_m)
        self._add_trajectory()
        self.load_meshes()
        server.on_client_connect(self._on_connect)
        server.scene.on_click()(self._on_click)
        server.scene.on_rect_select(modifier="shift")(self._on_rect_select)
        session.subscribe(self._on_session_event)

    # -- the window of points ---------------------------------------------------------------

    def show_window(self, start_m: float) -> float:
        """Show the points of ``[start_m, start_m + window_m)``; returns the seconds it took."""
        clock = time.perf_counter()
        lo, hi = self.station_range
        start_m = float(np.clip(start_m, lo, max(lo, hi - self.window_m)))
        with self._lock:
            self.start_m = start_m
            window = self.session.tiles.window(start_m, start_m + self.window_m)
            self.shown = window.take(
                window_points(
                    window.station, window.segment, start_m, self.window_m, self.point_budget
                )
            )
            self._cloud = self.server.scene.add_point_cloud(
                "/drive/points",
                points=self.shown.xyz.astype(np.float32),
                colors=self._colours(),
                point_size=0.04,
                point_shape="circle",
                precision="float32",
            )
        self._add_cameras()
        self.show_meshes_near()
        self._window_text.content = (
            f"{start_m:.0f}-{start_m + self.window_m:.0f} m of "
            f"{hi - lo:.0f} m · {len(self.shown):,} points"
        )
        return time.perf_counter() - clock

    def _colours(self) -> np.ndarray:
        session = self.session
        selected = np.zeros(session.n_segments, bool)
        lasso = session.lasso
        if len(lasso) == 0:
            selected[session.selection] = True
        colours = point_colours(
            self.mode,
            self.shown.segment,
            segment_label=session.effective_label(),
            raw_label=session.run.segments["raw_label"],
            probability=session.run.segments["probability"],
            point_labels=session.labels_at(self.shown.index),
            point_class=self.shown.point_class,
            selected=selected,
        )
        if len(lasso):  # a lasso selects points, not whole segments
            colours[np.isin(self.shown.index, lasso, assume_unique=True)] = SELECTED
        return colours

    def recolour(self) -> float:
        """Recolour the points shown (after a relabel, a new selection or another mode);
        returns the seconds it took."""
        clock = time.perf_counter()
        with self._lock:
            if self._cloud is not None:
                self._cloud.colors = self._colours()
        return time.perf_counter() - clock

    def _add_trajectory(self) -> None:
        position = self.session.drive.trajectory.position
        step = max(1, len(position) // 2000)
        path = position[::step]
        segments = np.stack([path[:-1], path[1:]], axis=1)
        self.server.scene.add_line_segments(
            "/drive/trajectory",
            points=segments,
            colors=(40, 120, 255),
            thickness=2.0,
            thickness_units="screen",
        )

    def _add_cameras(self) -> None:
        """Frusta of the images taken along the window (the crops' sources)."""
        drive = self.session.drive
        for handle in list(self._frusta):
            handle.remove()
        self._frusta = []
        if not drive.images:
            return
        times = np.array([image.gps_time for image in drive.images])
        station = np.interp(times, drive.trajectory.time, self.vehicle_station)
        inside = np.flatnonzero(
            (station >= self.start_m) & (station < self.start_m + self.window_m)
        )
        for i in inside:
            image = drive.images[i]
            camera = drive.cameras[image.camera]
            fov = 2 * np.arctan2(camera.height / 2, camera.K[1, 1])
            T = image.T_world_camera
            self._frusta.append(
                self.server.scene.add_camera_frustum(
                    f"/drive/cameras/{i:05d}",
                    fov=float(fov),
                    aspect=camera.width / camera.height,
                    scale=0.4,
                    color=(255, 200, 40),
                    wxyz=vtf.SO3.from_matrix(T[:3, :3]).wxyz,
                    position=T[:3, 3],
                )
            )

    # -- meshes -----------------------------------------------------------------------------

    def load_meshes(self) -> None:
        """Read which runs have a reconstructed mesh (``reconstruction/meshes``) and where they
        lie along the drive, and show those near the window (:meth:`show_meshes_near`)."""
        self._shown_mesh = {}
        for name in list(self._ghosts):
            self._ghosts.pop(name).remove()
        for handle in list(self._meshes.values()):
            handle.remove()
        self._meshes = {}
        try:
            self._tuner = RunTuner(self.session.folder)
        except (RunFolderError, OSError, KeyError):
            self._tuner = None
        self._mesh_files = self.session.folder.reconstruction.mesh_files("glb")
        runs = self._tuner.runs if self._tuner is not None else []
        stations = run_stations(runs, self.session.drive.trajectory)
        self._mesh_stations = {run.run_id: at for run, at in zip(runs, stations, strict=True)}
        self.show_meshes_near()
        self._update_tuning_runs()

    def show_meshes_near(self) -> None:
        """Show the meshes of the runs within half a window of the window (a survey has
        thousands), and take away the others but those being tuned."""
        margin = 0.5 * self.window_m
        lo, hi = self.start_m - margin, self.start_m + self.window_m + margin
        for run_id, path in self._mesh_files.items():
            first, last = self._mesh_stations.get(run_id, (-np.inf, np.inf))  # no poles: always
            near = first <= hi and last >= lo
            if near and run_id not in self._meshes:
                self._meshes[run_id] = self.server.scene.add_glb(
                    _mesh_node(run_id), glb_data=path.read_bytes()
                )
            elif not near and run_id in self._meshes and run_id not in self._shown_mesh:
                self._meshes.pop(run_id).remove()

    # -- picking ----------------------------------------------------------------------------

    def _segment_points(self) -> TilePoints:
        """The points shown that lie in a segment (what a click or a rectangle may pick)."""
        shown = self.shown
        return shown.take(np.flatnonzero(shown.segment >= 0))

    def _on_click(self, event: viser.SceneClickEvent) -> None:
        if self._lasso is not None:
            self.add_lasso_corner(event)
            return
        candidates = self._segment_points()
        hit = pick_along_ray(
            candidates.xyz, np.asarray(event.ray_origin), np.asarray(event.ray_direction)
        )
        if hit is None:
            return
        self.session.select([int(candidates.segment[hit])])

    def _on_rect_select(self, event: viser.SceneRectSelectEvent) -> None:
        camera = event.client.camera
        candidates = self._segment_points()
        uv, in_front = project_to_screen(
            candidates.xyz, _camera_pose(camera), camera.fov, camera.aspect
        )
        inside = in_rectangle(
            uv, in_front, np.asarray(event.screen_min), np.asarray(event.screen_max)
        )
        segments = np.unique(candidates.segment[inside])
        if len(segments):
            self.session.select(segments)

    # -- the lasso ----------------------------------------------------------------------------

    def start_lasso(self) -> None:
        """Start a lasso: each click in the scene adds a corner, *Close the lasso* selects the
        segment points inside it, as the view showed them at the first corner."""
        with self._lock:
            self._lasso = []
            self._lasso_camera = None
        self._lasso_start.visible = False
        self._lasso_close.visible = self._lasso_cancel.visible = True
        self._selection_text.content = LASSO_HELP

    def add_lasso_corner(self, event: viser.SceneClickEvent) -> None:
        """One corner of the lasso: the click's screen position (the polygon's), drawn a little
        in front of the camera along the click's ray."""
        if self._lasso is None or event.screen_pos is None:
            return
        camera = event.client.camera
        with self._lock:
            if self._lasso_camera is None:  # the view the polygon is drawn in
                self._lasso_camera = _camera_pose(camera), float(camera.fov), float(camera.aspect)
            origin = np.asarray(event.ray_origin, np.float64)
            direction = np.asarray(event.ray_direction, np.float64)
            corner = origin + LASSO_DRAW_M * direction / np.linalg.norm(direction)
            self._lasso.append((np.asarray(event.screen_pos, np.float64), corner))
            self._draw_lasso()

    def _draw_lasso(self) -> None:
        corners = np.array([world for _, world in self._lasso or []]).reshape(-1, 3)
        if len(corners) < 2:
            return
        closed = np.concatenate([corners, corners[:1]])
        self._lasso_line = self.server.scene.add_line_segments(
            LASSO_NODE,
            points=np.stack([closed[:-1], closed[1:]], axis=1),
            colors=LASSO_COLOUR,
            thickness=2.0,
            thickness_units="screen",
        )

    def close_lasso(self) -> np.ndarray:
        """Select the segment points shown inside the lasso (their segments become the
        selection, and the page labels the points); returns the drive points taken."""
        with self._lock:
            corners, view = self._lasso or [], self._lasso_camera
            self._end_lasso()
            if len(corners) < 3 or view is None:
                self._selection_text.content = "A lasso needs three corners: try again."
                return np.zeros(0, np.int64)
            candidates = self._segment_points()
            T, fov, aspect = view
            uv, in_front = project_to_screen(candidates.xyz, T, fov, aspect)
            polygon = np.array([screen for screen, _ in corners])
            taken = candidates.index[in_polygon(uv, in_front, polygon)]
        self._fly_on_select = False  # the operator is looking at them
        try:
            self.session.select_points(taken)
        finally:
            self._fly_on_select = True
        return taken

    def _close_lasso_clicked(self) -> None:
        self.close_lasso()

    def cancel_lasso(self) -> None:
        with self._lock:
            self._end_lasso()
        self._show_selection()

    def _end_lasso(self) -> None:
        self._lasso = None
        self._lasso_camera = None
        if self._lasso_line is not None:
            self._lasso_line.remove()
            self._lasso_line = None
        self._lasso_start.visible = True
        self._lasso_close.visible = self._lasso_cancel.visible = False

    def fly_to(self, segment: int) -> None:
        """Move the window and every browser's camera to a segment."""
        target = self.session.run.segments["centroid"][segment]
        trajectory = self.session.drive.trajectory
        scanned = float(np.mean(self.session.run.segments["time"][segment]))
        station = float(np.interp(scanned, trajectory.time, self.vehicle_station))
        if not self.start_m <= station < self.start_m + self.window_m:
            self.show_window(station - self.window_m / 2)
        for client in self.server.get_clients().values():
            self._look_at(client, target, distance_m=8.0)

    def _look_at(self, client: viser.ClientHandle, target: np.ndarray, distance_m: float) -> None:
        """Put a browser's camera above the trajectory beside ``target``, looking at it."""
        trajectory = self.session.drive.trajectory.position
        nearest = int(np.argmin(np.linalg.norm(trajectory - target, axis=1)))
        back = trajectory[max(nearest - 1, 0)] - trajectory[min(nearest + 1, len(trajectory) - 1)]
        back = back / max(float(np.linalg.norm(back)), 1e-9)
        eye = trajectory[nearest] + 0.5 * distance_m * back + np.array([0.0, 0.0, 0.4 * distance_m])
        eye = target + (eye - target) / max(float(np.linalg.norm(eye - target)), 1e-9) * distance_m
        client.camera.position = eye
        client.camera.look_at = target

    def _on_connect(self, client: viser.ClientHandle) -> None:
        """A new browser starts at the selection, or at the start of the window."""
        if len(self.session.selection):
            target = self.session.run.segments["centroid"][int(self.session.selection[0])]
            self._look_at(client, target, distance_m=8.0)
            return
        shown = self.shown
        if len(shown) == 0:
            return
        ahead = shown.station < self.start_m + 0.3 * self.window_m
        target = np.median(shown.xyz[ahead] if ahead.any() else shown.xyz, axis=0)
        self._look_at(client, target, distance_m=25.0)

    def close(self) -> None:
        """Stop listening to the session and cancel a pending re-run."""
        self.session.unsubscribe(self._on_session_event)
        if self._tune_timer is not None:
            self._tune_timer.cancel()

    # -- session events ---------------------------------------------------------------------

    def _on_session_event(self, event: str, segments: np.ndarray) -> None:
        if event == "reconstruction":
            self.load_meshes()
            return
        if event == "lasso_cancelled":  # the page was reloaded, or Escape pressed there
            with self._lock:
                self._end_lasso()
        self.recolour()
        if event in ("selection", "labels", "predictions", "lasso_cancelled"):
            self._show_selection()
        if event == "selection" and len(segments) and self._fly_on_select:
            self.fly_to(int(segments[0]))

    def step(self, direction: int) -> None:
        """Move the window back (-1) or forward (+1) along the trajectory, overlapping by 20%."""
        self.show_window(self.start_m + direction * 0.8 * self.window_m)

    # -- GUI --------------------------------------------------------------------------------

    def _build_gui(self) -> None:
        gui = self.server.gui

        with gui.add_folder("View"):
            mode = gui.add_dropdown("Colour by", COLOUR_MODES, initial_value="label")
            self._window_text = gui.add_markdown("")
            back = gui.add_button("◀ Back", icon=None)
            forward = gui.add_button("Forward ▶")

        @mode.on_update
        def _(_: Any) -> None:
            self.mode = mode.value
            self.recolour()

        back.on_click(lambda _: self.step(-1))
        forward.on_click(lambda _: self.step(+1))

        with gui.add_folder("Selection"):
            self._selection_text = gui.add_markdown(NO_SELECTION)
            self._lasso_start = gui.add_button("Lasso points")
            self._lasso_close = gui.add_button("Close the lasso", visible=False)
            self._lasso_cancel = gui.add_button("Cancel the lasso", visible=False)

        self._lasso_start.on_click(lambda _: self.start_lasso())
        self._lasso_close.on_click(lambda _: self._close_lasso_clicked())
        self._lasso_cancel.on_click(lambda _: self.cancel_lasso())

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
                aspect=2.0,
            )
            self._section = gui.add_uplot(
                data=(np.zeros(2), np.zeros(2)),
                series=(
                    {"label": "height y (m)"},
                    {"label": "depth z (m)", "stroke": "#4e79a7", "width": 2.0},
                ),
                title="beam section (depth by height)",
                scales={"x": {"time": False}},
                aspect=2.0,
                visible=False,
            )
            self._tune_text = gui.add_markdown("")
            apply = gui.add_button("Apply to the whole drive")

        self._run_choice.on_update(lambda _: self._on_run_chosen())
        apply.on_click(lambda _: self.apply_tuning())

    def _show_selection(self) -> None:
        session = self.session
        if self._lasso is not None:  # being drawn
            self._selection_text.content = LASSO_HELP
            return
        if len(session.lasso):
            self._selection_text.content = (
                f"**Lasso:** {len(session.lasso):,} points in {len(session.selection)} "
                "segments  \nlabel them on the page beside the scene (g, o)"
            )
            return
        if len(session.selection) == 0:
            self._selection_text.content = NO_SELECTION
            return
        s = int(session.selection[0])
        seg = session.run.segments
        p = float(seg["probability"][s])
        label = "guardrail" if session.effective_label()[s] else "other"
        reviewed = "reviewed" if session.operator_label[s] >= 0 else "model"
        more = f" (+{len(session.selection) - 1} more)" if len(session.selection) > 1 else ""
        self._selection_text.content = (
            f"**Segment {s}**{more}  \n"
            f"probability {'—' if np.isnan(p) else f'{100 * p:.1f}%'} · "
            f"raw {'guardrail' if seg['raw_label'][s] else 'other'}  \n"
            f"label **{label}** ({reviewed}) · {int(seg['n_points'][s])} points  \n"
            "label it on the page beside the scene (g, o)"
        )

    # -- tuning -----------------------------------------------------------------------------

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
            self._run_choice.options = options
            self._run_choice.value = options[0]  # type: ignore[misc]
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
        if self._tune_timer is not None:
            self._tune_timer.cancel()
        self._tune_timer = threading.Timer(DEBOUNCE_S, self.retune)
        self._tune_timer.daemon = True
        self._tune_timer.start()

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
        """Re-run the chosen run's unit model with the sliders' values and show its mesh, the
        previous one ghosted; returns the seconds the re-run took."""
        with self._tune_lock:
            return self._retune()

    def _retune(self) -> float | None:
        run_id = self._chosen_run()
        if self._tuner is None or run_id is None:
            return None
        params = self.slider_params()
        try:
            result = self._tuner.retune(run_id, params)
        except (GuardrailError, ValueError) as exc:
            self._tune_text.content = f"**Not re-run:** {exc}"
            return None
        name = _mesh_node(run_id)
        previous = self._meshes.pop(run_id, None)
        ghost = self._shown_mesh.get(run_id)
        if ghost is None:  # first re-run: the ghost is the reconstruction's own mesh
            ghost = run_mesh(self._tuner.run(run_id), self._tuner.params.sweep)
        if previous is not None:
            previous.remove()
        if ghost is not None:
            self._ghosts[run_id] = self.server.scene.add_mesh_simple(
                _mesh_node(run_id, ghost=True),
                vertices=ghost.vertices.astype(np.float32),
                faces=ghost.faces.astype(np.uint32),
                color=GHOST_COLOUR,
                opacity=GHOST_OPACITY,
            )
        mesh: trimesh.Trimesh = result.mesh
        self._meshes[run_id] = self.server.scene.add_mesh_simple(  # type: ignore[assignment]
            name,
            vertices=mesh.vertices.astype(np.float32),
            faces=mesh.faces.astype(np.uint32),
            color=TUNED_COLOUR,
        )
        self._shown_mesh[run_id] = mesh
        self.last_tune_seconds = result.seconds
        self._plot_unit(unit_numbers(run_id, result.unit, params), result.seconds)
        return result.seconds

    def _on_run_chosen(self) -> None:
        """Plot the chosen run's histogram (or section) as its model has it, then re-run it
        with the sliders' values."""
        if not self._quiet_sliders:
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
            job = self.jobs.submit("reconstruct", review_jobs.reconstruct(self.session, params))
        except JobBusyError as exc:
            self._tune_text.content = f"not now: {exc}"
            return
        self._tune_text.content = f"reconstructing the drive (job {job.id})…"


def _camera_pose(camera: viser.CameraHandle) -> np.ndarray:
    """(4, 4) T_world_camera of a browser's camera."""
    T = np.eye(4)
    T[:3, :3] = vtf.SO3(np.asarray(camera.wxyz)).as_matrix()
    T[:3, 3] = camera.position
    return T


def _pipe_kind(kind: str, radii_mm: list[float]) -> str:
    """``"15 vertical r10-11 mm"``: the pipes of one kind and their radii."""
    lo, hi = round(min(radii_mm)), round(max(radii_mm))
    return f"{len(radii_mm)} {kind} r{lo}{'' if lo == hi else f'-{hi}'} mm"


def _mesh_node(run_id: int, *, ghost: bool = False) -> str:
    """The scene node of a run's mesh (``MESH_NODES/run_NNN``, named as its file and its GLB
    node) or of the ghost of its previous mesh (``MESH_NODES/ghost_NNN``)."""
    if ghost:
        return f"{MESH_NODES}/ghost_{run_id:03d}"
    return f"{MESH_NODES}/{run_file_stem(run_id)}"
