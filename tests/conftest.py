"""Shared fixtures: a short simulated drive, made once per test session (and xdist worker)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from guardrail_core.formats.drive import Drive, load_drive
from guardrail_core.synth.scene import load_scene_spec
from guardrail_core.synth.simulate import SimulationOptions, simulate_drive

if TYPE_CHECKING:  # the app's modules load FastAPI and viser: only where a test asks for them
    from fastapi.testclient import TestClient

    from app.session import ReviewSession

TEST_SEED = 11
#: Default camera resolution: thin pipes need it for the projection test (see test_simulate).
TEST_OPTIONS = SimulationOptions(image_every_m=5.0)
#: For tests that only compare drives with each other.
SMALL_OPTIONS = SimulationOptions(image_every_m=8.0, image_size=(160, 120))


@pytest.fixture(scope="session")
def drive_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A ~32 m drive along ``data_samples/scenes/test_straight.yaml``."""
    out = tmp_path_factory.mktemp("drives") / "test_straight"
    simulate_drive(
        load_scene_spec("test_straight"), out, seed=TEST_SEED, options=TEST_OPTIONS, progress=False
    )
    return out


@pytest.fixture(scope="session")
def drive(drive_path: Path) -> Drive:
    return load_drive(drive_path)


@pytest.fixture(scope="session")
def model_path(drive_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fast-mode classifier trained on the test drive's truth."""
    from guardrail_core.extract.classify.crop_classifier_params import ClassifierParams
    from guardrail_core.extract.classify.model_folder import save_model
    from guardrail_core.extract.classify.model_training import train_from_drives

    out = tmp_path_factory.mktemp("models") / "fast"
    save_model(train_from_drives([drive_path], params=ClassifierParams(mode="fast")), out)
    return out


@pytest.fixture(scope="session")
def run_path(drive: Drive, model_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The test drive processed with :func:`model_path`."""
    from guardrail_core.extract.classify.model_folder import load_model
    from guardrail_core.process import process_drive

    out = tmp_path_factory.mktemp("runs") / "run"
    process_drive(drive, load_model(model_path), out)
    return out


@pytest.fixture(scope="session")
def shipped_run_path(drive_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The test drive processed by ``guardrail process`` with the shipped default model, as a
    user's first run is (no ``--model``)."""
    from guardrail_core.cli import main

    out = tmp_path_factory.mktemp("shipped") / "run"
    command = ["process", str(drive_path), "--out", str(out), "--workers", "1", "--quiet"]
    assert main(command) == 0
    return out


@pytest.fixture(scope="module")
def module_session(
    drive_path: Path, run_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[ReviewSession]:
    """A review session on a copy of the test run, shared by one module's tests (for tests
    that change nothing the others see)."""
    from tests.app_fixtures import copy_run, new_session

    tmp = tmp_path_factory.mktemp("session")
    session = new_session(drive_path, copy_run(run_path, tmp), tmp / "review")
    yield session
    session.close()


@pytest.fixture(scope="module")
def module_client(module_session: ReviewSession) -> Iterator[TestClient]:
    """The review app's API on :func:`module_session`."""
    from fastapi.testclient import TestClient

    from app.main import create_app

    with TestClient(create_app(module_session)) as client:
        yield client
