"""Assemble a whole guardrail run in the world frame (Matsumoto et al. 2019, §4.3-4.4).

§4.3: "for reconstructing the overall shape of a guardrail, 3D models of the unit shape are
copied between poles". Each copy of the pipe unit mesh is mapped by its unit's ``T_world_unit``
with x stretched by ``frame.length / model.length``, so that a pipe ending at a pole axis in the
model ends at the next pole's axis in the world. §4.4: a beam is one section curve swept along
the run: here continuously along the poles' ground points, mitred at each interior pole, so a
curved run has no gaps. Every pole stands as a vertical cylinder (with an optional dome cap).

All coordinates are the drive's local frame, metres (add the drive's origin for map coordinates).
"""

from __future__ import annotations

import numpy as np
import trimesh

from guardrail_core.errors import ReconstructionError
from guardrail_core.geom.mesh import Mesh, cylinder, dome, outward, plate
from guardrail_core.reconstruct.model import Pole, RunModel, UnitModel
from guardrail_core.reconstruct.sweep import (
    SweepParams,
    check_unit_model,
    empty_mesh,
    to_trimesh,
    unit_mesh,
)
from guardrail_core.reconstruct.unit_frame import UP


def pole_mesh(pole: Pole, params: SweepParams = SweepParams()) -> Mesh:
    """One pole: a closed vertical cylinder from its ground point up to ``pole.height`` (m).

    With ``params.pole_cap`` the top is a hemisphere of the pole's radius whose apex is at the
    pole's height (the cylinder stops one radius lower); the result is one watertight body
    with outward faces either way. Returns ``(vertices (V, 3), faces (F, 3))``, world, metres.
    """
    base = np.asarray(pole.position, np.float64)
    radius, height, m = float(pole.radius), float(pole.height), params.pole_sections
    if not (params.pole_cap and height > radius):
        return outward(cylinder(base, base + height * UP, radius, sections=m))
    body = height - radius
    cap_vertices, cap_faces = dome(
        base + body * UP, radius, sections=m, rings=params.dome_rings
    )  # its first ring is the cylinder's top ring, lon = 0 .. 2 pi counter-clockwise
    lon = np.linspace(0.0, 2 * np.pi, m, endpoint=False)
    bottom = base + radius * np.stack([np.cos(lon), np.sin(lon), np.zeros(m)], axis=1)
    vertices = np.vstack([bottom, base, cap_vertices])
    j = np.arange(m)
    a, b = j, (j + 1) % m  # bottom ring
    c, d = m + 1 + j, m + 1 + (j + 1) % m  # the dome's equator
    side = np.concatenate([np.stack([a, b, d], -1), np.stack([a, d, c], -1)])
    floor = np.stack([np.full(m, m), b, a], -1)
    return outward((vertices, np.vstack([side, floor, cap_faces + m + 1])))


def _check_run(run: RunModel) -> np.ndarray:
    """Validate the run's poles and units; return the ground points (P, 3) float64."""
    positions = np.array([np.asarray(p.position, np.float64) for p in run.poles]).reshape(-1, 3)
    if not np.isfinite(positions).all():
        raise ReconstructionError(f"run {run.run_id}: pole positions must be finite")
    for k, pole in enumerate(run.poles):
        if not (pole.radius > 0 and pole.height > 0):
            raise ReconstructionError(
                f"run {run.run_id}: pole {k} needs a positive radius and height, got "
                f"{pole.radius} and {pole.height}"
            )
    expected = max(len(run.poles) - 1, 0)
    if run.model is not None and len(run.units) != expected:
        raise ReconstructionError(
            f"run {run.run_id}: {len(run.poles)} poles need {expected} units, got {len(run.units)}"
        )
    return positions


def _copied_units(run: RunModel, model: UnitModel, params: SweepParams) -> trimesh.Trimesh:
    """The unit mesh copied into every unit of the run, stretched to reach the next pole."""
    template = unit_mesh(model, params)
    if len(template.faces) == 0 or not run.units:
        return empty_mesh()
    vertices = np.asarray(template.vertices)  # (n, 3) unit coordinates
    faces = np.asarray(template.faces)  # (f, 3)
    stretch = np.array([u.length / model.length for u in run.units])  # (U,)
    T_world_unit = np.stack([u.T_world_unit for u in run.units])  # (U, 4, 4)
    # §4.3: the unit copied between poles; x scaled so x = model.length lands on the next pole
    A = (
        T_world_unit[:, :3, :3]
        * np.stack([stretch, np.ones_like(stretch), np.ones_like(stretch)], 1)[:, None, :]
    )
    world = np.einsum("kij,nj->kni", A, vertices) + T_world_unit[:, None, :3, 3]  # (U, n, 3)
    all_faces = faces[None] + (np.arange(len(run.units)) * len(vertices))[:, None, None]
    colors = np.tile(np.asarray(params.rail_color, np.uint8), (world.shape[0] * world.shape[1], 1))
    return trimesh.Trimesh(
        world.reshape(-1, 3), all_faces.reshape(-1, 3), vertex_colors=colors, process=False
    )


