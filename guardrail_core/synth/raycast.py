"""Ray casting against a :class:`~guardrail_core.synth.mesh.SceneMesh` with Open3D."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from guardrail_core.synth.mesh import SceneMesh

#: Open3D's marker for "no triangle hit" in ``primitive_ids``.
MISS = np.iinfo(np.uint32).max


@dataclass(frozen=True)
class Hits:
    """Result of casting N rays.

    Attributes
    ----------
    t : (N,) float64, distance along the (unit) ray to the hit, ``inf`` on a miss
    face : (N,) int64, index of the face hit, -1 on a miss
    normal : (N, 3) float64, unit normal of the face hit (as wound; flip to face the ray)
    """

    t: np.ndarray
    face: np.ndarray
    normal: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.face >= 0


class SceneRaycaster:
    """Casts rays into a scene mesh; coordinates are float32 inside Open3D, so keep them local.

    The local frame's origin is near the drive; float32 then resolves ~0.01 mm at 100 m.
    """

    def __init__(self, mesh: SceneMesh, *, threads: int = 0) -> None:
        self.mesh = mesh
        self._scene = o3d.t.geometry.RaycastingScene(nthreads=threads)
        vertices = o3d.core.Tensor(mesh.vertices.astype(np.float32))  # type: ignore[call-overload]
        faces = o3d.core.Tensor(mesh.faces.astype(np.uint32))  # type: ignore[call-overload]
        self._scene.add_triangles(vertices, faces)

    @staticmethod
    def _rays(origins: np.ndarray, directions: np.ndarray) -> o3d.core.Tensor:
        origins = np.broadcast_to(np.asarray(origins, np.float32), np.shape(directions))
        return o3d.core.Tensor(  # type: ignore[call-overload]
            np.concatenate([origins, np.asarray(directions, np.float32)], axis=-1)
        )

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """Cast rays from ``origins`` (N, 3) or (3,) along unit ``directions`` (N, 3)."""
        result = self._scene.cast_rays(self._rays(origins, directions))
        face = result["primitive_ids"].numpy().astype(np.int64)
        miss = face == MISS
        face[miss] = -1
        t = result["t_hit"].numpy().astype(np.float64)
        t[miss] = np.inf
        return Hits(t=t, face=face, normal=result["primitive_normals"].numpy().astype(np.float64))

    def occluded(
        self, origins: np.ndarray, directions: np.ndarray, t_far: float = np.inf
    ) -> np.ndarray:
        """Whether anything lies on each ray closer than ``t_far`` metres (N,) bool (shadows)."""
        rays = self._rays(origins, directions)
        return self._scene.test_occlusions(rays, tfar=float(t_far)).numpy().astype(bool)
