"""Triangle-mesh primitives and the scene mesh that carries truth per face.

Every primitive is a function returning ``(vertices (V, 3) float64, faces (F, 3) int64)`` in
metres; :class:`MeshBuilder` gathers them with a truth class, an object id and a material per
face, so that a ray hit (a face id) tells at once what was hit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from guardrail_core.synth.materials import MATERIAL_ID

Mesh = tuple[np.ndarray, np.ndarray]


@dataclass(frozen=True)
class SceneMesh:
    """All surfaces of a scene as one triangle soup with per-face truth.

    Attributes
    ----------
    vertices : (V, 3) float64, metres, local frame
    faces : (F, 3) int32
    face_class : (F,) uint8, :class:`~guardrail_core.classes.TruthClass` ids
    face_object : (F,) int32, object ids (as in ``truth/objects.json``; 0 = scenery)
    face_material : (F,) uint8, indices into ``materials.MATERIAL_NAMES``
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_class: np.ndarray
    face_object: np.ndarray
    face_material: np.ndarray

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])


class MeshBuilder:
    """Accumulates primitives with their truth; :meth:`build` returns a :class:`SceneMesh`."""

    def __init__(self) -> None:
        self._vertices: list[np.ndarray] = []
        self._faces: list[np.ndarray] = []
        self._class: list[np.ndarray] = []
        self._object: list[np.ndarray] = []
        self._material: list[np.ndarray] = []
        self._n_vertices = 0

    def add(self, mesh: Mesh, *, cls: int, object_id: int, material: str) -> None:
        """Add one primitive; every face gets the same class, object and material."""
        vertices, faces = mesh
        vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        n = len(faces)
        self._vertices.append(vertices)
        self._faces.append(faces + self._n_vertices)
        self._class.append(np.full(n, int(cls), np.uint8))
        self._object.append(np.full(n, int(object_id), np.int32))
        self._material.append(np.full(n, MATERIAL_ID[material], np.uint8))
        self._n_vertices += len(vertices)

    def build(self) -> SceneMesh:
        if not self._faces:
            empty = np.zeros((0, 3))
            return SceneMesh(
                empty,
                empty.astype(np.int32),
                np.zeros(0, np.uint8),
                np.zeros(0, np.int32),
                np.zeros(0, np.uint8),
            )
        return SceneMesh(
            vertices=np.concatenate(self._vertices),
            faces=np.concatenate(self._faces).astype(np.int32),
            face_class=np.concatenate(self._class),
            face_object=np.concatenate(self._object),
            face_material=np.concatenate(self._material),
        )