def beam_path(
    positions: np.ndarray, min_mitre_cos: float = SweepParams.min_mitre_cos
) -> tuple[np.ndarray, np.ndarray]:
    """The horizontal across-directions of a beam swept through pole ground points.

    Parameters
    ----------
    positions : (P, 3) float64, metres: ground points in order (road on the right), P >= 2
    min_mitre_cos : float: floor of the mitre's cosine (see :class:`SweepParams`)

    Returns
    -------
    across : (P, 3) float64
        Horizontal vectors toward the road: the unit normal ``along x up`` at the end poles; at an
        interior pole the bisector of the two units' normals scaled by 1 / cos(half the turn), so
        a section offset z stays z away from both units' vertical planes (a mitred joint).
    normals : (P - 1, 3) float64: each unit's horizontal normal
    """
    horizontal = np.diff(positions, axis=0) * np.array([1.0, 1.0, 0.0])
    length = np.linalg.norm(horizontal, axis=1, keepdims=True)
    if (length < 1e-6).any():
        k = int(np.argmin(length))
        raise ReconstructionError(f"poles {k} and {k + 1} stand at the same place")
    normals = np.cross(horizontal / length, UP)
    across = np.vstack([normals[:1], normals[:-1] + normals[1:], normals[-1:]])
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    cos_half = np.einsum("ij,ij->i", normals[:-1], across[1:-1])
    across[1:-1] /= np.clip(cos_half, min_mitre_cos, 1.0)[:, None]
    return across, normals


def _swept_beam(
    run: RunModel, model: UnitModel, positions: np.ndarray, params: SweepParams
) -> trimesh.Trimesh:
    """§4.4: the beam's section swept once along the whole run, through every pole."""
    section = model.section
    if section is None or len(section) < 2 or len(positions) < 2:
        return empty_mesh()
    across, _ = beam_path(positions, params.min_mitre_cos)
    up = np.broadcast_to(UP, positions.shape)
    try:
        mesh = plate(section, params.beam_thickness_m, positions, across, up, caps=params.caps)
    except ValueError as exc:
        raise ReconstructionError(f"run {run.run_id}: beam cannot be swept: {exc}") from exc
    return to_trimesh([mesh], params.rail_color)


def run_parts(run: RunModel, params: SweepParams = SweepParams()) -> dict[str, trimesh.Trimesh]:
    """The run's meshes by part, world frame (local, metres), vertex-coloured.

    Returns
    -------
    dict
        ``"pipes"`` (pipe model: the unit copied into each of the P - 1 units) or ``"beam"``
        (beam model: one plate through all poles), absent when ``run.model`` is None; and
        ``"poles"`` always (P closed cylinders; empty for a run without poles).

    References
    ----------
    Matsumoto et al. 2019, §4.3 (copies between poles) and §4.4 (the beam swept along the run).
    """
    positions = _check_run(run)
    parts: dict[str, trimesh.Trimesh] = {}
    if run.model is not None:
        check_unit_model(run.model)
        if run.model.type == "beam":
            parts["beam"] = _swept_beam(run, run.model, positions, params)
        else:
            parts["pipes"] = _copied_units(run, run.model, params)
    parts["poles"] = to_trimesh([pole_mesh(p, params) for p in run.poles], params.pole_color)
    return parts


def run_mesh(run: RunModel, params: SweepParams = SweepParams()) -> trimesh.Trimesh:
    """The whole run as one mesh in the world frame (local, metres): rails and poles.

    Parameters
    ----------
    run : RunModel
        Poles in order, P - 1 unit frames and the unit model. ``model`` None gives the poles
        only; no poles gives an empty mesh.
    params : SweepParams

    Returns
    -------
    trimesh.Trimesh
        Vertex-coloured; not merged, so each pipe copy, the beam plate and each pole stay
        separate closed bodies (the mesh as a whole is not watertight where rails meet poles).

    References
    ----------
    Matsumoto et al. 2019, §4.3-4.4.
    """
    parts = [(k, m) for k, m in run_parts(run, params).items() if len(m.faces)]
    if not parts:
        return empty_mesh()
    offsets = np.cumsum([0] + [len(m.vertices) for _, m in parts[:-1]])
    vertices = np.concatenate([np.asarray(m.vertices) for _, m in parts])
    faces = np.concatenate(
        [np.asarray(m.faces) + o for (_, m), o in zip(parts, offsets, strict=True)]
    )
    colors = np.concatenate(
        [
            np.tile(params.pole_color if k == "poles" else params.rail_color, (len(m.vertices), 1))
            for k, m in parts
        ]
    ).astype(np.uint8)
    return trimesh.Trimesh(vertices, faces, vertex_colors=colors, process=False)
