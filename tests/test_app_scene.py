"""The 3D scene: its window of points, picking, colours, and live threshold tuning."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import viser

from app.scene.colours import GUARDRAIL, OTHER, SELECTED, point_colours, probability_colours
from app.scene.picking import in_rectangle, pick_along_ray, project_to_screen
from app.scene.tuning import RunTuner, unit_numbers, with_value
from app.scene.viewer import ReviewScene
from app.scene.window import window_points
from app.session import ReviewSession
from guardrail_core.formats.drive import Drive
from guardrail_core.formats.drive_tiles import vehicle_station
from tests.app_fixtures import copy_run, new_session


def test_window_keeps_segment_points_first_within_the_budget() -> None:
    station = np.arange(1000, dtype=np.float64) / 10  # 0 .. 99.9 m
    segment = np.where(np.arange(1000) % 10 == 0, 1, -1)  # every tenth point in a segment
    everything = window_points(station, segment, 0.0, 200.0, 10_000)
    assert np.array_equal(everything, np.arange(1000))
    window = window_points(station, segment, 20.0, 10.0, 10_000)
    assert np.array_equal(window, np.arange(200, 300))
    small = window_points(station, segment, 0.0, 200.0, 150)
    assert len(small) == 150
    assert np.all(segment[np.arange(0, 1000, 10)] == 1)
    assert set(np.arange(0, 1000, 10)) <= set(small.tolist())  # all 100 segment points kept
    tiny = window_points(station, segment, 0.0, 200.0, 40)
    assert len(tiny) == 40 and np.all(segment[tiny] == 1)


def test_click_ray_picks_the_nearest_point_it_passes() -> None:
    xyz = np.array([[10.0, 0.05, 0.0], [5.0, -0.02, 0.0], [5.0, 3.0, 0.0], [-5.0, 0.0, 0.0]])
    assert pick_along_ray(xyz, np.zeros(3), np.array([2.0, 0, 0])) == 1  # first along the ray
    assert pick_along_ray(xyz, np.zeros(3), np.array([-1.0, 0, 0])) == 3
    assert pick_along_ray(xyz, np.zeros(3), np.array([0, 0, 1.0])) is None
    assert pick_along_ray(xyz[[0, 2]], np.zeros(3), np.array([1.0, 0, 0])) == 0


def test_projection_matches_a_pinhole_camera() -> None:
    # Camera at the origin looking down +x (OpenCV: z forward, x right, y down).
    R = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], np.float64)  # columns: camera axes in world
    T = np.eye(4)
    T[:3, :3] = R
    fov = np.deg2rad(60)
    xyz = np.array([[10.0, 0, 0], [10.0, -10 * np.tan(fov / 2), 0], [-10.0, 0, 0]])
    uv, front = project_to_screen(xyz, T, fov, aspect=1.0)
    assert np.allclose(uv[0], [0.5, 0.5])
    assert np.allclose(uv[1], [1.0, 0.5])  # the right edge: world -y is camera +x
    assert front.tolist() == [True, True, False]
    inside = in_rectangle(uv, front, np.array([0.4, 0.4]), np.array([0.6, 0.6]))
    assert inside.tolist() == [True, False, False]


def test_colours_follow_mode_and_operator_labels() -> None:
    point_segment = np.array([0, 0, 1, -1, -2])
    common = dict(
        segment_label=np.array([True, False]),
        raw_label=np.array([False, True]),
        probability=np.array([0.9, np.nan], np.float32),
        point_class=np.array([6, 6, 15, 1, 16]),
    )
    none = np.full(5, -1, np.int8)
    unselected = np.zeros(2, bool)
    label = point_colours("label", point_segment, point_labels=none, selected=unselected, **common)
    assert (label[:2] == GUARDRAIL).all() and (label[2] == OTHER).all()
    own = np.array([-1, 0, -1, -1, -1], np.int8)  # an operator said point 1 is not guardrail
    mixed = point_colours("label", point_segment, point_labels=own, selected=unselected, **common)
    assert (mixed[0] == GUARDRAIL).all() and (mixed[1] == OTHER).all()
    raw = point_colours(
        "prediction", point_segment, point_labels=none, selected=unselected, **common
    )
    assert (raw[:2] == OTHER).all() and (raw[2] == GUARDRAIL).all()
    truth = point_colours("truth", point_segment, point_labels=none, selected=unselected, **common)
    assert (truth[:2] == GUARDRAIL).all() and (truth[2] == OTHER).all()
    chosen = point_colours(
        "probability", point_segment, point_labels=none, selected=np.array([False, True]), **common
    )
    assert (chosen[2] == SELECTED).all()
    assert (chosen[0] == probability_colours(np.array([0.9]))[0]).all()
    with pytest.raises(ValueError, match="colour mode"):
        point_colours("rainbow", point_segment, point_labels=none, selected=unselected, **common)


@pytest.fixture()
def session(drive_path: Path, run_path: Path, tmp_path: Path):
    s = new_session(drive_path, copy_run(run_path, tmp_path), tmp_path / "review")
    yield s
    s.close()


@pytest.fixture()
def scene(session: ReviewSession):
    server = viser.ViserServer(host="127.0.0.1", port=18_480, verbose=False)
    try:
        yield ReviewScene(session, server, window_m=40.0, point_budget=50_000)
    finally:
        server.stop()


def test_scene_shows_a_window_and_recolours_a_relabelled_segment(
    scene: ReviewScene, session: ReviewSession, drive: Drive
) -> None:
    window = scene.shown
    assert 0 < len(window) <= 50_000
    # The window read from the tiles holds the drive's points and the run's segments.
    np.testing.assert_array_equal(window.xyz, drive.points.xyz[window.index])
    np.testing.assert_array_equal(window.segment, session.folder.point_segment()[window.index])
    station = vehicle_station(drive.trajectory, drive.points.gps_time[window.index])
    assert station.min() >= scene.start_m and station.max() < scene.start_m + 40.0
    shown = window.segment
    s = int(np.bincount(shown[shown >= 0]).argmax())  # the segment with most points shown
    flipped = "other" if session.effective_label()[s] else "guardrail"
    session.relabel([s], flipped)
    colours = scene._cloud.colors  # type: ignore[union-attr]
    expected = GUARDRAIL if flipped == "guardrail" else OTHER
    assert (colours[shown == s] == expected).all()
    session.select([s])
    assert (scene._cloud.colors[shown == s] == SELECTED).all()  # type: ignore[union-attr]
    assert "Segment" in scene._selection_text.content


def test_retuning_a_run_changes_its_model_and_keeps_the_run_folder(
    scene: ReviewScene, session: ReviewSession
) -> None:
    tuner = RunTuner(session.run.root)
    runs = tuner.tunable_runs()
    assert runs, "the test street has reconstructed runs"
    run = runs[0]
    before = (session.run.root / "reconstruction" / "models.json").read_bytes()
    same = tuner.retune(run.run_id, tuner.params)
    assert same.unit.model.type == run.model.type  # type: ignore[union-attr]
    if run.model.type == "pipe":  # type: ignore[union-attr]
        assert len(same.unit.model.pipes) == len(run.model.pipes)  # type: ignore[union-attr]
        assert same.unit.histogram is not None
    assert len(same.mesh.faces) > 0
    strict = with_value(tuner.params, "pipes", "histogram_factor", 50.0)
    assert strict.pipes.histogram_factor == 50.0 and tuner.params.pipes.histogram_factor != 50.0
    as_int = with_value(tuner.params, "pipes", "taubin_iterations", 3.0)
    assert isinstance(as_int.pipes.taubin_iterations, int)
    assert (session.run.root / "reconstruction" / "models.json").read_bytes() == before

    # A scene client may send any value: the reconstruction gets the slider's own range.
    sliders = scene._sliders
    sliders[("pipes", "slice_interval_m")].value = 0.5  # the slider's maximum is 0.1
    sliders[("pipes", "taubin_iterations")].value = 400  # ... 40
    sliders[("pipes", "histogram_factor")].value = float("nan")
    clamped = scene.slider_params()
    assert clamped.pipes.slice_interval_m == 0.1 and clamped.pipes.taubin_iterations == 40
    assert clamped.pipes.histogram_factor == tuner.params.pipes.histogram_factor
    for key, slider in sliders.items():
        slider.value = getattr(getattr(tuner.params, key[0]), key[1])

    scene._run_choice.value = scene._run_choice.options[0]
    seconds = scene.retune()
    assert seconds is not None and seconds < 5.0
    assert "ms" in scene._tune_text.content
    chosen = scene._chosen_run()
    assert chosen is not None and chosen in scene._ghosts  # the previous mesh, ghosted
    assert chosen in scene._shown_mesh


def test_the_tuning_panel_plots_each_run_s_histogram_or_section(
    scene: ReviewScene, session: ReviewSession
) -> None:
    """The chosen run's x histogram with its threshold and its vertical pipes marked (pipes), or
    its section curve (beams), redrawn when a slider moves: the numbers of the histogram route."""
    tuner = RunTuner(session.run.root)
    runs = tuner.tunable_runs()
    options = list(scene._run_choice.options)
    assert len(options) == len(runs) >= 1
    pipe_runs = 0
    for option, run in zip(options, runs, strict=True):
        scene._run_choice.value = option
        scene.show_unit_plot()
        expected = unit_numbers(run.run_id, tuner.unit(run.run_id, tuner.params), tuner.params)
        assert f"run {run.run_id}:" in scene._tune_text.content
        if expected["x_m"] is None:  # a beam: its section, no histogram
            assert scene._section.visible and not scene._histogram.visible
            z_by_height = np.asarray(expected["section"])
            z_by_height = z_by_height[np.argsort(z_by_height[:, 1], kind="stable")]
            np.testing.assert_allclose(scene._section.data[0], z_by_height[:, 1])
            np.testing.assert_allclose(scene._section.data[1], z_by_height[:, 0])
            continue
        pipe_runs += 1
        assert scene._histogram.visible and not scene._section.visible
        x, counts, threshold, marked = scene._histogram.data
        np.testing.assert_allclose(x, expected["x_m"])
        np.testing.assert_allclose(counts, expected["counts"])
        assert np.all(threshold == expected["threshold"])
        assert f"threshold {expected['threshold']:.1f}" in scene._tune_text.content
        verticals = [p for p in expected["pipes"] if p["kind"] == "vertical"]
        half = expected["bin_m"] / 2
        inside = np.zeros(len(x), bool)
        for pipe in verticals:
            inside |= (x >= pipe["x_min_m"] - half) & (x <= pipe["x_max_m"] + half)
        np.testing.assert_allclose(marked, np.where(inside, counts, 0.0))
        # A slider moved: the plot follows with the new factor's threshold.
        factor = scene._sliders[("pipes", "histogram_factor")]
        old = factor.value
        factor.value = 5.0 if old < 5.0 else 2.0
        scene.retune()
        params = with_value(tuner.params, "pipes", "histogram_factor", factor.value)
        moved = unit_numbers(run.run_id, tuner.unit(run.run_id, params), params)
        assert scene._histogram.data[2][0] == moved["threshold"] != expected["threshold"]
        factor.value = old
    assert 1 <= pipe_runs < len(runs), "the test street has pipe runs and a beam run"
