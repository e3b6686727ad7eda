"""The review app's REST API, through FastAPI's TestClient, on the test drive's run."""

from __future__ import annotations

import json
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.session import ReviewSession
from guardrail_core.errors import InvalidOptionError
from guardrail_core.extract.crops import CropParams, crop_window, cut_crop
from guardrail_core.formats.drive import Drive
from guardrail_core.formats.run_folder import load_run
from guardrail_core.review.queue import (
    MIN_QUEUE_POINTS,
    asked_segments,
    segment_queue_scores,
    unchecked_runs,
)
from tests.app_fixtures import api_client, copy_run, new_session


@pytest.fixture()
def session(drive_path: Path, run_path: Path, model_path: Path, tmp_path: Path):
    s = new_session(drive_path, copy_run(run_path, tmp_path), tmp_path / "review", model_path)
    yield s
    s.close()


@pytest.fixture()
def client(session: ReviewSession) -> Iterator[TestClient]:
    with api_client(session) as c:
        yield c


def _segment_with_crop(session: ReviewSession) -> int:
    return int(np.flatnonzero(session.run.segments["crop_status"] == 0)[0])


def test_info_describes_the_run(client: TestClient, session: ReviewSession, drive: Drive) -> None:
    info = client.get("/api/info").json()
    assert info["n_segments"] == len(session.run)
    assert info["n_points"] == len(drive.points)
    assert info["model"]["version"] == session.run.info.model.version
    assert info["token_required"] is False


def test_segments_are_paged_filtered_and_sorted(client: TestClient, session: ReviewSession):
    everything = client.get("/api/segments", params={"limit": 1000}).json()
    assert everything["total"] == len(session.run)
    assert [row["id"] for row in everything["items"]] == list(range(min(1000, len(session.run))))
    page = client.get("/api/segments", params={"offset": 5, "limit": 3}).json()
    assert [row["id"] for row in page["items"]] == [5, 6, 7]

    guardrail = client.get("/api/segments", params={"label": "guardrail", "limit": 1000}).json()
    assert guardrail["total"] == int(session.run.segments["label"].sum())
    assert all(row["label"] == "guardrail" for row in guardrail["items"])

    by_p = client.get(
        "/api/segments", params={"sort": "-probability", "crop": True, "limit": 1000}
    ).json()["items"]
    probabilities = [row["probability"] for row in by_p]
    assert probabilities == sorted(probabilities, reverse=True)
    assert all(row["crop_url"] for row in by_p)

    uncertain = client.get("/api/segments", params={"sort": "uncertainty", "crop": True}).json()
    u = [1 - abs(2 * row["probability"] - 1) for row in uncertain["items"]]
    # Non-increasing up to rounding: p and 1 - p are equally uncertain, and the server's sum
    # may round them 1e-16 apart in either order.
    assert all(a >= b - 1e-12 for a, b in zip(u, u[1:], strict=False))


def test_bad_requests_get_404_and_422(client: TestClient, session: ReviewSession) -> None:
    n = len(session.run)
    assert client.get(f"/api/segments/{n}").status_code == 404
    assert client.get("/api/segments/-1").status_code == 404
    assert client.get("/api/segments/abc").status_code == 422
    assert client.put("/api/segments/0/label", json={"label": "tree"}).status_code == 422
    assert client.put(f"/api/segments/{n}/label", json={"label": "other"}).status_code == 404
    batch = {"segments": [0, n + 5], "label": "other"}
    assert client.post("/api/labels/batch", json=batch).status_code == 404
    assert (
        client.post("/api/labels/batch", json={"segments": [], "label": "other"}).status_code == 422
    )
    assert client.get("/api/segments", params={"sort": "colour"}).status_code == 422
    assert client.put("/api/selection", json={"segments": [n]}).status_code == 404
    # Nothing of that reached the store.
    assert session.store.counts()["labelled_points"] == 0


