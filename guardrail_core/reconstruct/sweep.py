"""Sweep a unit model into a triangle mesh in unit coordinates (Matsumoto et al. 2019, §4.3-4.4).

Pipes are circles swept along their axis polylines (§4.3); a beam's section curve becomes a thin
closed plate swept straight along x from 0 to the unit length (§4.4). Poles are not part of the
unit mesh: they stand once per pole in the run (:mod:`guardrail_core.reconstruct.assemble`).

Unit coordinates (:mod:`guardrail_core.reconstruct.unit_frame`): x along the unit from its first
pole, y above the ground line, z toward the road; metres.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import trimesh

from guardrail_core.errors import ReconstructionError
from guardrail_core.geom.mesh import Mesh, plate, tube
from guardrail_core.params import StageParams, param
from guardrail_core.reconstruct.model import Pipe, UnitModel

UNIT_TYPES = ("pipe", "beam")


@dataclass(frozen=True)
class SweepParams(StageParams):
    """How unit and run models become meshes."""

    renamed: ClassVar[Mapping[str, str]] = {"beam_thickness": "beam_thickness_m"}

    tube_sections: int = param(12, ge=3, doc="Segments of a pipe's circle (the simulator's 12).")
    pole_sections: int = param(16, ge=3, doc="Segments of a pole's circle (the simulator's 16).")
    beam_thickness_m: float = param(
        0.003,
        unit="m",
        gt=0,
        lt=0.1,
        doc="The display thickness of a beam plate (real beams: 3-4 mm).",
    )
    caps: bool = param(
        True, doc="Close the ends of pipes and beam plates (each part is then watertight)."
    )
    pole_cap: bool = param(
        True, doc="A hemispherical dome on each pole, topping out at the pole's height."
    )
    dome_rings: int = param(4, ge=1, doc="Latitude rings of a pole's dome.")
    min_mitre_cos: float = param(
        0.3,
        gt=0,
        le=1,
        doc="The cosine of half a bend below which a mitre stops stretching (bends sharper than "
        "about 145° would otherwise spike).",
    )
    rail_color: tuple[int, int, int, int] = param(
        (225, 225, 215, 255), ge=0, le=255, doc="RGBA (0-255) vertex colour of pipes and beams."
    )
    pole_color: tuple[int, int, int, int] = param(
        (150, 150, 145, 255), ge=0, le=255, doc="RGBA (0-255) vertex colour of poles."
    )


def empty_mesh() -> trimesh.Trimesh:
    """A mesh with no vertices and no faces."""
    return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), process=False)


def to_trimesh(
    parts: list[Mesh], color: tuple[int, int, int, int] | None = None
) -> trimesh.Trimesh:
    """Concatenate ``(vertices, faces)`` pairs into one :class:`trimesh.Trimesh` (not merged)."""
    parts = [(v, f) for v, f in parts if len(f)]
    if not parts:
        return empty_mesh()
    offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
    vertices = np.concatenate([np.asarray(v, np.float64) for v, _ in parts])
    faces = np.concatenate(
        [np.asarray(f, np.int64) + o for (_, f), o in zip(parts, offsets, strict=True)]
    )
    colors = None if color is None else np.tile(np.asarray(color, np.uint8), (len(vertices), 1))
    return trimesh.Trimesh(vertices, faces, vertex_colors=colors, process=False)


def check_unit_model(model: UnitModel) -> None:
    """Raise :class:`ReconstructionError` unless ``model`` can be swept."""
    if model.type not in UNIT_TYPES:
        raise ReconstructionError(
            f"unit model type must be one of {UNIT_TYPES}, got {model.type!r}"
        )
    if not (np.isfinite(model.length) and model.length > 0):
        raise ReconstructionError(
            f"unit model length must be a positive number, got {model.length}"
        )
    for k, pipe in enumerate(model.pipes):
        axis = np.asarray(pipe.axis, np.float64)
        if axis.ndim != 2 or axis.shape[1] != 3 or len(axis) < 2 or not np.isfinite(axis).all():
            raise ReconstructionError(
                f"pipe {k}: axis must be a finite (K, 3) polyline with K >= 2, got {axis.shape}"
            )
        if not (np.isfinite(pipe.radius) and pipe.radius > 0):
            raise ReconstructionError(f"pipe {k}: radius must be positive, got {pipe.radius}")
    if model.section is not None:
        section = np.asarray(model.section, np.float64)
        if section.ndim != 2 or section.shape[1] != 2 or not np.isfinite(section).all():
            raise ReconstructionError(
                f"beam section must be a finite (M, 2) array of (z, y), got {section.shape}"
            )


def pipe_mesh(pipe: Pipe, params: SweepParams = SweepParams()) -> Mesh:
    """One pipe as a tube, unit coordinates: ``(vertices (V, 3), faces (F, 3))``, metres.

    The circle of ``pipe.radius`` is swept along ``pipe.axis`` with exact mitres at bends, so every
    vertex lies ``radius`` from the lines of its adjacent axis segments.

    References
    ----------
    Matsumoto et al. 2019, §4.3: "cylindrical pipes are generated by sweeping circles along
    polylines".
    """
    try:
        return tube(
            pipe.axis,
            pipe.radius,
            sections=params.tube_sections,
            caps=params.caps,
            exact_mitre=True,
        )
    except ValueError as exc:
        raise ReconstructionError(f"pipe cannot be swept: {exc}") from exc


def beam_mesh(section: np.ndarray, length: float, params: SweepParams = SweepParams()) -> Mesh:
    """A beam section (M, 2) of (z, y) metres as a plate swept along x from 0 to ``length`` (m).

    References
    ----------
    Matsumoto et al. 2019, §4.4.
    """
    path = np.array([[0.0, 0.0, 0.0], [float(length), 0.0, 0.0]])
    across = np.broadcast_to([0.0, 0.0, 1.0], path.shape)  # section z -> unit z
    up = np.broadcast_to([0.0, 1.0, 0.0], path.shape)  # section y -> unit y
    try:
        return plate(section, params.beam_thickness_m, path, across, up, caps=params.caps)
    except ValueError as exc:
        raise ReconstructionError(f"beam section cannot be swept: {exc}") from exc


def unit_mesh(model: UnitModel, params: SweepParams = SweepParams()) -> trimesh.Trimesh:
    """The unit model as one mesh in unit coordinates (metres), without poles.

    Parameters
    ----------
    model : UnitModel
        Pipe type: every pipe swept as a tube. Beam type: ``model.section`` (M, 2) (z, y) swept
        as a plate of ``params.beam_thickness_m`` along x in [0, ``model.length``]. A model with no
        pipes or no section gives an empty mesh.
    params : SweepParams

    Returns
    -------
    trimesh.Trimesh
        Vertices (V, 3) float64 in unit coordinates, coloured ``params.rail_color``; each pipe or
        plate is a closed, outward-facing body when ``params.caps``.

    References
    ----------
    Matsumoto et al. 2019, §4.3 (pipes) and §4.4 (beams).
    """
    check_unit_model(model)
    parts: list[Mesh] = []
    if model.type == "pipe":
        # §4.3: "cylindrical pipes are generated by sweeping circles along polylines"
        parts = [pipe_mesh(p, params) for p in model.pipes]
    elif model.section is not None and len(model.section) >= 2:
        # §4.4: the section curve swept along the direction of the guardrail
        parts = [beam_mesh(model.section, model.length, params)]
    return to_trimesh(parts, params.rail_color)
