"""Reconstruction metrics against truth records made by the simulator's own guardrail builder."""

from __future__ import annotations

import json

import numpy as np
import pytest

from guardrail_core.evaluate.reconstruction import (
    densify,
    evaluate_reconstruction,
    hausdorff,
    units_in_view,
)
from guardrail_core.reconstruct.model import Pipe, Pole, RunModel, UnitModel
from guardrail_core.reconstruct.model_json import run_model_from_json, run_model_to_json
from guardrail_core.reconstruct.unit_frame import UnitFrame
from guardrail_core.synth.designs import load_design
from guardrail_core.synth.guardrail import build_guardrail_run
from guardrail_core.synth.mesh import MeshBuilder


def _truth(design_name: str, n_poles: int = 5, *, curve: float = 0.0, object_id: int = 1):
    """A truth record of a run along +x (on a gentle arc when ``curve`` > 0), road toward -y."""
    design = load_design(design_name)
    s = np.arange(n_poles) * design.unit_length
    poles = np.stack([s, curve * s**2, 0.01 * s], axis=1)
    toward = np.tile([0.0, -1.0, 0.0], (n_poles, 1))
    record = build_guardrail_run(
        design, poles, toward, paint="white", object_id=object_id, builder=MeshBuilder()
    )
    return design, record


def _perfect_run(design, record, *, pole_shift=0.0, drop_pipe=None, radius_bias=0.0) -> RunModel:
    """The run a perfect reconstruction would give, optionally spoilt."""
    positions = np.array([p["position"] for p in record["poles"]])
    positions[:, 1] += pole_shift
    poles = [Pole(p, design.pole.radius, design.pole.height, 100) for p in positions]
    frames = [UnitFrame.between(positions[i], positions[i + 1]) for i in range(len(poles) - 1)]
    length = float(np.median([f.length for f in frames]))
    pipes = []
    for j, spec in enumerate(design.pipes):
        if j == drop_pipe:
            continue
        axis = np.column_stack(
            [
                spec.points[:, 0] * length / design.unit_length,
                spec.points[:, 1],
                np.zeros(len(spec.points)),
            ]
        )
        pipes.append(Pipe(axis, spec.radius + radius_bias, spec.kind, 50))
    section = None
    if design.type == "beam":
        section = np.asarray(record["beams"][0]["section"])
    model = UnitModel(
        type=design.type,
        length=length,
        pipes=tuple(pipes),
        section=section,
        pole_radius=design.pole.radius,
        pole_height=design.pole.height,
        n_units=len(frames),
    )
    return RunModel(0, poles, frames, model, np.ones(len(frames), bool), 1000)


@pytest.mark.parametrize("design_name", ["pipe_simple_3", "pipe_diamond", "pipe_arch", "pipe_wave"])
def test_a_perfect_reconstruction_finds_every_pipe_with_no_error(design_name):
    design, record = _truth(design_name)
    result = evaluate_reconstruction([_perfect_run(design, record)], [record])
    overall = result.overall
    assert overall.pipes_found == overall.pipes_total == len(design.pipes)
    assert overall.poles_found == overall.poles_total == 5
    assert overall.radius_err_mm_median == pytest.approx(0.0, abs=1e-9)
    assert overall.axis_dev_mm_mean < 0.01
    assert overall.pole_pos_err_mm_median == pytest.approx(0.0, abs=1e-6)
    assert overall.unit_length_err_mm_median == pytest.approx(0.0, abs=1e-6)
    assert result.designs[design_name].pipes_total == len(design.pipes)


def test_errors_are_measured_in_millimetres():
    design, record = _truth("pipe_simple_2")
    run = _perfect_run(design, record, pole_shift=0.012, radius_bias=0.0015)
    overall = evaluate_reconstruction([run], [record]).overall
    assert overall.pole_pos_err_mm_median == pytest.approx(12.0, abs=1e-6)
    assert overall.radius_err_mm_median == pytest.approx(1.5, abs=1e-6)
    # Every pole moved 12 mm toward the road, so the whole model moved with them.
    assert overall.axis_dev_mm_mean == pytest.approx(12.0, abs=0.01)
    assert overall.pipes_found == 2


def test_a_missing_pipe_and_a_far_model_are_not_found():
    design, record = _truth("pipe_diagonal_x")
    result = evaluate_reconstruction([_perfect_run(design, record, drop_pipe=2)], [record])
    assert result.overall.pipes_found == 3
    assert result.overall.pipes_total == 4
    # 30 mm off: beyond max(2 r, 20 mm) = 27.2 mm for the diagonals, within 48.6 mm for the rails.
    far = _perfect_run(design, record, pole_shift=0.030)
    found = {p.kind: p.found for p in evaluate_reconstruction([far], [record]).runs[0].pipes}
    assert found == {"horizontal": True, "diagonal": False}


def test_poles_beyond_the_match_distance_are_missed_and_units_need_both_poles():
    design, record = _truth("pipe_simple_2", n_poles=4)
    run = _perfect_run(design, record)
    moved = run.poles[1].position + np.array([0.0, 0.5, 0.0])
    run.poles[1] = Pole(moved, run.poles[1].radius, run.poles[1].height, 10)
    result = evaluate_reconstruction([run], [record])
    assert result.overall.poles_found == 3
    assert result.runs[0].units_measured == 1  # only the unit between poles 2 and 3


