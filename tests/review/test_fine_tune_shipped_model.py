"""An operator's Train from the shipped default model, on a run ``guardrail process`` made with it.

The shipped model reads the whole component's features (it was trained before chains); a
fine-tuning keeps the features the head it starts from reads. Every step waits on the job's
state, never on time.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.session import ReviewSession
from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR, load_model
from guardrail_core.extract.segment_truth import segment_truth
from guardrail_core.formats.drive import Drive
from guardrail_core.formats.run_folder import load_run
from guardrail_core.review.predictions import predict_run
from tests.app_fixtures import api_client, copy_run, new_session

#: How long a fine-tuning of the test drive may take before the test fails (about 10 s here).
JOB_TIMEOUT_S = 600


@pytest.fixture()
def session(drive_path: Path, shipped_run_path: Path, tmp_path: Path) -> Iterator[ReviewSession]:
    """``guardrail serve DRIVE --run RUN``: no model folder named, as a new user starts."""
    s = new_session(drive_path, copy_run(shipped_run_path, tmp_path), tmp_path / "review")
    yield s
    s.close()


@pytest.fixture()
def client(session: ReviewSession) -> Iterator[TestClient]:
    with api_client(session) as c:
        yield c


def test_train_from_the_shipped_model_then_activate(
    client: TestClient, session: ReviewSession, drive: Drive
) -> None:
    shipped = load_model(DEFAULT_MODEL_DIR)
    assert client.get("/api/info").json()["model"]["version"] == shipped.version
    before = load_run(session.run.root).segments["probability"].copy()

    # An operator labels 30 segments as they are: what the queue asks (the shipped model is sure
    # of most of this street), then the most uncertain others, as the gallery sorts them.
    assert drive.truth is not None
    truth = segment_truth(drive.truth.point_class, session.run.point_segment, len(session.run))
    queue = [row["id"] for row in client.get("/api/queue", params={"limit": 30}).json()["items"]]
    doubtful = client.get("/api/segments", params={"sort": "uncertainty", "limit": 60}).json()
    queue += [row["id"] for row in doubtful["items"] if row["id"] not in queue]
    queue = queue[:30]
    assert len(queue) == 30
    for s in queue:
        label = "guardrail" if truth[s] else "other"
        assert client.put(f"/api/segments/{s}/label", json={"label": label}).status_code == 200

    job_id = client.post("/api/train", json={"mode": "fast"}).json()["job"]
    job = client.jobs.wait(job_id, timeout=JOB_TIMEOUT_S)  # type: ignore[attr-defined]
    assert job.status == "done", job.error
    answer = client.get(f"/api/jobs/{job_id}").json()
    assert answer["error"] is None and answer["advice"] is None
    version = answer["result"]["version"]
    tuned = session.models.load(version)
    assert tuned.info["trained_on"]["segment_head_from"] == shipped.version
    assert tuned.info["trained_on"]["reviewed_segments"] == 30
    # Fine-tuned, it reads what the shipped head reads.
    assert tuned.info["segment_head"]["features"] == shipped.info["segment_head"]["features"]

    activated = client.post(f"/api/models/{version}/activate", json={})
    assert activated.status_code == 200, activated.text
    assert activated.json()["active"] == version
    run = load_run(session.run.root)
    assert run.info.model.version == version
    # The run's labels are the new model's: predicted again, not left as the shipped model's.
    again = predict_run(run, tuned, drive_root=drive.root)
    np.testing.assert_array_equal(run.segments["label"], again["label"])
    np.testing.assert_allclose(run.segments["probability"], again["probability"], atol=1e-6)
    assert np.abs(run.segments["probability"] - before).max() > 1e-3
    # And the operator's labels stand over the new predictions.
    rows = client.get("/api/segments", params={"reviewed": True, "limit": 100}).json()["items"]
    assert {row["id"]: row["label"] == "guardrail" for row in rows} == {
        s: bool(truth[s]) for s in queue
    }

    # With the fine-tuned model active, Train works again, from the shipped model once more.
    again = client.jobs.wait(  # type: ignore[attr-defined]
        client.post("/api/train", json={}).json()["job"], timeout=JOB_TIMEOUT_S
    )
    assert again.status == "done", again.error
    second = session.models.load(client.get(f"/api/jobs/{again.id}").json()["result"]["version"])
    assert second.info["trained_on"]["segment_head_from"] == shipped.version


def test_a_training_without_labels_to_learn_from_says_what_to_do(client: TestClient) -> None:
    """Only the operators' labels asked for, and none given: the job fails in words an
    operator can act on, and keeps the program's own error beside them."""
    job_id = client.post("/api/train", json={"include_unreviewed": False}).json()["job"]
    client.jobs.wait(job_id, timeout=JOB_TIMEOUT_S)  # type: ignore[attr-defined]
    job = client.get(f"/api/jobs/{job_id}").json()
    assert job["status"] == "failed"
    assert job["error"].startswith("TrainingDataError: ")
    assert job["advice"] == (
        "Not enough labels to learn from yet: fine-tuning needs segments of both kinds. "
        "Label more segments (g guardrail, o other), then press Fine-tune again."
    )
