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

from app.jobs import JobRunner
from app.route_overview import run_stations
from app.run_tiles import TilePoints
from app.run_tuning import RunTuner
from app.scene.colours import COLOUR_MODES, SELECTED, colour_legend, point_colours
from app.scene.lasso_tool import LASSO_HELP, LassoTool
from app.scene.latest_only import LatestOnly
from app.scene.picking import camera_pose, in_rectangle, pick_along_ray, project_to_screen
from app.scene.tuning_panel import MESH_COLOUR, TuningPanel, mesh_node
from app.scene.window import window_points
from app.session import ReviewSession
from guardrail_core.errors import RunFolderError
from guardrail_core.formats.drive_tiles import vehicle_station

#: The selection panel without a selection: picking is the scene's, labelling the page's.
NO_SELECTION = "Click a point to select its segment (shift + drag: many); label it on the page."
#: The layers an operator can show or hide, and whether each shows at first: the camera frusta
#: stand in the foreground, between the road and the rails, and hide the selection.
LAYERS = {
    "points": "Points",
    "other": "Points labelled other",
    "meshes": "Meshes",
    "cameras": "Cameras",
}
LAYERS_SHOWN = {"points": True, "other": True, "meshes": True, "cameras": False}
#: The selection is drawn over the points, larger so that it shows through them: selecting
#: sends the few points selected, not new colours for every point shown.
SELECTION_NODE = "/drive/selection"
SELECTION_SIZE = 1.6  # times the points' size


