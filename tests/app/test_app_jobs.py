"""Background jobs are bounded: one queued or running per kind, a time limit, and cancellation
(queued: never starts; running: stops at its next progress report, leaving nothing half-written).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app import jobs as jobs_module
from app.jobs import JobBusyError, JobRunner
from app.main import create_app
from app.session import ReviewSession
from guardrail_core.formats.drive import load_drive
from tests.app_fixtures import copy_run, new_session
from tests.file_tree import file_tree

Report = Callable[[float, str], None]


@pytest.fixture()
def runner() -> Iterator[JobRunner]:
    r = JobRunner()
    yield r
    r.shutdown()


def _blocking(started: threading.Event, release: threading.Event) -> Callable[[Report], dict]:
    def work(report: Report) -> dict[str, Any]:
        started.set()
        release.wait(60)
        return {}

    return work


def _reporting_forever(started: threading.Event) -> Callable[[Report], dict]:
    def work(report: Report) -> dict[str, Any]:
        started.set()
        while True:  # ends only by report raising
            report(0.5, "working")
            threading.Event().wait(0.01)

    return work


def test_a_running_job_stops_at_its_next_report_when_cancelled(runner: JobRunner) -> None:
    started = threading.Event()
    job = runner.submit("reconstruct", _reporting_forever(started))
    assert started.wait(30)
    runner.cancel(job.id)
    ended = runner.wait(job.id, timeout=30)
    assert ended.status == "cancelled" and ended.error is None


def test_a_queued_job_cancelled_never_starts(runner: JobRunner) -> None:
    started, release = threading.Event(), threading.Event()
    first = runner.submit("train", _blocking(started, release))
    assert started.wait(30)
    ran = threading.Event()
    queued = runner.submit("reconstruct", lambda report: ran.set() or {})
    assert runner.get(queued.id).status == "queued"
    assert runner.cancel(queued.id).status == "cancelled"
    release.set()
    assert runner.wait(first.id).status == "done"
    follow = runner.submit("reconstruct", lambda report: {})  # the worker went past it
    assert runner.wait(follow.id).status == "done"
    assert not ran.is_set() and runner.get(queued.id).status == "cancelled"


def test_one_job_of_a_kind_at_a_time(runner: JobRunner) -> None:
    started, release = threading.Event(), threading.Event()
    first = runner.submit("train", _blocking(started, release))
    with pytest.raises(JobBusyError, match=first.id):
        runner.submit("train", lambda report: {})
    release.set()
    assert runner.wait(first.id).status == "done"
    assert runner.wait(runner.submit("train", lambda report: {}).id).status == "done"


def test_a_job_past_its_time_limit_fails_naming_the_limit(
    runner: JobRunner, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(jobs_module.TIME_LIMIT_S, "reconstruct", 0.05)
    job = runner.submit("reconstruct", _reporting_forever(threading.Event()))
    ended = runner.wait(job.id, timeout=30)
    assert ended.status == "failed" and "limit of 0.05 s" in (ended.error or "")


@pytest.fixture()
def session(drive_path: Path, run_path: Path, model_path: Path, tmp_path: Path):
    s = new_session(drive_path, copy_run(run_path, tmp_path), tmp_path / "review", model_path)
    yield s
    s.close()


def test_the_api_cancels_a_queued_reconstruction_and_refuses_a_second(
    session: ReviewSession,
) -> None:
    runner = JobRunner()
    started, release = threading.Event(), threading.Event()
    runner.submit("train", _blocking(started, release))  # holds the one worker thread
    assert started.wait(30)
    before = file_tree(session.run.root / "reconstruction")
    with TestClient(create_app(session, jobs=runner)) as client:
        job = client.post("/api/reconstruction/apply", json={"params": {}}).json()["job"]
        again = client.post("/api/reconstruction/apply", json={"params": {}})
        assert again.status_code == 409 and job in again.json()["detail"]
        assert client.post("/api/train", json={}).status_code == 409
        assert client.request("DELETE", "/api/jobs/nope", json={}).status_code == 404
        cancelled = client.request("DELETE", f"/api/jobs/{job}", json={})
        assert cancelled.status_code == 200 and cancelled.json()["status"] == "cancelled"
        assert client.request("DELETE", f"/api/jobs/{job}", json={}).status_code == 409
        release.set()
        assert runner.wait(job).status == "cancelled"
    runner.shutdown()
    assert file_tree(session.run.root / "reconstruction") == before


def test_a_reconstruction_stopped_half_way_leaves_the_previous_one(
    session: ReviewSession,
) -> None:
    from guardrail_core.reconstruct.writing import reconstruct_into

    folder = session.run.root / "reconstruction"
    before = file_tree(folder)
    drive = load_drive(session.drive.root)

    def stop_after_the_first_run(done: int, runs: int) -> None:
        if done == 1:
            raise RuntimeError("stopped")

    with pytest.raises(RuntimeError, match="stopped"):
        reconstruct_into(
            session.run.root,
            drive.points.xyz,
            session.run.point_segment,
            session.effective_label(),
            drive.trajectory.position,
            origin=drive.origin,
            crs=drive.crs,
            on_run=stop_after_the_first_run,
        )
    assert file_tree(folder) == before
    assert not [p for p in folder.parent.iterdir() if p.name.startswith(".reconstruction")]
