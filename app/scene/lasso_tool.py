"""The 3D scene's lasso: click the corners of a polygon around points, close it, and the
segment points inside (as the view showed them at the first corner) become the selection; the
page labels those points alone.

:class:`LassoTool` is a part of :class:`app.scene.viewer.ReviewScene`: it uses the scene's
server, session, selection text and picking.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import viser

from app.run_tiles import TilePoints
from app.scene.picking import camera_pose, in_polygon, project_to_screen
from app.session import ReviewSession

#: The lasso being drawn: its node, colour, and how far in front of the camera (metres).
LASSO_NODE = "/lasso"
LASSO_COLOUR = (255, 0, 220)
LASSO_DRAW_M = 2.0
LASSO_HELP = (
    "**Lasso:** click the corners of a polygon around the points, then *Close the lasso*; "
    "the page labels the points inside (g, o)."
)


class LassoTool:
    """The lasso half of the review scene (a mixin of :class:`~app.scene.viewer.ReviewScene`)."""

    # What the scene holds and this tool uses (set by ReviewScene.__init__ and _build_gui).
    server: viser.ViserServer
    session: ReviewSession
    _lock: threading.RLock
    _fly_on_select: bool
    _lasso: list[tuple[np.ndarray, np.ndarray]] | None
    _lasso_camera: tuple[np.ndarray, float, float] | None
    _lasso_line: viser.LineSegmentsHandle | None
    _lasso_start: Any
    _lasso_close: Any
    _lasso_cancel: Any
    _selection_text: Any
    _segment_points: Callable[[], TilePoints]
    _show_selection: Callable[[], None]

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
                self._lasso_camera = camera_pose(camera), float(camera.fov), float(camera.aspect)
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
