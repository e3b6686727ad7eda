"""Why poles and pipes were missed: every miss gets the first cause that applies, and the counts
add up to the truth (on a made-up street, and on the test drive's run)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from guardrail_core.evaluate.detection import evaluate_run_folder
from guardrail_core.evaluate.misses import MissBreakdown, explain_misses
from guardrail_core.evaluate.reconstruction import PolePointCounter
from guardrail_core.formats.drive import Drive
from guardrail_core.reconstruct.model import Pole, RunModel
from guardrail_core.reconstruct.run_models import load_run_models
from guardrail_core.sensors.trajectory import Trajectory

SCANNED, UNSEEN = 20, 0


def straight_trajectory() -> Trajectory:
    """The vehicle drives 100 m along +x in 10 s."""
    x = np.linspace(0.0, 100.0, 101)
    position = np.stack([x, np.zeros_like(x), np.full_like(x, 1.8)], axis=1)
    return Trajectory(time=x / 10.0, position=position, attitude=np.zeros((101, 3)))


def guardrail(ident: int, xs: list[float], y: float, pipes_per_unit: int = 2) -> dict:
    poles = [{"position": [x, y, 0.0]} for x in xs]
    units = [{"start_pole": i, "end_pole": i + 1} for i in range(len(xs) - 1)]
    pipes = [
        {
            "unit": u,
            "kind": "horizontal",
            "radius": 0.0243,
            "axis": [[xs[u], y, 0.5 + 0.3 * k], [xs[u + 1], y, 0.5 + 0.3 * k]],
        }
        for u in range(len(units))
        for k in range(pipes_per_unit)
    ]
    return {
        "id": ident,
        "kind": "guardrail",
        "design": f"design_{ident}",
        "type": "pipe",
        "poles": poles,
        "units": units,
        "pipes": pipes,
        "beams": [],
    }


def test_every_missed_pole_and_pipe_gets_its_cause() -> None:
    objects = [
        guardrail(1, [10, 12, 14, 16, 18], 2.0),  # near side, one pole hidden
        guardrail(2, [30, 32, 34, 36], -6.0),  # far side, its first pole unseen
        guardrail(3, [50, 52, 54], 2.0),  # two units: a short run
        guardrail(4, [-10, -8], 2.0),  # before the drive's first position
        {"id": 5, "kind": "parked_car"},
    ]
    counter = PolePointCounter(objects)
    counter.counts = [
        np.array([SCANNED, UNSEEN, SCANNED, SCANNED, SCANNED]),
        np.array([UNSEEN, SCANNED, SCANNED, SCANNED]),
        np.array([SCANNED] * 3),
        np.array([UNSEEN] * 2),
    ]
    misses = explain_misses([], objects, counter, straight_trajectory())

    assert misses.poles_total == 14 and misses.poles_found == 0
    assert (misses.poles_in_view, misses.poles_found_in_view) == (10, 0)
    assert misses.pole_misses == {
        "beyond the drive's ends": 2,
        "far side": 1,
        "occluded": 1,
        "short run": 3,
        "unit partly seen": 3,  # poles 0 and 2 of guardrail 1, pole 1 of guardrail 2
        "far side, scanned": 2,
        "in view": 2,
    }
    # In view: guardrails 1-3 (a unit with both poles scanned); 2 pipes per unit of the design.
    assert misses.pipes_in_view == 6 and misses.pipes_found == 0
    assert misses.pipe_misses == {"short run": 2, "far side": 2, "not reconstructed": 2}
    assert misses.designs["design_4"] == {
        "poles_total": 2,
        "poles_found": 0,
        "pipes_in_view": 0,
        "pipes_found": 0,
    }


def test_poles_detected_where_none_stands_are_false_poles() -> None:
    # Poles within the match distance of a true one are found, one per true pole; a second one
    # at the same true pole, and the stems of a hedge 1 m behind the rail, are false poles.
    objects = [guardrail(1, [10, 12, 14], 2.0)]
    counter = PolePointCounter(objects)
    counter.counts = [np.array([SCANNED] * 3)]
    at = [(10.0, 2.0), (12.01, 2.0), (12.1, 2.0)] + [(x, 3.0) for x in (10.5, 10.7, 10.9)]
    poles = [Pole(np.array([x, y, 0.0]), 0.03, 0.9, 50) for x, y in at]
    run = RunModel(0, poles, [], None, np.zeros(0, bool), 300, [])
    misses = explain_misses([run], objects, counter, straight_trajectory())
    assert (misses.poles_found, misses.poles_detected, misses.false_poles) == (2, 6, 4)
    assert misses.to_json()["false_poles"] == 4
    assert (misses + misses).false_poles == 8


def test_breakdowns_add_up_over_drives() -> None:
    a = MissBreakdown(
        poles_total=3,
        poles_found=2,
        pole_misses={"occluded": 1},
        designs={"d": {"poles_total": 3, "poles_found": 2, "pipes_in_view": 0, "pipes_found": 0}},
        pole_errors_mm=(1.0, 2.0),
    )
    b = MissBreakdown(
        poles_total=2,
        poles_found=1,
        pole_misses={"occluded": 1, "in view": 0},
        designs={"d": {"poles_total": 2, "poles_found": 1, "pipes_in_view": 4, "pipes_found": 3}},
        pole_errors_mm=(3.0,),
    )
    total = a + b
    assert (total.poles_total, total.poles_found) == (5, 3)
    assert total.pole_misses == {"occluded": 2, "in view": 0}
    assert total.designs == {
        "d": {"poles_total": 5, "poles_found": 3, "pipes_in_view": 4, "pipes_found": 3}
    }
    assert total.pole_errors_mm == (1.0, 2.0, 3.0)


def test_on_a_real_run_the_misses_and_finds_add_up_to_the_evaluation(
    drive: Drive, drive_path: Path, run_path: Path
) -> None:
    assert drive.truth is not None
    counter = PolePointCounter(drive.truth.objects)
    counter.add(drive.points.xyz, drive.truth.point_object)
    misses = explain_misses(
        list(load_run_models(run_path).runs), drive.truth.objects, counter, drive.trajectory
    )
    overall = evaluate_run_folder(drive_path, run_path).reconstruction
    assert overall is not None
    figures = overall.overall
    assert misses.poles_total == figures.poles_total > 0
    assert misses.poles_found == figures.poles_found > 0
    assert misses.poles_found + sum(misses.pole_misses.values()) == misses.poles_total
    unseen = ("beyond the drive's ends", "far side", "occluded")
    seen_misses = sum(n for cause, n in misses.pole_misses.items() if cause not in unseen)
    assert misses.poles_found_in_view + seen_misses == misses.poles_in_view
    assert misses.pipes_in_view == figures.pipes_in_view
    assert misses.pipes_found == figures.pipes_found
    assert misses.pipes_found + sum(misses.pipe_misses.values()) == misses.pipes_in_view
    assert sum(misses.design_misses.values()) == misses.pipe_misses.get("design", 0)
    assert len(misses.pole_errors_mm) == misses.poles_found
    assert np.median(misses.pole_errors_mm) == figures.pole_pos_err_mm_median


def test_wrong_segments_get_the_first_cause_that_applies() -> None:
    from guardrail_core.evaluate.misses import explain_detection_misses
    from guardrail_core.formats.run_folder import CROP_OK

    no_crop = CROP_OK + 1
    segments = {
        # far and without a crop: far side wins; near without a crop; near, few points; near
        "lateral": np.array([[5.0, 6.0], [1.5, 2.0], [-2.0, -1.8], [1.9, 2.1], [-7.0, -6.5]]),
        "crop_status": np.array([no_crop, no_crop, CROP_OK, CROP_OK, CROP_OK]),
        "n_points": np.array([50, 50, 5, 80, 80]),
    }
    truth = np.array([True, True, True, True, False])
    label = np.array([False, False, False, True, True])
    out = explain_detection_misses(truth, label, segments)
    assert out["missed"] == {"far side": 1, "no crop": 1, "few points": 1, "near, with a crop": 0}
    assert out["false alarms"] == {
        "far side": 1,
        "no crop": 0,
        "few points": 0,
        "near, with a crop": 0,
    }
    assert out["guardrail"] == {
        "far side": 1,
        "no crop": 1,
        "few points": 1,
        "near, with a crop": 1,
    }
