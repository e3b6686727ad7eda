"""The road: a centreline of straights and arcs, its cross-section, and its surface meshes.

Positions along the road are given by ``s`` (metres along the centreline) and ``lateral``
(metres to the left of the centreline, negative to the right). The carriageway is crowned;
curbs raise the sidewalks; a grass verge runs beyond them, level or on an embankment that rises
or falls away from the road, with or without a ditch along its foot (:class:`Roadside`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from guardrail_core.classes import TruthClass
from guardrail_core.geom.mesh import grid_surface
from guardrail_core.synth.mesh import MeshBuilder

SIDES = {"left": 1.0, "right": -1.0}


@dataclass(frozen=True)
class Roadside:
    """The ground beyond a sidewalk: an embankment and a ditch.

    Attributes
    ----------
    slope : float, m/m, rise of the verge away from the road (negative: it falls, a fill slope
        down from the road; positive: a cut slope up from it)
    ditch_depth_m, ditch_width_m : float, metres, a ditch of rounded section along the sidewalk's
        outer edge (depth 0: none); the slope starts beyond it
    """

    slope: float = 0.0
    ditch_depth_m: float = 0.0
    ditch_width_m: float = 1.0

    @property
    def level(self) -> bool:
        return self.slope == 0.0 and self.ditch_depth_m == 0.0

    def height(self, beyond: np.ndarray) -> np.ndarray:
        """Height (N,) metres over a level verge at ``beyond`` (N,) metres past the sidewalk."""
        d = np.maximum(np.asarray(beyond, np.float64), 0.0)
        w = self.ditch_width_m if self.ditch_depth_m > 0 else 0.0
        ditch = np.where(
            d < w, -0.5 * self.ditch_depth_m * (1 - np.cos(2 * np.pi * d / max(w, 1e-9))), 0.0
        )
        return ditch + self.slope * np.maximum(d - w, 0.0)


@dataclass(frozen=True)
class RoadSpec:
    """Geometry of a road.

    Attributes
    ----------
    segments : tuple of (kind, length_m, curvature_1_per_m)
        ``("straight", L, 0.0)`` or ``("arc", L, k)`` with k > 0 turning left.
    heading_deg : float, initial heading, degrees counter-clockwise from the local +x axis
    lanes : int; lane_width : float, metres
    crown_slope : float, fall of the carriageway from the centre to the edges (m/m)
    grade : float, longitudinal slope (m/m)
    undulation_m : float, amplitude of a gentle vertical wave over the grade
    curb_height, curb_width : float, metres
    sidewalk_left, sidewalk_right : float, metres
    verge : float, metres of grass beyond each sidewalk
    roadside_left, roadside_right : the lie of the verge on each side
    dash_m : (on, off) metres of the dashed lane lines
    """

    segments: tuple[tuple[str, float, float], ...]
    heading_deg: float = 0.0
    lanes: int = 2
    lane_width: float = 3.25
    crown_slope: float = 0.02
    grade: float = 0.01
    undulation_m: float = 0.3
    curb_height: float = 0.15
    curb_width: float = 0.18
    sidewalk_left: float = 2.5
    sidewalk_right: float = 2.5
    verge: float = 6.0
    roadside_left: Roadside = Roadside()
    roadside_right: Roadside = Roadside()
    dash_m: tuple[float, float] = (5.0, 5.0)


class Road:
    """A road sampled every ``step`` metres along its centreline."""

    def __init__(self, spec: RoadSpec, *, step: float = 0.1) -> None:
        self.spec = spec
        lengths = np.array([seg[1] for seg in spec.segments], np.float64)
        curvatures = np.array([seg[2] for seg in spec.segments], np.float64)
        self.length = float(lengths.sum())
        self.s = np.arange(0.0, self.length + step / 2, step)
        ends = np.cumsum(lengths)
        index = np.minimum(np.searchsorted(ends, self.s, side="right"), len(ends) - 1)
        curvature = curvatures[index]
        heading0 = np.deg2rad(spec.heading_deg)
        # Heading is the integral of curvature; positions the integral of the heading vector.
        self.heading = heading0 + np.concatenate([[0.0], np.cumsum(curvature[:-1] * step)])
        mid = self.heading[:-1] + 0.5 * curvature[:-1] * step
        dxy = np.stack([np.cos(mid), np.sin(mid)], axis=1) * step
        self.xy = np.vstack([[0.0, 0.0], np.cumsum(dxy, axis=0)])
        self.half_width = spec.lanes * spec.lane_width / 2

    # ------------------------------------------------------------------ frames and heights
    def centre_height(self, s: np.ndarray) -> np.ndarray:
        """Height (N,) of the crown at ``s`` (N,) metres."""
        s = np.asarray(s, np.float64)
        return self.spec.grade * s + self.spec.undulation_m * np.sin(2 * np.pi * s / 180.0)

    def frame(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centreline ground point, tangent and left normal, each (N, 3), at ``s`` (N,)."""
        s = np.clip(np.asarray(s, np.float64), 0.0, self.length)
        x = np.interp(s, self.s, self.xy[:, 0])
        y = np.interp(s, self.s, self.xy[:, 1])
        heading = np.interp(s, self.s, self.heading)
        z = self.centre_height(s)
        zeros = np.zeros_like(s)
        tangent = np.stack([np.cos(heading), np.sin(heading), zeros], axis=1)
        left = np.stack([-np.sin(heading), np.cos(heading), zeros], axis=1)
        return np.stack([x, y, z], axis=1), tangent, left

    def ground_height(self, s: np.ndarray, lateral: np.ndarray) -> np.ndarray:
        """Height (N,) of the ground surface at (s, lateral): road, curb top, sidewalk or verge."""
        spec = self.spec
        s, lateral = np.broadcast_arrays(np.asarray(s, np.float64), np.asarray(lateral, np.float64))
        a = np.abs(lateral)
        hw = self.half_width
        road = self.centre_height(s) - spec.crown_slope * np.minimum(a, hw)
        # Beyond the curb the sidewalk rises 1% away from the road so rain drains to it.
        off_road = spec.curb_height + 0.01 * np.maximum(a - hw - spec.curb_width, 0.0)
        walk_edge = (
            hw + spec.curb_width + np.where(lateral > 0, spec.sidewalk_left, spec.sidewalk_right)
        )
        beyond = a - walk_edge
        verge = np.where(
            lateral > 0, spec.roadside_left.height(beyond), spec.roadside_right.height(beyond)
        )
        return road + np.where(a > hw, off_road, 0.0) + np.where(beyond > 0, verge, 0.0)

    def point(self, s: np.ndarray, lateral: np.ndarray) -> np.ndarray:
        """Ground points (N, 3) at (s, lateral)."""
        s, lateral = np.broadcast_arrays(np.asarray(s, np.float64), np.asarray(lateral, np.float64))
        centre, _, left = self.frame(s)
        p = centre + lateral[:, None] * left
        p[:, 2] = self.ground_height(s, lateral)
        return p

    def lateral_of(self, side: str, offset: float) -> float:
        """Lateral position of something ``offset`` metres outward from the edge of the road."""
        return SIDES[side] * (self.half_width + offset)

    def sidewalk_width(self, side: str) -> float:
        return self.spec.sidewalk_left if side == "left" else self.spec.sidewalk_right

    def roadside(self, side: str) -> Roadside:
        return self.spec.roadside_left if side == "left" else self.spec.roadside_right

    # ------------------------------------------------------------------ meshes
    def _strip(
        self, s: np.ndarray, l0: float, l1: float, columns: int = 2
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ground from lateral ``l0`` to ``l1`` at the stations ``s``, in ``columns``."""
        laterals = np.linspace(l0, l1, columns)
        grid = np.stack([self.point(s, np.full_like(s, lat)) for lat in laterals], axis=1)
        if l1 < l0:  # keep the faces wound upward
            grid = grid[:, ::-1]
        return grid_surface(grid)

    def mesh_rows(self, step: float = 0.5) -> np.ndarray:
        """(R,) float64 metres: the stations of the rows of the road mesh, ``step`` apart at most."""
        return np.linspace(0.0, self.length, max(2, int(np.ceil(self.length / step)) + 1))

    def build_mesh(
        self, builder: MeshBuilder, *, step: float = 0.5, rows: tuple[int, int] | None = None
    ) -> None:
        """Add the carriageway, markings, curbs, sidewalks and verges to ``builder``.

        ``rows`` (first, last), inclusive, of :meth:`mesh_rows`: only that stretch of road (the
        same triangles as the whole road's there); None: the whole road.
        """
        spec = self.spec
        hw = self.half_width
        s = self.mesh_rows(step)
        if rows is not None:
            s = s[rows[0] : rows[1] + 1]
        # Lane lines: solid edge lines and dashed lines between lanes.
        line_w = 0.15
        solid = [(-hw + 0.1, -hw + 0.1 + line_w), (hw - 0.1 - line_w, hw - 0.1)]
        dashed = [
            (-hw + i * spec.lane_width - line_w / 2, -hw + i * spec.lane_width + line_w / 2)
            for i in range(1, spec.lanes)
        ]
        breaks = sorted({-hw, hw, 0.0, *[v for pair in solid + dashed for v in pair]})
        for l0, l1 in zip(breaks[:-1], breaks[1:], strict=True):
            if (l0, l1) in solid:
                builder.add(
                    self._strip(s, l0, l1),
                    cls=TruthClass.ROAD_MARKING,
                    object_id=0,
                    material="lane_paint",
                )
            elif (l0, l1) in dashed:
                on, off = spec.dash_m
                phase = np.mod(s, on + off) < on
                self._add_dashes(builder, s, phase, l0, l1)
            else:
                builder.add(
                    self._strip(s, l0, l1), cls=TruthClass.ROAD, object_id=0, material="asphalt"
                )
        for side, sign in SIDES.items():
            edge = sign * hw
            outer = sign * (hw + spec.curb_width)
            walk = sign * (hw + spec.curb_width + self.sidewalk_width(side))
            verge = walk + sign * spec.verge
            # Curb face: a vertical strip from the road edge up to the curb top.
            low = self.point(s, np.full_like(s, edge - sign * 1e-4))
            high = self.point(s, np.full_like(s, edge + sign * 1e-4))
            face = np.stack([low, high], axis=1) if sign < 0 else np.stack([high, low], axis=1)
            builder.add(grid_surface(face), cls=TruthClass.CURB, object_id=0, material="concrete")
            builder.add(
                self._strip(s, edge + sign * 1e-4, outer),
                cls=TruthClass.CURB,
                object_id=0,
                material="concrete",
            )
            builder.add(
                self._strip(s, outer, walk), cls=TruthClass.SIDEWALK, object_id=0, material="paving"
            )
            # A level verge is one flat strip; an embankment or a ditch a column every 0.25 m.
            columns = 2 if self.roadside(side).level else int(np.ceil(spec.verge / 0.25)) + 1
            builder.add(
                self._strip(s, walk, verge, columns),
                cls=TruthClass.TERRAIN,
                object_id=0,
                material="grass",
            )

    def _add_dashes(
        self, builder: MeshBuilder, s: np.ndarray, on: np.ndarray, l0: float, l1: float
    ) -> None:
        # Split the rows into runs of painted and bare asphalt.
        edges = np.flatnonzero(np.diff(on.astype(np.int8))) + 1
        for run in np.split(np.arange(len(s)), edges):
            rows = np.append(run, run[-1] + 1) if run[-1] + 1 < len(s) else run
            if len(rows) < 2:
                continue
            painted = bool(on[run[0]])
            builder.add(
                self._strip(s[rows], l0, l1),
                cls=TruthClass.ROAD_MARKING if painted else TruthClass.ROAD,
                object_id=0,
                material="lane_paint" if painted else "asphalt",
            )
