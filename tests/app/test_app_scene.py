"""The 3D scene: its window of points, picking, colours, and live threshold tuning."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import viser
import viser.transforms as vtf
from fastapi.testclient import TestClient

from app.jobs import JobRunner
from app.main import create_app
from app.route_overview import run_places
from app.run_tuning import RunTuner, unit_numbers, with_value
from app.scene.colours import (
    GUARDRAIL,
    NO_VALUE,
    OFF_ROAD,
    OTHER,
    ROAD,
    SELECTED,
    point_colours,
    probability_colours,
)
from app.scene.picking import in_polygon, in_rectangle, pick_along_ray, project_to_screen
from app.scene.viewer import ReviewScene
from app.scene.window import window_points
from app.session import ReviewSession
from guardrail_core.errors import InvalidOptionError
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


def test_a_lasso_polygon_holds_what_it_winds_round_once() -> None:
    """Even-odd: inside a square and a concave L, outside the L's notch; a figure-eight's two
    loops are both inside; points behind the camera never are."""
    rng = np.random.default_rng(2)
    uv = rng.random((4000, 2))
    front = np.ones(len(uv), bool)
    square = np.array([[0.2, 0.2], [0.8, 0.2], [0.8, 0.8], [0.2, 0.8]])
    expected = np.all((uv > 0.2) & (uv < 0.8), axis=1)
    np.testing.assert_array_equal(in_polygon(uv, front, square), expected)
    ell = np.array([[0.1, 0.1], [0.9, 0.1], [0.9, 0.4], [0.4, 0.4], [0.4, 0.9], [0.1, 0.9]])
    in_ell = (np.all((uv > 0.1) & (uv < 0.9), axis=1)) & ~((uv[:, 0] > 0.4) & (uv[:, 1] > 0.4))
    np.testing.assert_array_equal(in_polygon(uv, front, ell), in_ell)
    eight = np.array([[0.1, 0.1], [0.5, 0.5], [0.9, 0.1], [0.9, 0.9], [0.5, 0.5], [0.1, 0.9]])
    probes = np.array([[0.2, 0.5], [0.8, 0.5], [0.5, 0.2], [0.5, 0.8]])
    assert in_polygon(probes, np.ones(4, bool), eight).tolist() == [True, True, False, False]
    behind = in_polygon(uv, np.zeros(len(uv), bool), square)
    assert not behind.any()
    assert not in_polygon(uv, front, square[:2]).any()  # two corners make no polygon


def test_colours_follow_mode_and_operator_labels() -> None:
    point_segment = np.array([0, 0, 1, -1, -2])
    common = dict(
        segment_label=np.array([True, False]),
        raw_label=np.array([False, True]),
        probability=np.array([0.9, np.nan], np.float32),
        point_class=np.array([6, 6, 15, 1, 16]),
    )
    none = np.full(5, -1, np.int8)
    label = point_colours("label", point_segment, point_labels=none, **common)
    assert (label[:2] == GUARDRAIL).all() and (label[2] == OTHER).all()
    assert (label[3] == ROAD).all() and (label[4] == OFF_ROAD).all()
    own = np.array([-1, 0, -1, -1, -1], np.int8)  # an operator said point 1 is not guardrail
    mixed = point_colours("label", point_segment, point_labels=own, **common)
    assert (mixed[0] == GUARDRAIL).all() and (mixed[1] == OTHER).all()
    raw = point_colours("prediction", point_segment, point_labels=none, **common)
    assert (raw[:2] == OTHER).all() and (raw[2] == GUARDRAIL).all()
    truth = point_colours("truth", point_segment, point_labels=none, **common)
    assert (truth[:2] == GUARDRAIL).all() and (truth[2] == OTHER).all()
    probability = point_colours("probability", point_segment, point_labels=none, **common)
    assert (probability[0] == probability_colours(np.array([0.9]))[0]).all()
    assert (probability[2] == NO_VALUE).all() and (probability[3] == ROAD).all()
    with pytest.raises(ValueError, match="colour mode"):
        point_colours("rainbow", point_segment, point_labels=none, **common)


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
    # The selection is drawn over the points: its own cloud holds exactly the segment's points
    # shown, in magenta, and the points keep their label colours.
    overlay = scene._selection_cloud
    assert overlay is not None
    np.testing.assert_array_equal(overlay.points, window.xyz[shown == s].astype(np.float32))
    assert (overlay.colors == SELECTED).all()
    assert (scene._cloud.colors[shown == s] == expected).all()  # type: ignore[union-attr]
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
    assert chosen is not None and chosen in scene._ghosts  # the reconstruction's, ghosted
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
        # Only the sliders of the run's kind show: a beam has no pipes to tune.
        kind = "pipes" if run.model is not None and run.model.type == "pipe" else "beams"
        for (stage, _), slider in scene._sliders.items():
            assert slider.visible == (stage == kind), (run.run_id, stage)
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


def test_choosing_a_run_flies_there_and_apply_says_done_and_keeps_it(
    session: ReviewSession,
) -> None:
    """Choosing a run in the tuning panel moves the window to it; *Apply to the whole drive*
    reconstructs in a background job, then says so, the same run still chosen."""
    server = viser.ViserServer(host="127.0.0.1", port=18_490, verbose=False)
    jobs = JobRunner()
    try:
        # An 8 m window on the 32 m test drive, so that a run can lie outside it.
        scene = ReviewScene(session, server, window_m=8.0, point_budget=50_000, jobs=jobs)
        options = list(scene._run_choice.options)
        assert len(options) >= 2
        last = options[-1]
        run_id = int(last.split()[1])
        poles = scene._tuner.run(run_id).poles  # type: ignore[union-attr]
        middle = np.asarray(poles[len(poles) // 2].position)
        trajectory = session.drive.trajectory.position
        nearest = int(np.argmin(np.linalg.norm(trajectory - middle, axis=1)))
        station = scene.vehicle_station[nearest]
        lo, hi = scene.station_range
        scene.show_window(hi if station < (lo + hi) / 2 else lo)  # far from it
        assert not scene.start_m <= station < scene.start_m + scene.window_m
        scene._run_choice.value = last
        scene._on_run_chosen()
        assert scene.start_m <= station < scene.start_m + scene.window_m
        scene.apply_tuning()
        (job,) = jobs.list("reconstruct")
        assert jobs.wait(job.id, timeout=600).status == "done"
        assert scene._tune_text.content.startswith("**Applied:**"), scene._tune_text.content
        assert scene._run_choice.value == last
        scene.close()
    finally:
        jobs.shutdown()
        server.stop()


def test_layers_point_size_and_the_colour_legend(
    scene: ReviewScene, session: ReviewSession, drive: Drive
) -> None:
    """Points, the points labelled other, meshes and cameras can be hidden (the cameras are at
    first: their frusta hid the selection); the point size changes; the legend follows the
    colour mode; the meshes are not near-white."""
    shown = scene.shown
    n_guardrail = int(
        ((shown.segment >= 0) & session.effective_label()[np.maximum(shown.segment, 0)]).sum()
    )
    assert 0 < n_guardrail < len(shown)
    assert len(scene._cloud.points) == len(shown)  # type: ignore[union-attr]
    scene.show_layer("other", False)
    assert len(scene._cloud.points) == n_guardrail  # type: ignore[union-attr]
    picked = scene._segment_points()
    assert len(picked) == n_guardrail and session.effective_label()[picked.segment].all()
    scene.show_layer("other", True)
    assert len(scene._cloud.points) == len(shown)  # type: ignore[union-attr]
    scene.show_layer("points", False)
    assert not scene._cloud.visible and len(scene._segment_points()) == 0  # type: ignore[union-attr]
    scene.show_layer("points", True)
    assert scene._cloud.visible  # type: ignore[union-attr]

    assert drive.images and scene._frusta == []
    scene.show_layer("cameras", True)
    assert len(scene._frusta) > 0
    scene.show_layer("cameras", False)
    assert scene._frusta == []

    assert scene._meshes, "the test street's runs have meshes"
    for handle in scene._meshes.values():
        assert handle.visible and min(handle.color) < 100  # type: ignore[union-attr]
    scene.show_layer("meshes", False)
    assert not any(handle.visible for handle in scene._meshes.values())
    scene.show_layer("meshes", True)

    assert "P(guardrail)" not in scene._legend.content
    scene.mode = "probability"
    scene.recolour()
    assert "P(guardrail)" in scene._legend.content and "linear-gradient" in scene._legend.content


def _click(client: object, screen: tuple[float, float]) -> SimpleNamespace:
    """A scene click at a screen position of a browser's camera (its ray through that pixel)."""
    camera = client.camera  # type: ignore[attr-defined]
    T = np.eye(4)
    T[:3, :3] = vtf.SO3(np.asarray(camera.wxyz)).as_matrix()
    half = np.tan(camera.fov / 2)
    direction = T[:3, :3] @ np.array(
        [(2 * screen[0] - 1) * half * camera.aspect, (2 * screen[1] - 1) * half, 1.0]
    )
    return SimpleNamespace(
        client=client,
        screen_pos=screen,
        ray_origin=tuple(camera.position),
        ray_direction=tuple(direction),
    )


