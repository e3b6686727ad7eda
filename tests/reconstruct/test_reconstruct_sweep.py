"""Unit models swept into meshes in unit coordinates (Matsumoto et al. 2019, §4.3-4.4)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from guardrail_core.errors import ReconstructionError
from guardrail_core.params import ParameterError
from guardrail_core.reconstruct.model import Pipe, UnitModel
from guardrail_core.reconstruct.sweep import SweepParams, pipe_mesh, unit_mesh

L = 2.0


def _pipe_model() -> UnitModel:
    arc = np.linspace(0.0, np.pi, 9)
    pipes = (
        Pipe(np.array([[0.0, 0.95, 0.0], [L, 0.95, 0.0]]), 0.0243, "horizontal", 100),
        Pipe(np.array([[0.0, 0.62, 0.0], [L, 0.62, 0.0]]), 0.017, "horizontal", 80),
        Pipe(np.array([[1.0, 0.0, 0.0], [1.0, 0.95, 0.0]]), 0.017, "vertical", 40),
        Pipe(
            np.c_[1.0 - 0.4 * np.cos(arc), 0.2 + 0.3 * np.sin(arc), np.zeros(9)],
            0.012,
            "curved",
            30,
        ),
    )
    return UnitModel("pipe", L, pipes, pole_radius=0.03, pole_height=1.0, n_units=4)


def _beam_model() -> UnitModel:
    y = np.linspace(0.35, 0.70, 25)
    section = np.c_[0.05 * np.sin((y - 0.35) / 0.35 * 2 * np.pi) ** 2, y]  # a W-like bulge
    return UnitModel("beam", L, section=section, n_units=3)


def _line_distance(points, a, b):
    d = (b - a) / np.linalg.norm(b - a)
    rel = points - a
    return np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)


def test_pipe_vertices_lie_at_the_radius_from_their_axis():
    params = SweepParams(tube_sections=12)
    for pipe in _pipe_model().pipes:
        v, _ = pipe_mesh(pipe, params)
        rings = v[:-2].reshape(len(pipe.axis), params.tube_sections, 3)
        for i in range(len(pipe.axis)):
            for k in (i - 1, i):
                if 0 <= k < len(pipe.axis) - 1:
                    np.testing.assert_allclose(
                        _line_distance(rings[i], pipe.axis[k], pipe.axis[k + 1]),
                        pipe.radius,
                        atol=1e-9,
                    )


def test_pipe_unit_mesh_is_one_closed_body_per_pipe():
    model = _pipe_model()
    mesh = unit_mesh(model)
    bodies = mesh.split(only_watertight=False)
    assert len(bodies) == len(model.pipes)
    assert all(b.is_watertight and b.is_winding_consistent and b.volume > 0 for b in bodies)
    np.testing.assert_allclose(mesh.bounds[:, 0], [0.0, L], atol=1e-12)  # flat end caps
    assert mesh.visual.vertex_colors.shape == (len(mesh.vertices), 4)


def test_capped_pipe_volume():
    pipe = Pipe(np.array([[0.0, 0.5, 0.0], [L, 0.5, 0.0]]), 0.03, "horizontal", 1)
    mesh = unit_mesh(UnitModel("pipe", L, (pipe,)), SweepParams(tube_sections=48))
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(np.pi * 0.03**2 * L, rel=0.02)


def test_beam_plate_spans_the_unit_and_follows_the_section():
    model = _beam_model()
    params = SweepParams(beam_thickness_m=0.004)
    mesh = unit_mesh(model, params)
    assert mesh.is_watertight and mesh.is_winding_consistent
    np.testing.assert_allclose(mesh.bounds[:, 0], [0.0, L], atol=1e-12)
    arc = np.linalg.norm(np.diff(model.section, axis=0), axis=1).sum()
    assert mesh.volume == pytest.approx(params.beam_thickness_m * arc * L, rel=0.02)
    # Every vertex is within half the thickness of the section curve (z, y).
    zy = np.asarray(mesh.vertices)[:, [2, 1]]
    dense = np.array(
        [np.interp(np.linspace(0, 1, 2000), np.linspace(0, 1, 25), c) for c in model.section.T]
    ).T
    nearest = np.min(np.linalg.norm(zy[:, None, :] - dense[None], axis=2), axis=1)
    assert nearest.max() < params.beam_thickness_m / 2 + 1e-3


def test_models_without_geometry_give_empty_meshes():
    assert len(unit_mesh(UnitModel("pipe", L)).faces) == 0
    assert len(unit_mesh(UnitModel("beam", L, section=None)).faces) == 0


@pytest.mark.parametrize(
    "model",
    [
        UnitModel("rope", L),
        UnitModel("pipe", 0.0),
        UnitModel("pipe", L, (Pipe(np.zeros((1, 3)), 0.02, "horizontal", 1),)),
        UnitModel("pipe", L, (Pipe(np.array([[0, 0, 0], [1, np.nan, 0]]), 0.02, "horizontal", 1),)),
        UnitModel("pipe", L, (Pipe(np.array([[0, 0, 0], [1, 0, 0.0]]), -0.02, "horizontal", 1),)),
        UnitModel("pipe", L, (Pipe(np.zeros((3, 3)), 0.02, "horizontal", 1),)),
        UnitModel("beam", L, section=np.zeros((4, 3))),
    ],
)
def test_bad_models_raise(model):
    with pytest.raises(ReconstructionError):
        unit_mesh(model)


@pytest.mark.parametrize(
    "kwargs", [{"tube_sections": 2}, {"beam_thickness_m": 0.0}, {"min_mitre_cos": 0.0}]
)
def test_bad_params_raise(kwargs):
    with pytest.raises(ParameterError, match=f"SweepParams.*{next(iter(kwargs))}"):
        SweepParams(**kwargs)


@pytest.mark.parametrize("color", [(1, 2, 3), (0, 0, 0, 256), (0.5, 0, 0, 255)])
def test_bad_colours_raise(color):
    with pytest.raises(ParameterError, match="rail_color"):
        SweepParams(rail_color=color)


def test_mesh_is_a_trimesh_in_float64():
    mesh = unit_mesh(_pipe_model())
    assert isinstance(mesh, trimesh.Trimesh)
    assert mesh.vertices.dtype == np.float64
