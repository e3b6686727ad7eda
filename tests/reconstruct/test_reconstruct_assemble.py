"""A run assembled in the world: unit copies between poles, one swept beam, poles (§4.3-4.4)."""

from __future__ import annotations

import numpy as np
import pytest

from guardrail_core.errors import ReconstructionError
from guardrail_core.reconstruct.assemble import beam_path, pole_mesh, run_mesh, run_parts
from guardrail_core.reconstruct.model import Pipe, Pole, RunModel, UnitModel
from guardrail_core.reconstruct.sweep import SweepParams, unit_mesh
from guardrail_core.reconstruct.unit_frame import UnitFrame

MODEL_LENGTH = 2.0
RAIL_Y = 0.8


def _run(positions: np.ndarray, model: UnitModel | None, run_id: int = 1) -> RunModel:
    poles = [Pole(p, 0.03, 1.0, 50) for p in positions]
    units = [UnitFrame.between(a, b) for a, b in zip(positions[:-1], positions[1:], strict=True)]
    return RunModel(run_id, poles, units, model, np.ones(len(units), bool), 1000)


def _graded_positions() -> np.ndarray:
    """Five poles, spacing 1.9-2.2 m, a gentle bend and a grade."""
    rng = np.random.default_rng(5)
    heading = np.cumsum(rng.uniform(-0.1, 0.1, 4))
    steps = rng.uniform(1.9, 2.2, 4)[:, None] * np.c_[np.cos(heading), np.sin(heading)]
    xy = np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)]) + [100.0, -50.0]
    return np.c_[xy, 3.0 + 0.04 * xy[:, 0]]


def _pipe_model() -> UnitModel:
    pipes = (
        Pipe(np.array([[0.0, RAIL_Y, 0.0], [MODEL_LENGTH, RAIL_Y, 0.0]]), 0.024, "horizontal", 9),
        Pipe(np.array([[1.0, 0.0, 0.0], [1.0, RAIL_Y, 0.0]]), 0.017, "vertical", 9),
    )
    return UnitModel("pipe", MODEL_LENGTH, pipes, pole_radius=0.03, pole_height=1.0, n_units=4)


def _beam_model() -> UnitModel:
    y = np.linspace(0.35, 0.7, 15)
    return UnitModel(
        "beam", MODEL_LENGTH, section=np.c_[0.04 * np.sin(np.pi * (y - 0.35) / 0.35), y]
    )


def test_unit_copied_between_every_pair_of_poles_reaches_the_poles():
    positions = _graded_positions()
    run = _run(positions, _pipe_model())
    pipes = run_parts(run)["pipes"]
    template = unit_mesh(run.model)
    n = len(template.vertices)
    assert len(pipes.vertices) == (len(positions) - 1) * n  # P - 1 copies
    assert len(pipes.split(only_watertight=False)) == (len(positions) - 1) * 2
    # The horizontal pipe's end caps (its first tube's last two vertices) sit on the pole axes.
    n_first = len(template.split(only_watertight=False)[0].vertices)
    world = np.asarray(pipes.vertices).reshape(len(positions) - 1, n, 3)
    up = np.array([0.0, 0.0, RAIL_Y])
    np.testing.assert_allclose(world[:, n_first - 2], positions[:-1] + up, atol=1e-9)
    np.testing.assert_allclose(world[:, n_first - 1], positions[1:] + up, atol=1e-9)


def test_beam_is_one_closed_plate_with_mitres_at_interior_poles():
    t = np.linspace(0.0, 1.2, 7)  # poles on a 10 m arc, road on the right (inside)
    positions = np.c_[10 * np.sin(t), 10 * (1 - np.cos(t)) * -1, 0.1 * t]
    run = _run(positions, _beam_model())
    beam = run_parts(run)["beam"]
    assert beam.is_watertight and beam.is_winding_consistent and beam.volume > 0
    assert len(beam.split(only_watertight=False)) == 1  # no gap anywhere
    _, normals = beam_path(positions)
    rings = np.asarray(beam.vertices).reshape(len(positions), -1, 3)
    for i in range(1, len(positions) - 1):
        rel = rings[i] - positions[i]
        # A section offset z is z away from both adjacent units' vertical planes.
        np.testing.assert_allclose(rel @ normals[i - 1], rel @ normals[i], atol=1e-9)
    # The beam starts square across the run, in the vertical plane through the first pole.
    rel0 = rings[0] - positions[0]
    np.testing.assert_allclose(rel0[:, :2] @ np.cross(normals[0], [0, 0, 1.0])[:2], 0.0, atol=1e-9)


def test_poles_are_closed_cylinders_up_to_their_height():
    positions = _graded_positions()
    run = _run(positions, None)
    parts = run_parts(run, SweepParams(pole_sections=64))
    assert list(parts) == ["poles"]
    bodies = parts["poles"].split(only_watertight=False)
    assert len(bodies) == len(positions)
    r, h = 0.03, 1.0
    expected = np.pi * r**2 * (h - r) + 2 / 3 * np.pi * r**3
    for body in bodies:
        assert body.is_watertight and body.is_winding_consistent
        assert body.volume == pytest.approx(expected, rel=0.02)
        assert np.ptp(np.asarray(body.vertices)[:, 2]) == pytest.approx(h, abs=1e-12)
    flat = pole_mesh(run.poles[0], SweepParams(pole_cap=False))
    assert np.ptp(flat[0][:, 2]) == pytest.approx(h)


def test_run_mesh_joins_parts_and_handles_missing_models():
    positions = _graded_positions()
    run = _run(positions, _pipe_model())
    parts = run_parts(run)
    mesh = run_mesh(run)
    assert len(mesh.vertices) == sum(len(m.vertices) for m in parts.values())
    assert mesh.visual.vertex_colors.shape == (len(mesh.vertices), 4)
    assert len(run_mesh(_run(positions, None)).split(only_watertight=False)) == len(positions)
    empty = RunModel(2, [], [], None, np.zeros(0, bool), 0, ["no poles found"])
    assert len(run_mesh(empty).faces) == 0
    one_pole = _run(positions[:1], _beam_model())
    assert len(run_parts(one_pole)["beam"].faces) == 0


def test_bad_runs_raise():
    positions = _graded_positions()
    run = _run(positions, _pipe_model())
    run.units = run.units[:-1]
    with pytest.raises(ReconstructionError):
        run_mesh(run)
    bad_pole = _run(positions, None)
    bad_pole.poles[0] = Pole(np.array([0.0, np.nan, 0.0]), 0.03, 1.0, 1)
    with pytest.raises(ReconstructionError):
        run_mesh(bad_pole)
    with pytest.raises(ReconstructionError):
        beam_path(np.array([[0.0, 0, 0], [0.0, 0, 1.0]]))
