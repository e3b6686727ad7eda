"""The route overview: the trajectory, every reconstructed run in order along the drive, the
segments on each run, and the review state that follows the operators' labels."""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.route_overview import RUN_REACH_M, run_places, segment_runs
from app.session import ReviewSession
from guardrail_core.formats.drive import Drive
from guardrail_core.formats.drive_tiles import vehicle_station
from guardrail_core.review.queue import asked_segments
from tests.app_fixtures import copy_run, new_session


@pytest.fixture
def session(drive_path: Path, run_path: Path, tmp_path: Path) -> Iterator[ReviewSession]:
    s = new_session(drive_path, copy_run(run_path, tmp_path), tmp_path / "review")
    yield s
    s.close()


@pytest.fixture
def client(session: ReviewSession) -> Iterator[TestClient]:
    with TestClient(create_app(session)) as c:
        yield c


def _distance_to_line(point: np.ndarray, path: np.ndarray) -> float:
    """Metres from a point (2,) to a polyline (P, 2)."""
    if len(path) == 1:
        return float(np.linalg.norm(point - path[0]))
    a, b = path[:-1], path[1:]
    t = np.clip(np.einsum("ij,ij->i", point - a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0, 1)
    return float(np.min(np.linalg.norm(a + t[:, None] * (b - a) - point, axis=1)))


def test_the_overview_lists_every_run_with_poles_in_order_along_the_drive(
    client: TestClient, session: ReviewSession, drive: Drive
) -> None:
    overview = client.get("/api/overview").json()
    models = json.loads((session.run.root / "reconstruction" / "models.json").read_text())["runs"]
    with_poles = {m["run_id"]: m for m in models if m["poles"]}
    runs = overview["runs"]
    assert len(runs) >= 2, "the test street has reconstructed runs"
    assert sorted(r["run_id"] for r in runs) == sorted(with_poles)
    assert [r["station_m"] for r in runs] == sorted(r["station_m"] for r in runs)
    for run in runs:
        poles = np.array([p["position"][:2] for p in with_poles[run["run_id"]]["poles"]])
        np.testing.assert_allclose(run["path"], poles, atol=0.006)  # rounded to the cm
        assert run["poles"] == len(poles)
        assert run["reviewed"] == run["changed"] == 0
        assert run["state"] == ("unreviewed" if run["asked"] else "done")
        assert run["progress"] == (0.0 if run["asked"] else 1.0)
        assert run["segments"] > 0 and run["segment"] is not None
    trajectory = np.array(overview["trajectory"])
    assert len(trajectory) <= 2001
    np.testing.assert_allclose(
        trajectory[[0, -1]], drive.trajectory.position[[0, -1], :2], atol=0.006
    )
    travelled = vehicle_station(drive.trajectory, drive.trajectory.time)[-1]
    assert overview["length_m"] == pytest.approx(travelled, abs=0.06)


def test_each_segment_lies_on_the_run_it_is_counted_for(session: ReviewSession) -> None:
    places = run_places(session)
    owner = segment_runs(session, places)
    seg = session.run.segments
    counted = seg["label"] | session.effective_label()
    assert (owner[~counted] == -1).all()  # nothing unreviewed that no one calls guardrail
    on_runs = np.flatnonzero(owner >= 0)
    assert len(on_runs) >= 0.9 * counted.sum()  # the test street's guardrails are runs
    for s in on_runs:
        xy = seg["centroid"][s, :2]
        distances = [_distance_to_line(xy, place.path) for place in places]
        assert distances[owner[s]] <= RUN_REACH_M + 0.26  # the line sampled every 0.25 m
        assert distances[owner[s]] <= min(distances) + 0.26
    assert session.truth(on_runs).mean() >= 0.95  # and they are guardrails


def test_the_review_state_follows_the_labels(client: TestClient) -> None:
    runs = client.get("/api/overview").json()["runs"]
    first, second = runs[0], runs[1]
    detail = client.get(f"/api/segments/{first['segment']}").json()
    client.put(f"/api/segments/{first['segment']}/label", json={"label": detail["model_label"]})
    other = client.get(f"/api/segments/{second['segment']}").json()["model_label"]
    flipped = "other" if other == "guardrail" else "guardrail"
    client.put(f"/api/segments/{second['segment']}/label", json={"label": flipped})
    overview = client.get("/api/overview").json()
    after = {r["run_id"]: r for r in overview["runs"]}
    assert after[first["run_id"]]["reviewed"] == 1 and after[first["run_id"]]["changed"] == 0
    assert after[first["run_id"]]["segment"] != first["segment"]  # the next doubtful one
    assert after[second["run_id"]]["segments"] == second["segments"]  # reviewed still counts
    assert after[second["run_id"]]["changed"] == 1
    # One label is not a reviewed run: the share of what the queue asks that is labelled.
    for run in (after[first["run_id"]], after[second["run_id"]]):
        assert run["progress"] == pytest.approx(1 / (1 + run["asked"]), abs=1e-4)
        assert run["state"] == ("started" if run["asked"] else "done")
    assert any(run["state"] == "started" for run in after.values()), "runs with doubt left"
    assert overview["reviewed"] == 2
    assert overview["asked"] == client.get("/api/queue?limit=1").json()["asked"]
    client.post("/api/labels/undo")
    client.post("/api/labels/undo")
    again = {r["run_id"]: r for r in client.get("/api/overview").json()["runs"]}
    assert again[first["run_id"]] == first and again[second["run_id"]] == second


def test_a_run_folder_without_a_reconstruction_has_no_runs(
    drive_path: Path, run_path: Path, tmp_path: Path
) -> None:
    run = copy_run(run_path, tmp_path)
    shutil.rmtree(run / "reconstruction")
    session = new_session(drive_path, run, tmp_path / "review")
    try:
        with TestClient(create_app(session)) as client:
            overview = client.get("/api/overview").json()
        assert overview["runs"] == [] and len(overview["trajectory"]) > 1
        assert overview["segments_off_runs"] == int(
            (session.run.segments["label"] | session.effective_label()).sum()
        )
    finally:
        session.close()


def test_review_this_run_steps_through_its_doubtful_segments_along_the_road(
    client: TestClient, session: ReviewSession
) -> None:
    places = run_places(session)
    owner = segment_runs(session, places)
    seg = session.run.segments
    # The test model is sure of most segments: make every third segment on a run a coin toss.
    on_runs = np.flatnonzero(owner >= 0)
    seg["probability"][on_runs[::3]] = 0.5
    walked = 0
    for k, place in enumerate(places):
        run_id = place.row.run_id
        queue = client.get(f"/api/queue?run={run_id}&limit=500").json()
        items = queue["items"]
        ids = np.array([item["id"] for item in items], np.int64)
        reviewed = session.operator_label >= 0
        expected = np.flatnonzero((owner == k) & asked_segments(seg, reviewed))
        assert sorted(ids.tolist()) == expected.tolist()
        assert queue["asked"] == len(ids) and queue["done"] == (len(ids) == 0)
        assert queue["reviewed"] == int(reviewed[owner == k].sum())
        scanned = seg["time"][ids].mean(axis=1)
        assert (np.diff(scanned) >= 0).all()  # along the road, as scanned
        assert all(not item["reviewed"] for item in items)
        walked += len(ids)
        if len(ids):  # a labelled segment leaves the run's queue
            client.put(f"/api/segments/{int(ids[0])}/label", json={"label": "guardrail"})
            again = client.get(f"/api/queue?run={run_id}&limit=500").json()
            reviewed = session.operator_label >= 0
            left = (owner == k) & asked_segments(seg, reviewed)
            assert [item["id"] for item in again["items"]] == [s for s in ids if left[s]]
            assert int(ids[0]) not in [item["id"] for item in again["items"]]
            assert again["reviewed"] == queue["reviewed"] + 1
    assert walked > 0, "the test street's runs have doubtful segments"
    unknown = max(place.row.run_id for place in places) + 1
    assert client.get(f"/api/queue?run={unknown}").status_code == 404
    assert client.get("/api/queue?run=-1").status_code == 422


def test_a_redone_reconstruction_is_read_again(client: TestClient, session: ReviewSession) -> None:
    """The runs are kept between requests, and read again once models.json changes (as
    "Apply to the whole drive" rewrites it)."""
    before = client.get("/api/overview").json()["runs"]
    models = session.run.root / "reconstruction" / "models.json"
    document = json.loads(models.read_text())
    dropped = before[0]["run_id"]
    document["runs"] = [run for run in document["runs"] if run["run_id"] != dropped]
    models.write_text(json.dumps(document, indent=2))
    after = client.get("/api/overview").json()["runs"]
    assert [r["run_id"] for r in after] == [r["run_id"] for r in before[1:]]


def test_the_guardrail_segments_on_no_run_have_a_queue_along_the_road(
    client: TestClient, session: ReviewSession
) -> None:
    """What the route table cannot reach (a run without poles, a rail beyond its end poles, a
    mistake): the guardrail segments on no run, unreviewed, along the road."""
    places = run_places(session)
    seg = session.run.segments
    # Take the poles of the first run away: its segments lie on no run now.
    models_file = session.folder.reconstruction.models_file
    document = json.loads(models_file.read_text())
    document["runs"][0]["poles"] = []
    models_file.write_text(json.dumps(document))
    places = run_places(session)
    owner = segment_runs(session, places)
    counted = seg["label"] | session.effective_label() | (session.operator_label >= 0)
    expected = np.flatnonzero(counted & (owner < 0) & (seg["n_points"] >= 10))
    assert len(expected) >= 5, "the first run's segments are off the runs now"
    queue = client.get("/api/queue/off-runs?limit=500").json()
    ids = [item["id"] for item in queue["items"]]
    assert sorted(ids) == expected.tolist() and queue["asked"] == len(ids)
    scanned = seg["time"][ids].mean(axis=1)
    assert (np.diff(scanned) >= 0).all()  # along the road
    assert client.get("/api/overview").json()["segments_off_runs"] >= len(ids)
    client.put(f"/api/segments/{ids[0]}/label", json={"label": "guardrail"})
    again = client.get("/api/queue/off-runs?limit=500").json()
    assert [item["id"] for item in again["items"]] == ids[1:] and again["reviewed"] == 1