def test_beam_section_hausdorff():
    design, record = _truth("beam_w", n_poles=3)
    run = _perfect_run(design, record)
    assert evaluate_reconstruction([run], [record]).overall.beam_section_hausdorff_mm < 1e-6
    shifted = np.asarray(record["beams"][0]["section"]) + [0.004, 0.0]
    run.model = UnitModel("beam", run.model.length, section=shifted, n_units=2)
    figure = evaluate_reconstruction([run], [record]).overall.beam_section_hausdorff_mm
    assert figure == pytest.approx(4.0, abs=0.05)


def test_curved_runs_are_measured_unit_by_unit():
    design, record = _truth("pipe_simple_3", n_poles=8, curve=0.01)
    overall = evaluate_reconstruction([_perfect_run(design, record)], [record]).overall
    assert overall.pipes_found == 3
    assert overall.axis_dev_mm_mean < 0.5


def test_unreconstructed_runs_count_in_the_totals():
    design, record = _truth("pipe_ladder")
    _, other = _truth("beam_w", object_id=2)
    result = evaluate_reconstruction([_perfect_run(design, record)], [record, other])
    assert result.overall.pipes_total == len(design.pipes)
    assert result.overall.poles_total == 10
    assert result.designs["beam_w"].beams_reconstructed == 0
    assert result.designs["beam_w"].beams_total == 1


def test_hausdorff_and_densify():
    line = np.array([[0.0, 0.0], [1.0, 0.0]])
    assert np.allclose(densify(line, 0.1)[[0, -1]], line)
    assert len(densify(line, 0.1)) == 11
    assert hausdorff(line, line + [0.0, 0.003]) == pytest.approx(0.003)
    assert hausdorff(line, np.array([[0.0, 0.0], [1.2, 0.0]])) == pytest.approx(0.2, abs=0.002)


def test_model_json_round_trip():
    design, record = _truth("pipe_arch")
    run = _perfect_run(design, record)
    back = run_model_from_json(run_model_to_json(run))
    assert len(back.poles) == len(run.poles) and len(back.units) == len(run.units)
    assert back.model is not None and len(back.model.pipes) == len(design.pipes)
    for a, b in zip(back.model.pipes, run.model.pipes, strict=True):
        assert np.abs(a.axis - b.axis).max() <= 5e-5 and a.kind == b.kind
    assert abs(back.units[2].length - run.units[2].length) <= 5e-5
    again = evaluate_reconstruction([back], [record]).overall
    assert again.pipes_found == len(design.pipes)


def test_a_guardrail_counts_in_view_from_one_unit_with_both_poles_scanned():
    design, seen = _truth("pipe_simple_3", object_id=1)
    _, hidden = _truth("pipe_diamond", object_id=2)
    hidden = {
        **hidden,
        "poles": [{**p, "position": [p["position"][0], 30.0, 0.0]} for p in hidden["poles"]],
    }
    rng = np.random.default_rng(0)
    own = [np.array(p["position"]) + rng.normal(0, 0.03, (12, 3)) for p in seen["poles"]]
    xyz = np.vstack([*own, np.array(hidden["poles"][0]["position"]) + np.zeros((40, 3))])
    object_id = np.repeat([1, 2], [12 * len(seen["poles"]), 40])
    # The first guardrail: 12 points at every pole, but pole 1's lie 0.3 m off (not scanned),
    # so units 0-1 and 1-2 are out of view; the second: one pole scanned, so no unit.
    xyz[12 : 2 * 12] += [0.0, 0.3, 0.0]
    in_view = units_in_view(xyz, object_id, [seen, hidden])
    assert in_view == {1: len(seen["units"]) - 2, 2: 0}
    result = evaluate_reconstruction([], [seen, hidden], in_view=in_view)
    overall = result.overall
    assert overall.pipes_total == len(design.pipes) + 6  # the diamond's 6 pipes
    assert overall.pipes_in_view == len(design.pipes)
    assert (overall.guardrails_total, overall.guardrails_in_view) == (2, 1)
    # Without the points, every guardrail counts as in view.
    assert (
        evaluate_reconstruction([], [seen, hidden]).overall.pipes_in_view == len(design.pipes) + 6
    )


def test_the_json_has_the_keys_evaluate_json_always_printed():
    design, record = _truth("pipe_simple_2")
    document = evaluate_reconstruction([_perfect_run(design, record)], [record]).to_json()
    assert list(document) == ["overall", "designs", "runs"]
    figures = [
        "pipes_found", "pipes_total", "pipes_in_view", "guardrails_total", "guardrails_in_view",
        "radius_err_mm_median", "axis_dev_mm_mean", "beam_section_hausdorff_mm",
        "beams_reconstructed", "beams_total", "poles_found", "poles_total",
        "pole_pos_err_mm_median", "unit_length_err_mm_median",
    ]  # fmt: skip
    assert list(document["overall"]) == list(document["designs"]["pipe_simple_2"]) == figures
    [run] = document["runs"]
    assert list(run) == [
        "truth_id", "design", "type", "run_id", "poles_total", "pipes", "pipes_total",
        "beam_section_hausdorff_mm", "units_in_view", "poles_found", "units_measured",
        "pipes_found",
    ]  # fmt: skip
    assert [list(p) for p in run["pipes"]] == [
        ["kind", "radius_mm", "found", "found_in_units", "radius_err_mm", "axis_dev_mm"]
    ] * len(design.pipes)
    assert json.loads(json.dumps(document)) == document  # plain JSON values only