def test_relabel_a_segment_then_undo(client: TestClient, session: ReviewSession) -> None:
    s = _segment_with_crop(session)
    before = client.get(f"/api/segments/{s}").json()
    flipped = "other" if before["label"] == "guardrail" else "guardrail"
    answer = client.put(f"/api/segments/{s}/label", json={"label": flipped}).json()
    assert answer["changed_points"] == before["n_points"]
    assert [row["id"] for row in answer["segments"]] == [s]
    after = client.get(f"/api/segments/{s}").json()
    assert after["label"] == flipped and after["reviewed"] is True
    assert after["model_label"] == before["model_label"]  # the model's label is kept apart
    assert after["history"][0]["new"] == flipped and after["history"][0]["who"] == "tester"

    undone = client.post("/api/labels/undo", json={}).json()
    assert undone["undone_batch"] == answer["batch"]
    again = client.get(f"/api/segments/{s}").json()
    assert again["label"] == before["label"] and again["reviewed"] is False
    assert client.post("/api/labels/undo", json={}).json()["batch"] is None  # nothing left to undo


def test_a_whole_connected_run_is_relabelled_at_once(client: TestClient, session: ReviewSession):
    component = session.run.segments["component"]
    sizes = np.bincount(component)
    s = int(np.flatnonzero(sizes[component] == sizes.max())[0])
    members = set(np.flatnonzero(component == component[s]).tolist())
    answer = client.post(
        "/api/labels/batch", json={"segments": [s], "label": "other", "expand": "component"}
    ).json()
    assert {row["id"] for row in answer["segments"]} == members
    assert all(row["label"] == "other" and row["reviewed"] for row in answer["segments"])
    n_points = int(session.run.segments["n_points"][list(members)].sum())
    assert session.store.counts()["labelled_points"] == n_points


def test_labels_survive_a_restart(
    drive_path: Path, run_path: Path, tmp_path: Path, session: ReviewSession
) -> None:
    s = _segment_with_crop(session)
    with TestClient(create_app(session)) as client:
        client.put(f"/api/segments/{s}/label", json={"label": "other"})
    session.close()
    reopened = new_session(drive_path, session.run.root, tmp_path / "review")
    try:
        with TestClient(create_app(reopened)) as client:
            row = client.get(f"/api/segments/{s}").json()
        assert row["label"] == "other" and row["reviewed"] is True
        assert row["history"][0]["new"] == "other"
    finally:
        reopened.close()


def test_queue_puts_disagreement_unchecked_runs_and_uncertainty_first(
    client: TestClient, session: ReviewSession
):
    seg = session.run.segments
    # The test model is sure of most segments: make every fifth one doubtful (P 5-95 %).
    seg["probability"][::5] = np.linspace(0.06, 0.94, len(seg["probability"][::5]))
    queue = client.get("/api/queue", params={"limit": 50}).json()
    items = queue["items"]
    scores = [row["score"] for row in items]
    assert scores == sorted(scores, reverse=True)
    big = seg["n_points"] >= MIN_QUEUE_POINTS
    assert all(row["n_points"] >= MIN_QUEUE_POINTS for row in items)  # too small to judge
    assert (~big).any(), "the test street has tiny segments to leave out"
    nobody = np.zeros(len(seg["label"]), bool)
    asked = asked_segments(seg, nobody)
    assert queue["asked"] == int(asked.sum()) > 50 and queue["reviewed"] == 0
    assert not queue["done"]
    assert all(asked[row["id"]] for row in items)
    expected = segment_queue_scores(seg, nobody)
    assert scores == [round(float(expected[row["id"]]), 4) for row in items]
    # Nothing asked scores more than the last one shown.
    assert expected[asked].max() == pytest.approx(scores[0], abs=1e-4)
    assert np.sort(expected[asked])[::-1][49] == pytest.approx(scores[-1], abs=1e-4)
    disagree = (seg["raw_label"] != seg["label"]) & big
    unchecked = unchecked_runs(
        seg["component"], seg["label"], seg["n_points"], nobody, segment_queue_scores(seg)
    )
    assert unchecked.any(), "the test street has guardrail runs"
    first = int((disagree | unchecked).sum())
    assert 0 < first < 50
    reasons = [row["reason"] for row in items]
    assert reasons[first:] == ["uncertain"] * (50 - first)
    want = ["disagrees" if disagree[row["id"]] else "unchecked" for row in items[:first]]
    assert reasons[:first] == want and "unchecked" in want
    # Looking at one segment of a run checks the whole run: its marked segment leaves the queue.
    ids = [row["id"] for row in items]
    marked = next(row["id"] for row in items if row["reason"] == "unchecked")
    same_run = np.flatnonzero((seg["component"] == seg["component"][marked]) & seg["label"])
    other = int(next(s for s in same_run if s != marked))
    client.put(f"/api/segments/{other}/label", json={"label": "guardrail"})
    after = {
        row["id"]: row for row in client.get("/api/queue", params={"limit": 500}).json()["items"]
    }
    assert marked not in after or after[marked]["reason"] != "unchecked"
    assert other not in after
    first_id = ids[0]
    client.put(f"/api/segments/{first_id}/label", json={"label": "other"})
    assert first_id not in [row["id"] for row in client.get("/api/queue").json()["items"]]


