"""The review app reads its run through the run folder object: a folder of another format version
or without a reconstruction gets a clear answer, never a crash."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.run_tuning import RunTuner
from app.serve import default_run
from app.session import ReviewSession
from guardrail_core.errors import (
    NotARunFolderError,
    ReconstructionFormatVersionError,
    RunFolderError,
    RunFormatVersionError,
)
from tests.app_fixtures import api_client, copy_run, new_session


@pytest.fixture()
def session(drive_path: Path, run_path: Path, tmp_path: Path) -> Iterator[ReviewSession]:
    s = new_session(drive_path, copy_run(run_path, tmp_path), tmp_path / "review")
    yield s
    s.close()


@pytest.fixture()
def client(session: ReviewSession) -> Iterator[TestClient]:
    with api_client(session) as c:
        yield c


def _set_version(path: Path, version: object) -> None:
    data = json.loads(path.read_text())
    data["format_version"] = version
    path.write_text(json.dumps(data))


def test_a_reconstruction_of_another_version_answers_409_with_the_reason(
    client: TestClient, session: ReviewSession
) -> None:
    assert client.get("/api/reconstruction").json()["present"] is True
    _set_version(session.folder.reconstruction.models_file, 99)
    answer = client.get("/api/reconstruction")
    assert answer.status_code == 409
    detail = answer.json()["detail"]
    assert "reconstruction format 99" in detail and "guardrail reconstruct" in detail
    with pytest.raises(ReconstructionFormatVersionError):
        RunTuner(session.folder)  # the 3D scene's sliders then stay off
    # The files themselves can still be downloaded.
    assert client.get("/api/downloads/inventory.csv").status_code == 200


def test_a_run_without_reconstruction_is_reported_absent(
    client: TestClient, session: ReviewSession
) -> None:
    models = session.folder.reconstruction.models_file
    models.rename(models.with_suffix(".bak"))
    answer = client.get("/api/reconstruction")
    assert answer.status_code == 200
    assert answer.json()["present"] is False and answer.json()["runs"] == []


def test_the_route_lists_the_runs_of_models_json(
    client: TestClient, session: ReviewSession
) -> None:
    saved = json.loads(session.folder.reconstruction.models_file.read_text())
    runs = client.get("/api/reconstruction").json()["runs"]
    assert [r["run_id"] for r in runs] == [r["run_id"] for r in saved["runs"]]
    assert [r["poles"] for r in runs] == [len(r["poles"]) for r in saved["runs"]]
    assert [r["type"] for r in runs] == [(r["model"] or {}).get("type") for r in saved["runs"]]


def test_a_session_refuses_what_is_not_a_run_of_this_version(
    drive_path: Path, run_path: Path, tmp_path: Path
) -> None:
    with pytest.raises(NotARunFolderError):
        ReviewSession(drive_path, drive_path, review_dir=tmp_path / "review")
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text((run_path / "run.json").read_text())
    _set_version(run / "run.json", 5)
    with pytest.raises(RunFormatVersionError, match="run format version 5"):
        ReviewSession(drive_path, run, review_dir=tmp_path / "review")


def test_serve_needs_a_run_folder_beside_the_drive(tmp_path: Path) -> None:
    (tmp_path / "drive").mkdir()
    with pytest.raises(RunFolderError, match="--run"):
        default_run(tmp_path / "drive")
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "run.json").write_text("{}")
    assert default_run(tmp_path / "drive") == (tmp_path / "run").resolve()