def test_a_lasso_selects_the_points_inside_it_and_the_page_labels_only_those(
    scene: ReviewScene, session: ReviewSession
) -> None:
    """Corners clicked in the scene make a screen polygon; closing it selects the segment
    points shown inside it as the first corner's view saw them (their segments become the
    selection), they turn magenta alone, and labelling the lasso labels just them, undoably."""
    camera = SimpleNamespace(
        wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, 0.0), fov=1.0, aspect=1.5
    )
    shown = scene.shown.take(np.flatnonzero(scene.shown.segment >= 0))
    # Look down at the middle of the window from 30 m up (OpenCV axes: z forward = world -z).
    centre = np.median(shown.xyz, axis=0)
    camera.wxyz = tuple(vtf.SO3.from_matrix(np.diag([1.0, -1.0, -1.0])).wxyz)
    camera.position = tuple(centre + np.array([0.0, 0.0, 30.0]))
    client = SimpleNamespace(camera=camera)
    polygon = [(0.3, 0.3), (0.7, 0.3), (0.7, 0.7), (0.45, 0.55), (0.3, 0.7)]
    scene.start_lasso()
    for corner in polygon:
        scene.add_lasso_corner(_click(client, corner))  # type: ignore[arg-type]
    assert scene._lasso_line is not None
    taken = scene.close_lasso()
    T = np.eye(4)
    T[:3, :3] = vtf.SO3(np.asarray(camera.wxyz)).as_matrix()
    T[:3, 3] = camera.position
    uv, front = project_to_screen(shown.xyz, T, camera.fov, camera.aspect)
    expected = shown.index[in_polygon(uv, front, np.array(polygon))]
    assert len(expected) >= 100
    np.testing.assert_array_equal(taken, expected)
    np.testing.assert_array_equal(session.lasso, expected)
    np.testing.assert_array_equal(
        session.selection, np.unique(shown.segment[np.isin(shown.index, expected)])
    )
    lassoed = np.isin(scene.shown.index, expected)
    overlay = scene._selection_cloud  # the lasso's points, not their whole segments
    assert overlay is not None and (overlay.colors == SELECTED).all()
    np.testing.assert_array_equal(overlay.points, scene.shown.xyz[lassoed].astype(np.float32))
    assert scene._lasso_line is None and "Lasso" in scene._selection_text.content

    before = session.store.counts()["labelled_points"]
    done = session.relabel_lasso("guardrail")
    assert session.store.counts()["labelled_points"] == before + len(expected)
    assert (session.store.labels_at(expected) == 1).all()
    others = np.setdiff1d(session.tiles.points_of(session.selection), expected)
    assert (session.store.labels_at(others) == -1).all()  # not their whole segments
    assert done.change is not None and done.change.n_points == len(expected)
    assert session.store.history(limit=1)[0]["note"] == f"lasso of {len(expected)} points"
    session.undo()
    assert (session.store.labels_at(expected) == -1).all()
    session.select([int(session.selection[0])])  # another selection lets the lasso go
    assert len(session.lasso) == 0
    with pytest.raises(InvalidOptionError, match="no lasso"):
        session.relabel_lasso("other")