def test_the_queue_has_an_end(client: TestClient, session: ReviewSession) -> None:
    """Only what the model is unsure of (or the correction changed, or stands for a run nobody
    has looked at) is asked; once that is labelled, the review is done."""
    seg = session.run.segments
    sure = np.abs(seg["probability"] - 0.5) > 0.45
    agrees = seg["raw_label"] == seg["label"]
    queue = client.get("/api/queue", params={"limit": 500}).json()
    asked = queue["asked"]
    assert 0 < asked < len(seg["label"]) / 2
    for row in queue["items"]:
        if row["reason"] == "uncertain":
            assert not sure[row["id"]]
    assert (sure & agrees & (seg["n_points"] >= MIN_QUEUE_POINTS)).sum() > asked
    labelled = 0
    while not (queue := client.get("/api/queue", params={"limit": 500}).json())["done"]:
        ids = [row["id"] for row in queue["items"]]
        client.post("/api/labels/batch", json={"segments": ids, "label": "guardrail"})
        labelled += len(ids)
        assert labelled <= asked  # labelling asks nothing new
    assert queue["items"] == [] and queue["asked"] == 0
    assert queue["reviewed"] == labelled
    overview = client.get("/api/overview").json()
    assert overview["asked"] == 0 and overview["reviewed"] == labelled
    assert all(run["state"] == "done" and run["progress"] == 1.0 for run in overview["runs"])


def test_selection_round_trip(client: TestClient, session: ReviewSession) -> None:
    version = client.get("/api/selection").json()["version"]
    both = {"segments": [1, 3], "lasso_points": 0, "version": version + 1}
    assert client.put("/api/selection", json={"segments": [3, 1, 3]}).json() == both
    assert client.get("/api/selection").json() == both
    heard = []
    session.subscribe(lambda event, ids: heard.append((event, list(ids))))
    client.put("/api/selection", json={"segments": [2]})
    assert heard == [("selection", [2])]


def test_the_selection_s_long_poll_answers_when_the_3d_view_changes_it(
    client: TestClient, session: ReviewSession
) -> None:
    """GET /api/selection?after=N waits while the version is N and answers as soon as a click
    in the 3D view (session.select, from another thread) moves it."""
    version = client.get("/api/selection").json()["version"]
    # A version the page has not seen is answered at once.
    stale = client.get("/api/selection", params={"after": version + 7, "wait_s": 25}).json()
    assert stale["version"] == version
    answers: list[dict] = []
    poll = threading.Thread(
        target=lambda: answers.append(
            client.get("/api/selection", params={"after": version, "wait_s": 25}).json()
        )
    )
    poll.start()
    deadline = time.monotonic() + 20
    while not session.selection_watch._waiters and time.monotonic() < deadline:
        time.sleep(0.005)  # until the request waits (state, not time, decides)
    assert session.selection_watch._waiters, "the long poll never waited"
    session.select([4])
    poll.join(timeout=20)  # far less than its 25 s: the change woke it
    assert not poll.is_alive()
    assert answers == [{"segments": [4], "lasso_points": 0, "version": version + 1}]
    assert not session.selection_watch._waiters
    # Nothing changes: the poll ends after wait_s with the same version.
    quiet = client.get("/api/selection", params={"after": version + 1, "wait_s": 0.05}).json()
    assert quiet["version"] == version + 1
    assert client.get("/api/selection", params={"after": 0, "wait_s": 26}).status_code == 422


