"""The scene mesh that carries truth per face.

The primitives live in :mod:`guardrail_core.geom.mesh` (shared with the reconstruction); each returns
``(vertices (V, 3) float64, faces (F, 3) int64)`` in metres. :class:`MeshBuilder` gathers them
with a truth class, an object id and a material per face, so that a ray hit (a face id) tells at
once what was hit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from guardrail_core.geom.mesh import Mesh
from guardrail_core.synth.materials import MATERIAL_ID


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


def join_meshes(meshes: Sequence[SceneMesh]) -> SceneMesh:
    """One mesh of several, in order: faces renumbered, truth per face kept."""
    if not meshes:
        return MeshBuilder().build()
    offsets = np.cumsum([0, *(len(m.vertices) for m in meshes[:-1])])
    return SceneMesh(
        vertices=np.concatenate([m.vertices for m in meshes]),
        faces=np.concatenate([m.faces + o for m, o in zip(meshes, offsets, strict=True)]).astype(
            np.int32
        ),
        face_class=np.concatenate([m.face_class for m in meshes]),
        face_object=np.concatenate([m.face_object for m in meshes]),
        face_material=np.concatenate([m.face_material for m in meshes]),
    )