def test_the_page_cancels_a_lasso_being_drawn_and_one_taken(
    scene: ReviewScene, session: ReviewSession
) -> None:
    """A reload of the page, or Escape there, cancels a lasso: one being drawn stops taking
    clicks as corners (before, the next clicks after a reload silently became corners), and
    the points one took are let go while their segments stay selected."""
    camera = SimpleNamespace(
        wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, 0.0), fov=1.0, aspect=1.5
    )
    client = SimpleNamespace(camera=camera)
    scene.start_lasso()
    for corner in ((0.3, 0.3), (0.6, 0.3)):
        scene.add_lasso_corner(_click(client, corner))  # type: ignore[arg-type]
    assert scene._lasso is not None and scene._lasso_line is not None
    with TestClient(create_app(session)) as api:
        assert api.post("/api/lasso/cancel", json={}).json()["lasso_points"] == 0
    assert scene._lasso is None and scene._lasso_line is None
    assert scene._lasso_start.visible and not scene._lasso_close.visible
    segment = int(np.flatnonzero(session.run.segments["n_points"] > 20)[0])
    points = session.tiles.points_of(np.array([segment]))[:5]
    session.select_points(points)
    assert len(session.lasso) == 5
    version = session.selection_watch.version
    with TestClient(create_app(session)) as api:
        assert api.post("/api/lasso/cancel", json={}).json() == {
            "segments": [segment],
            "lasso_points": 0,
            "version": version + 1,  # the page's long poll hears of it
        }
    assert len(session.lasso) == 0 and session.selection.tolist() == [segment]