def test_a_lasso_s_points_are_labelled_alone_and_undone(
    client: TestClient, session: ReviewSession
) -> None:
    """The 3D scene's lasso selects points (app.scene.viewer.ReviewScene.close_lasso); the
    page labels them through POST /api/labels/lasso: those points only, one undoable batch."""
    assert client.post("/api/labels/lasso", json={"label": "guardrail"}).status_code == 409
    big = int(np.argmax(session.run.segments["n_points"]))
    points = session.tiles.points_of([big, big + 1])
    half = points[::2]  # half of two segments' points, and a road point left out
    road = int(np.flatnonzero(session.folder.point_segment() == -1)[0])
    segments = session.select_points(np.append(half, road))
    assert segments.tolist() == [big, big + 1]
    selection = client.get("/api/selection").json()
    assert selection["segments"] == [big, big + 1] and selection["lasso_points"] == len(half)
    answer = client.post("/api/labels/lasso", json={"label": "other"}).json()
    assert answer["changed_points"] == len(half)
    assert [row["id"] for row in answer["segments"]] == [big, big + 1]
    assert (session.store.labels_at(half) == 0).all()
    assert (session.store.labels_at(np.setdiff1d(points, half)) == -1).all()
    assert session.store.counts()["labelled_points"] == len(half)
    assert client.post("/api/labels/undo").json()["changed_points"] == len(half)
    assert session.store.counts()["labelled_points"] == 0
    client.put("/api/selection", json={"segments": [big]})  # lets the lasso go
    assert client.get("/api/selection").json()["lasso_points"] == 0
    assert client.post("/api/labels/lasso", json={"label": "other"}).status_code == 409


