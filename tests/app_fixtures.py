"""A review session on a copy of the test run (the app writes into the run when a model is
activated, and into its review folder whenever a label changes)."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from fastapi.testclient import TestClient

from app.jobs import JobRunner
from app.main import create_app
from app.session import ReviewSession


def copy_run(run_path: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(run_path, out)
    return out


def new_session(
    drive_path: Path, run: Path, review: Path, model_path: Path | None = None
) -> ReviewSession:
    return ReviewSession(
        drive_path, run, review_dir=review, operator="tester", model_dir=model_path
    )


@contextmanager
def api_client(session: ReviewSession) -> Iterator[TestClient]:
    """The app's API on ``session``, with a job runner of its own (``client.jobs``, to wait on
    a job's state), shut down afterwards."""
    jobs = JobRunner()
    with TestClient(create_app(session, jobs=jobs)) as client:
        client.jobs = jobs  # type: ignore[attr-defined]
        yield client
    jobs.shutdown()
