"""Shared fixtures: a short simulated drive, made once per test session (and xdist worker)."""

from __future__ import annotations

from pathlib import Path

import pytest

from guardrail_core.formats.drive import Drive, load_drive
from guardrail_core.synth.scene import load_scene_spec
from guardrail_core.synth.simulate import SimulationOptions, simulate_drive

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
    from guardrail_core.extract.classify import ClassifierParams
    from guardrail_core.extract.model_folder import save_model
    from guardrail_core.extract.training import train_from_drives

    out = tmp_path_factory.mktemp("models") / "fast"
    save_model(train_from_drives([drive_path], params=ClassifierParams(mode="fast")), out)
    return out


@pytest.fixture(scope="session")
def run_path(drive: Drive, model_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The test drive processed with :func:`model_path`."""
    from guardrail_core.extract.model_folder import load_model
    from guardrail_core.process import process_drive

    out = tmp_path_factory.mktemp("runs") / "run"
    process_drive(drive, load_model(model_path), out)
    return out