def test_crops_are_served_and_missing_ones_are_404(client: TestClient, session: ReviewSession):
    """The crop is cut from the drive's image on request (the run stores none)."""
    s = _segment_with_crop(session)
    response = client.get(f"/api/segments/{s}/crop.jpg")
    assert response.status_code == 200 and response.headers["content-type"] == "image/jpeg"
    served = cv2.imdecode(np.frombuffer(response.content, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
    drive, seg = session.drive, session.run.segments
    image = drive.read_image(drive.images[int(seg["image"][s])])
    top_left, side = crop_window(seg["rect"][s], CropParams())
    expected = cut_crop(image, top_left[0], int(side[0]), 128)
    assert served.shape == (128, 128, 3)
    assert np.abs(served.astype(float) - expected).mean() < 3.0  # JPEG's loss only
    without = np.flatnonzero(seg["crop_status"] != 0)
    assert len(without)
    assert client.get(f"/api/segments/{int(without[0])}/crop.jpg").status_code == 404
    assert client.get(f"/api/segments/{len(seg['image'])}/crop.jpg").status_code == 404


def test_token_is_checked_on_every_api_call(session: ReviewSession) -> None:
    with TestClient(create_app(session, token="s3cret")) as client:
        for url in ("/api/info", "/api/segments", "/api/queue", "/api/models", "/api/downloads"):
            assert client.get(url).status_code == 401, url
        assert client.put("/api/segments/0/label", json={"label": "other"}).status_code == 401
        assert client.post("/api/train", json={}).status_code == 401
        wrong = {"Authorization": "Bearer nope"}
        assert client.get("/api/info", headers=wrong).status_code == 401
        good = {"Authorization": "Bearer s3cret"}
        assert client.get("/api/info", headers=good).json()["token_required"] is True
        assert client.get("/api/info", params={"token": "s3cret"}).status_code == 200
        assert client.get("/static/index.html").status_code == 200  # pages hold no data
    assert session.store.counts()["labelled_points"] == 0


def test_serving_beyond_localhost_needs_a_token(drive_path: Path, run_path: Path) -> None:
    from app.serve import serve

    with pytest.raises(InvalidOptionError, match="--token"):
        serve(drive_path, run_path, host="0.0.0.0")


def test_downloads_are_listed_files_only(client: TestClient, session: ReviewSession) -> None:
    items = {row["name"] for row in client.get("/api/downloads").json()["items"]}
    assert {"inventory.csv", "inventory.geojson", "meshes/guardrails.glb"} <= items
    csv = client.get("/api/downloads/inventory.csv")
    assert csv.status_code == 200 and csv.text.startswith("run_id")
    for sneaky in ("../run.json", "..%2Frun.json", "models.json", "meshes/../../run.json"):
        assert client.get(f"/api/downloads/{sneaky}").status_code == 404, sneaky


def test_fine_tune_then_activate(client: TestClient, session: ReviewSession) -> None:
    current = session.models.active_version
    # An operator corrects a few segments: the new model must learn from them.
    seg = session.run.segments
    guardrail = np.flatnonzero(seg["label"])[:5].tolist()
    client.post("/api/labels/batch", json={"segments": guardrail, "label": "guardrail"})
    job_id = client.post("/api/train", json={"mode": "fast"}).json()["job"]
    job = client.jobs.wait(job_id, timeout=300)  # type: ignore[attr-defined]
    assert job.status == "done", job.error
    listed = client.get("/api/jobs", params={"kind": "train"}).json()["items"]
    assert [j["id"] for j in listed] == [job_id] and listed[0]["status"] == "done"
    assert client.get("/api/jobs/nope").status_code == 404
    result = client.get(f"/api/jobs/{job_id}").json()["result"]
    new, cur = result["metrics_new"], result["metrics_current"]
    assert new is not None and cur is not None
    assert new["n_held_out"] == cur["n_held_out"] == result["held_out_segments"] > 0
    assert result["current_version"] == current
    # The active model was fine-tuned, not replaced by one taught by this run alone.
    trained_on = session.models.load(result["version"]).info["trained_on"]
    assert trained_on["segment_head_from"] == current

    models = client.get("/api/models").json()
    versions = {m["version"]: m for m in models["models"]}
    assert models["active"] == current and versions[result["version"]]["active"] is False

    assert client.post("/api/models/nonexistent/activate", json={}).status_code == 404
    answer = client.post(f"/api/models/{result['version']}/activate", json={}).json()
    assert answer["active"] == result["version"]
    run = load_run(session.run.root)
    assert run.info.model.version == result["version"]
    assert client.get("/api/info").json()["model"]["version"] == result["version"]
    # Operator labels outlive the model change.
    rows = client.get("/api/segments", params={"reviewed": True, "limit": 100}).json()["items"]
    assert sorted(row["id"] for row in rows) == guardrail
    assert all(row["label"] == "guardrail" for row in rows)
    # Trained again with the fine-tuned model active: it starts from the model that made the run
    # again, with every label so far, not from the fine-tuned one.
    again = client.jobs.wait(  # type: ignore[attr-defined]
        client.post("/api/train", json={"mode": "fast"}).json()["job"], timeout=300
    )
    assert again.status == "done", again.error
    second = client.get(f"/api/jobs/{again.id}").json()["result"]["version"]
    assert session.models.load(second).info["trained_on"]["segment_head_from"] == current
    # And the model that made the run can be activated again (its folder was given).
    assert client.post(f"/api/models/{current}/activate", json={}).json()["active"] == current


def test_a_second_training_while_one_runs_is_refused(client: TestClient) -> None:
    first = client.post("/api/train", json={}).json()["job"]
    second = client.post("/api/train", json={})
    if client.get(f"/api/jobs/{first}").json()["status"] in ("queued", "running"):
        assert second.status_code == 409
    client.jobs.wait(first, timeout=300)  # type: ignore[attr-defined]


def test_reconstruction_is_redone_with_new_parameters(client: TestClient, session: ReviewSession):
    bad = client.post("/api/reconstruction/apply", json={"params": {"pipes": {"nope": 1}}})
    assert bad.status_code == 422
    params = {"pipes": {"histogram_factor": 3.5}}
    job_id = client.post("/api/reconstruction/apply", json={"params": params}).json()["job"]
    job = client.jobs.wait(job_id, timeout=300)  # type: ignore[attr-defined]
    assert job.status == "done", job.error
    saved = json.loads(session.folder.reconstruction.models_file.read_text())
    assert saved["params"]["pipes"]["histogram_factor"] == 3.5
    summary = client.get(f"/api/jobs/{job_id}").json()["result"]["summary"]
    assert summary["runs"] == len(saved["runs"]) and "models.json" in summary["files"]
    assert client.get("/api/reconstruction").json()["params"]["pipes"]["histogram_factor"] == 3.5


def test_guardrail_train_takes_the_store_labels(
    session: ReviewSession, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from guardrail_core.cli import main
    from guardrail_core.extract.classify.model_folder import load_model

    seg = session.run.segments
    session.relabel(np.flatnonzero(seg["label"])[:3], "other")
    store = session.store.path
    out = tmp_path / "model"
    run = str(session.run.root)
    # The model that made the run is neither the shipped one nor one the app fine-tuned: the
    # command says so and draws a new head.
    assert main(["train", "--run", run, "--labels", str(store), "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "operator-labelled points" in said and "not at hand" in said
    trained_on = load_model(out).info["trained_on"]
    assert "operator labels" in json.dumps(trained_on)
    assert trained_on["segment_head_from"] is None
    # Fine-tuning the model that made the run.
    made = session.models.fine_tuning_start()
    assert made is not None and made.version == session.run.info.model.version
    tuned = tmp_path / "tuned"
    start = ["--start-from", str(session.models.run_model_dir)]
    assert main(["train", "--run", run, "--labels", str(store), "--out", str(tuned), *start]) == 0
    assert load_model(tuned).info["trained_on"]["segment_head_from"] == made.version
    # Next to the label store, where the app keeps its models, it is found without being named;
    # --fresh-head draws a new head all the same.
    kept = store.parent / "models" / made.version
    shutil.copytree(session.models.run_model_dir, kept)
    try:
        found = tmp_path / "found"
        assert main(["train", "--run", run, "--labels", str(store), "--out", str(found)]) == 0
        assert f"fine-tuning the segment head of model {made.version}" in capsys.readouterr().out
        assert load_model(found).info["trained_on"]["segment_head_from"] == made.version
        fresh = ["--fresh-head", "--out", str(tmp_path / "fresh")]
        assert main(["train", "--run", run, "--labels", str(store), *fresh]) == 0
        assert load_model(tmp_path / "fresh").info["trained_on"]["segment_head_from"] is None
    finally:
        shutil.rmtree(kept)
    # Drives and --run together, or a store that is not there, are named errors.
    assert main(["train", "x", "--run", run, "--out", str(tmp_path / "m2")]) == 2
    assert main(["train", "x", *start, "--out", str(tmp_path / "m2")]) == 2
    assert "--start-from" in capsys.readouterr().err
    both = ["train", "--run", run, *start, "--fresh-head", "--out", str(tmp_path / "m2")]
    assert main(both) == 2
    assert "not both" in capsys.readouterr().err
    missing = ["train", "--run", run, "--labels", str(tmp_path / "nope.sqlite"), "--out", "m3"]
    assert main(missing) == 2
    assert "LabelStoreError" in capsys.readouterr().err
