"""The review app on a run whose segment features another version of guardrail laid out: the
model is refused by name (409) and training says what to do, and the run stays as it was."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.jobs import JobRunner
from app.main import create_app
from app.session import ReviewSession
from tests.app_fixtures import new_session
from tests.run_files import copy_run_with_features_of_another_layout


@pytest.fixture()
def old_run(run_path: Path, tmp_path: Path) -> Path:
    copy_run_with_features_of_another_layout(run_path, tmp_path / "run")
    return tmp_path / "run"


@pytest.fixture()
def client(
    drive_path: Path, old_run: Path, model_path: Path, tmp_path: Path
) -> Iterator[TestClient]:
    session: ReviewSession = new_session(drive_path, old_run, tmp_path / "review", model_path)
    jobs = JobRunner()
    with TestClient(create_app(session, jobs=jobs)) as c:
        yield c
    jobs.shutdown()
    session.close()


def test_a_model_is_refused_on_a_run_of_another_feature_layout(
    client: TestClient, old_run: Path
) -> None:
    before = {name: (old_run / name).read_bytes() for name in ("segments.npz", "run.json")}
    version = client.get("/api/models").json()["active"]
    answer = client.post(f"/api/models/{version}/activate", json={})
    assert answer.status_code == 409
    assert "another version of guardrail" in answer.json()["detail"]
    assert "process the drive again" in answer.json()["detail"]
    for name, content in before.items():
        assert (old_run / name).read_bytes() == content, name


def test_a_training_on_a_run_of_another_feature_layout_says_what_to_do(
    client: TestClient, old_run: Path
) -> None:
    before = {name: (old_run / name).read_bytes() for name in ("segments.npz", "run.json")}
    job_id = client.post("/api/train", json={}).json()["job"]
    job = client.app.state.jobs.wait(job_id, timeout=600)
    assert job.status == "failed"
    assert job.error.startswith("IncompatibleModelError: ")
    assert "Process the drive again (guardrail process DRIVE --out RUN)" in job.advice
    assert "your labels are kept" in job.advice
    for name, content in before.items():
        assert (old_run / name).read_bytes() == content, name