def _perpendicular_frame(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to ``direction`` (3,) and to each other."""
    d = direction / np.linalg.norm(direction)
    helper = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(d, u)


def tube(polyline: np.ndarray, radius: float, *, sections: int = 12, caps: bool = True) -> Mesh:
    """A circular tube of ``radius`` (m) swept along ``polyline`` (N, 3), N >= 2.

    Frames are carried along the curve by parallel transport, so bends do not twist.
    """
    path = np.asarray(polyline, dtype=np.float64).reshape(-1, 3)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(path, axis=0), axis=1) > 1e-9])
    path = path[keep]
    if len(path) < 2:
        raise ValueError("a tube needs at least two distinct points")
    seg = np.diff(path, axis=0)
    seg /= np.linalg.norm(seg, axis=1, keepdims=True)
    # Tangent at each vertex: average of the adjacent segments.
    tangents = np.vstack([seg[:1], seg[:-1] + seg[1:], seg[-1:]])
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    u, _ = _perpendicular_frame(tangents[0])
    angles = np.linspace(0.0, 2 * np.pi, sections, endpoint=False)
    rings = []
    for t in tangents:
        u = u - np.dot(u, t) * t
        u /= np.linalg.norm(u)
        v = np.cross(t, u)
        rings.append(np.cos(angles)[:, None] * u + np.sin(angles)[:, None] * v)
    # Scale rings at bends so the tube keeps its radius (miter joint).
    scale = np.ones(len(path))
    scale[1:-1] = 1.0 / np.clip(np.einsum("ij,ij->i", seg[:-1], tangents[1:-1]), 0.3, 1.0)
    ring_pts = path[:, None, :] + radius * scale[:, None, None] * np.asarray(rings)
    vertices = ring_pts.reshape(-1, 3)
    n, m = len(path), sections
    i, j = np.meshgrid(np.arange(n - 1), np.arange(m), indexing="ij")
    a = i * m + j
    b = i * m + (j + 1) % m
    c = (i + 1) * m + j
    d = (i + 1) * m + (j + 1) % m
    faces = np.concatenate([np.stack([a, b, d], -1), np.stack([a, d, c], -1)]).reshape(-1, 3)
    if caps:
        vertices = np.vstack([vertices, path[0], path[-1]])
        c0, c1 = len(vertices) - 2, len(vertices) - 1
        jj = np.arange(m)
        cap0 = np.stack([np.full(m, c0), (jj + 1) % m, jj], -1)
        cap1 = np.stack([np.full(m, c1), (n - 1) * m + jj, (n - 1) * m + (jj + 1) % m], -1)
        faces = np.vstack([faces, cap0, cap1])
    return vertices, faces


def cylinder(p0: np.ndarray, p1: np.ndarray, radius: float, *, sections: int = 16) -> Mesh:
    """A capped cylinder of ``radius`` (m) with axis from ``p0`` to ``p1`` (3,)."""
    return tube(np.array([p0, p1], dtype=np.float64), radius, sections=sections, caps=True)


def box(centre: np.ndarray, size: np.ndarray, rotation: np.ndarray | None = None) -> Mesh:
    """A box with ``size`` (3,) metres along the columns of ``rotation`` (3, 3), at ``centre``."""
    mesh = trimesh.creation.box(extents=np.asarray(size, dtype=np.float64))
    vertices = np.asarray(mesh.vertices)
    if rotation is not None:
        vertices = vertices @ np.asarray(rotation, dtype=np.float64).T
    return vertices + np.asarray(centre, dtype=np.float64), np.asarray(mesh.faces)


def segment_box(
    p0: np.ndarray, p1: np.ndarray, width: float, depth: float, up=(0.0, 0.0, 1.0)
) -> Mesh:
    """A bar of rectangular section ``width`` x ``depth`` (m) from ``p0`` to ``p1`` (3,)."""
    p0, p1 = np.asarray(p0, np.float64), np.asarray(p1, np.float64)
    axis = p1 - p0
    length = np.linalg.norm(axis)
    x = axis / length
    up = np.asarray(up, np.float64)
    y = np.cross(up, x)
    if np.linalg.norm(y) < 1e-6:
        y, _ = _perpendicular_frame(x)
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    rotation = np.stack([x, y, z], axis=1)
    return box((p0 + p1) / 2, np.array([length, width, depth]), rotation)


def sphere(centre: np.ndarray, radius: float, *, subdivisions: int = 2) -> Mesh:
    """An icosphere of ``radius`` (m) at ``centre`` (3,)."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(mesh.vertices) + np.asarray(centre, np.float64), np.asarray(mesh.faces)


def sweep(section: np.ndarray, path: np.ndarray, across: np.ndarray, up: np.ndarray) -> Mesh:
    """Sweep an open section curve along a path, as a sheet.

    Parameters
    ----------
    section : (M, 2) float64
        Section curve in (across, up) metres.
    path : (N, 3) float64
        Points of the path the section follows.
    across, up : (N, 3) float64
        Unit directions of the section axes at every path point.
    """
    section = np.asarray(section, np.float64)
    path = np.asarray(path, np.float64)
    pts = (
        path[:, None, :]
        + section[None, :, 0:1] * across[:, None, :]
        + section[None, :, 1:2] * up[:, None, :]
    )
    return grid_surface(pts)


def grid_surface(points: np.ndarray) -> Mesh:
    """A surface through a grid of points (N, M, 3): rows along one direction, columns across."""
    points = np.asarray(points, np.float64)
    n, m = points.shape[:2]
    i, j = np.meshgrid(np.arange(n - 1), np.arange(m - 1), indexing="ij")
    a = i * m + j
    b = i * m + j + 1
    c = (i + 1) * m + j
    d = (i + 1) * m + j + 1
    faces = np.concatenate([np.stack([a, b, d], -1), np.stack([a, d, c], -1)]).reshape(-1, 3)
    return points.reshape(-1, 3), faces