def test_only_the_meshes_of_runs_near_the_window_are_sent(session: ReviewSession) -> None:
    """A survey has thousands of runs: the scene sends the meshes of those within half a window
    of it, and swaps them as the window moves."""
    server = viser.ViserServer(host="127.0.0.1", port=18_481, verbose=False)
    try:
        scene = ReviewScene(session, server, window_m=6.0, point_budget=20_000)
        places = {p.row.run_id: (p.station_m, p.station_end_m) for p in run_places(session)}
        with_mesh = set(session.folder.reconstruction.mesh_files("glb"))
        assert len(with_mesh) >= 2

        def near(start: float) -> set[int]:
            lo, hi = start - 3.0, start + 6.0 + 3.0
            return {r for r in with_mesh if places[r][0] <= hi and places[r][1] >= lo}

        seen, fewer = set(), False  # runs seen, and a window without them all
        for start in np.arange(scene.station_range[0], scene.station_range[1], 3.0):
            scene.show_window(float(start))
            assert set(scene._meshes) == near(scene.start_m)
            seen |= set(scene._meshes)
            fewer |= set(scene._meshes) != with_mesh
        assert seen == with_mesh, places  # every run's mesh was shown along the way
        if not fewer:  # the test street's runs span it all: place them apart to see the swap
            first, second = sorted(with_mesh)[:2]
            scene._mesh_stations = {first: (0.0, 5.0), second: (25.0, 30.0)}
            scene.show_window(0.0)
            assert set(scene._meshes) == {first} | (with_mesh - {first, second})
            scene.show_window(22.0)
            assert set(scene._meshes) == {second} | (with_mesh - {first, second})
        scene.close()
    finally:
        server.stop()