class ReviewScene(TuningPanel, LassoTool):
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
        self.layers = dict(LAYERS_SHOWN)
        self.point_size_m = 0.04
        self._lock = threading.RLock()
        self._cloud: viser.PointCloudHandle | None = None
        self._selection_cloud: viser.PointCloudHandle | None = None
        self._frusta: list[viser.CameraFrustumHandle] = []
        self._meshes: dict[int, viser.GlbHandle | viser.MeshHandle] = {}
        self._mesh_files: dict[int, Path] = {}  # run id -> its GLB, read when near the window
        self._mesh_stations: dict[int, tuple[float, float]] = {}  # metres along the drive
        self._shown_mesh: dict[int, trimesh.Trimesh] = {}  # per run: the mesh now shown
        self._ghosts: dict[int, viser.MeshHandle] = {}
        self._fly_on_select = True
        self._quiet_sliders = False  # set while the code, not an operator, moves the sliders
        self._tuner: RunTuner | None = None
        # A slider's re-run starts at once; moves made meanwhile collapse into one more.
        self._tune_runner = LatestOnly(self.retune)
        # One re-run at a time: the runner's and a direct call's (tests, the API).
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
            self._send_cloud()
            self._send_selection()
        self._add_cameras()
        self.show_meshes_near()
        self._window_text.content = (
            f"{start_m:.0f}-{start_m + self.window_m:.0f} m of "
            f"{hi - lo:.0f} m · {len(self.shown):,} points"
        )
        return time.perf_counter() - clock

    def _send_cloud(self) -> None:
        """Send the window's points (those the layers show) with their colours."""
        keep = self._kept()
        self._cloud = self.server.scene.add_point_cloud(
            "/drive/points",
            points=self.shown.xyz[keep].astype(np.float32),
            colors=self._colours()[keep],
            point_size=self.point_size_m,
            point_shape="circle",
            precision="float32",
            visible=self.layers["points"],
        )

    def _send_selection(self) -> None:
        """Draw the selection over the points: the points shown (those the layers show) of the
        selected segments, or of the lasso, in magenta."""
        session = self.session
        shown = self.shown
        if len(session.lasso):  # a lasso selects points, not whole segments
            chosen = np.isin(shown.index, session.lasso, assume_unique=True)
        else:
            chosen = np.isin(shown.segment, session.selection)
        kept = np.zeros(len(shown), bool)
        kept[self._kept()] = True
        xyz = shown.xyz[chosen & kept].astype(np.float32)
        with self._lock:
            if self._selection_cloud is not None:
                self._selection_cloud.remove()
                self._selection_cloud = None
            if len(xyz):
                self._selection_cloud = self.server.scene.add_point_cloud(
                    SELECTION_NODE,
                    points=xyz,
                    colors=np.broadcast_to(SELECTED, xyz.shape).copy(),
                    point_size=SELECTION_SIZE * self.point_size_m,
                    point_shape="circle",
                    precision="float32",
                    visible=self.layers["points"],
                )

    def _kept(self) -> np.ndarray | slice:
        """The points shown that the layers keep: all, or, with the layer "points labelled
        other" off, those of segments labelled guardrail."""
        if self.layers["other"]:
            return slice(None)
        segment = self.shown.segment
        label = self.session.effective_label()
        return (segment >= 0) & label[np.maximum(segment, 0)]

    def _colours(self) -> np.ndarray:
        """(K, 3) uint8 colours of the points shown in the colour mode (the selection is drawn
        over them: :meth:`_send_selection`)."""
        session = self.session
        return point_colours(
            self.mode,
            self.shown.segment,
            segment_label=session.effective_label(),
            raw_label=session.run.segments["raw_label"],
            probability=session.run.segments["probability"],
            point_labels=session.labels_at(self.shown.index),
            point_class=self.shown.point_class,
        )

    def recolour(self) -> float:
        """Recolour the points shown (after a relabel, new predictions or another mode);
        returns the seconds it took."""
        clock = time.perf_counter()
        with self._lock:
            if not self.layers["other"]:  # which points show follows the labels
                self._send_cloud()
            elif self._cloud is not None:
                self._cloud.colors = self._colours()
        self._legend.content = colour_legend(self.mode)
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
        for i in inside if self.layers["cameras"] else ():
            image = drive.images[i]
            camera = drive.cameras[image.camera]
            fov = 2 * np.arctan2(camera.height / 2, camera.K[1, 1])
            T = image.T_world_camera
            self._frusta.append(
                self.server.scene.add_camera_frustum(
                    f"/drive/cameras/{i:05d}",
                    fov=float(fov),
                    aspect=camera.width / camera.height,
                    scale=0.25,
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
                mesh = trimesh.load(path, file_type="glb", force="mesh")
                assert isinstance(mesh, trimesh.Trimesh)  # force="mesh" joins the scene's
                self._meshes[run_id] = self.server.scene.add_mesh_simple(
                    mesh_node(run_id),
                    vertices=mesh.vertices.astype(np.float32),
                    faces=mesh.faces.astype(np.uint32),
                    color=MESH_COLOUR,
                    visible=self.layers["meshes"],
                )
            elif not near and run_id in self._meshes and run_id not in self._shown_mesh:
                self._meshes.pop(run_id).remove()

    # -- picking ----------------------------------------------------------------------------

    def _segment_points(self) -> TilePoints:
        """The points shown that lie in a segment and that the layers show (what a click or a
        rectangle may pick)."""
        shown = self.shown
        keep = np.zeros(len(shown), bool)
        keep[self._kept()] = True
        if not self.layers["points"]:
            keep[:] = False
        return shown.take(np.flatnonzero(keep & (shown.segment >= 0)))

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
        self._select_in_view([int(candidates.segment[hit])])

    def _select_in_view(self, segments: np.ndarray | list[int]) -> None:
        """Select what the operator picked in this view: the camera stays where it is."""
        self._fly_on_select = False
        try:
            self.session.select(segments)
        finally:
            self._fly_on_select = True

    def _on_rect_select(self, event: viser.SceneRectSelectEvent) -> None:
        camera = event.client.camera
        candidates = self._segment_points()
        uv, in_front = project_to_screen(
            candidates.xyz, camera_pose(camera), camera.fov, camera.aspect
        )
        inside = in_rectangle(
            uv, in_front, np.asarray(event.screen_min), np.asarray(event.screen_max)
        )
        segments = np.unique(candidates.segment[inside])
        if len(segments):
            self._select_in_view(segments)

    def fly_to(self, segment: int) -> None:
        """Move the window and every browser's camera to a segment."""
        target = self.session.run.segments["centroid"][segment]
        trajectory = self.session.drive.trajectory
        scanned = float(np.mean(self.session.run.segments["time"][segment]))
        self._fly_to_place(target, float(np.interp(scanned, trajectory.time, self.vehicle_station)))

    def _fly_to_place(self, target: np.ndarray, station: float, distance_m: float = 8.0) -> None:
        """Move the window to ``station`` (metres along the drive) if it lies outside, and every
        browser's camera to look at ``target`` (3,) from ``distance_m``."""
        if not self.start_m <= station < self.start_m + self.window_m:
            self.show_window(station - self.window_m / 2)
        for client in self.server.get_clients().values():
            self._look_at(client, target, distance_m=distance_m)

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
        self._tune_runner.close()

    # -- session events ---------------------------------------------------------------------

    def _on_session_event(self, event: str, segments: np.ndarray) -> None:
        if event == "reconstruction":
            self.load_meshes()
            return
        if event == "lasso_cancelled":  # the page was reloaded, or Escape pressed there
            with self._lock:
                self._end_lasso()
        if event != "selection":  # the labels or predictions changed: so do the colours
            self.recolour()
        self._send_selection()  # which points show may have changed with the labels
        self._show_selection()
        if event == "selection" and len(segments) and self._fly_on_select:
            self.fly_to(int(segments[0]))

    def _layer_toggle(self, name: str, box: Any) -> Any:
        """The callback of layer ``name``'s checkbox."""
        return lambda _: self.show_layer(name, box.value)

    def show_layer(self, name: str, on: bool) -> None:
        """Show or hide a layer of :data:`LAYERS`."""
        self.layers[name] = bool(on)
        with self._lock:
            if name == "points":
                for cloud in (self._cloud, self._selection_cloud):
                    if cloud is not None:
                        cloud.visible = self.layers["points"]
            elif name == "other":
                self._send_cloud()
                self._send_selection()
            elif name == "meshes":
                for handle in [*self._meshes.values(), *self._ghosts.values()]:
                    handle.visible = self.layers["meshes"]
        if name == "cameras":
            self._add_cameras()

    def step(self, direction: int) -> None:
        """Move the window back (-1) or forward (+1) along the trajectory, overlapping by 20%."""
        self.show_window(self.start_m + direction * 0.8 * self.window_m)

    # -- GUI --------------------------------------------------------------------------------

    def _build_gui(self) -> None:
        gui = self.server.gui

        with gui.add_folder("View"):
            mode = gui.add_dropdown("Colour by", COLOUR_MODES, initial_value="label")
            self._legend = gui.add_html(colour_legend(self.mode))
            self._window_text = gui.add_markdown("")
            back = gui.add_button("◀ Back", icon=None)
            forward = gui.add_button("Forward ▶")
            size = gui.add_slider(
                "Point size (cm)", min=1, max=15, step=1, initial_value=100 * self.point_size_m
            )
            layers = {
                name: gui.add_checkbox(label, initial_value=self.layers[name])
                for name, label in LAYERS.items()
            }

        @mode.on_update
        def _(_: Any) -> None:
            self.mode = mode.value
            self.recolour()

        @size.on_update
        def _(_: Any) -> None:
            self.point_size_m = float(size.value) / 100
            if self._cloud is not None:
                self._cloud.point_size = self.point_size_m
            if self._selection_cloud is not None:
                self._selection_cloud.point_size = SELECTION_SIZE * self.point_size_m

        for name, box in layers.items():
            box.on_update(self._layer_toggle(name, box))

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

        self._build_tuning_gui(gui)

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
