"""The ``guardrail`` command: help, simulate, info, and errors without tracebacks."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from guardrail_core.cli import main


def test_help_lists_the_commands(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    for command in ("simulate", "info", "train", "process", "evaluate", "demo"):
        assert command in out


def test_console_script_is_installed() -> None:
    exe = Path(sys.executable).parent / "guardrail"
    result = subprocess.run(
        [str(exe), "simulate", "--help"], capture_output=True, text=True, check=True
    )
    assert "--seed" in result.stdout and "--length" in result.stdout and "--scene" in result.stdout


def test_simulate_a_random_drive_and_describe_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "drive"
    code = main(
        [
            "simulate",
            str(out),
            "--seed",
            "4",
            "--length",
            "25",
            "--image-size",
            "160x120",
            "--image-every",
            "10",
            "--quiet",
        ]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "points" in text and "guardrail runs" in text and str(out.resolve()) in text
    assert (out / "drive.json").is_file() and (out / "truth" / "objects.json").is_file()
    assert main(["info", str(out)]) == 0


def test_simulate_takes_the_scanner_s_conditions_and_a_bare_roadside(tmp_path: Path) -> None:
    out = tmp_path / "drive"
    options = ["--range-noise", "0.02", "--dropout", "0.1", "--intensity-gain", "0.5"]
    args = ["simulate", str(out), "--seed", "4", "--length", "25", "--image-every", "1000"]
    assert main([*args, *options, "--no-roadside", "--quiet"]) == 0
    spec = yaml.safe_load((out / "truth" / "scene.yaml").read_text())
    assert spec["scanner"] == {"range_noise_m": 0.02, "dropout": 0.1, "intensity_gain": 0.5}
    assert "roadside" not in spec["road"]
    kinds = {o["kind"] for o in json.loads((out / "truth" / "objects.json").read_text())}
    assert not kinds & {"hedge", "shrub", "tall_grass"}
    # Long runs and a street without curbs, as a motorway's shoulder.
    road = tmp_path / "road"
    options = ["--long-runs", "1", "--curb-height", "0", "--height-jitter", "0.15", "--quiet"]
    assert main(["simulate", str(road), *args[2:], *options]) == 0
    spec = yaml.safe_load((road / "truth" / "scene.yaml").read_text())
    assert spec["road"]["curb"] == {"height": 0.0}
    assert spec["guardrails"][0]["length"] >= 40  # the first run: the street goes on past it
    assert all(0.85 <= g["height_scale"] <= 1.15 for g in spec["guardrails"])
    assert main(["simulate", str(tmp_path / "z"), "--long-runs", "2", "--quiet"]) == 2
    assert not (tmp_path / "z").exists()
    # A dropout out of range is named with its key, and nothing is written.
    assert main([*args[:1], str(tmp_path / "y"), "--dropout", "2", "--quiet"]) == 2
    assert not (tmp_path / "y").exists()


def test_errors_are_reported_without_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["info", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err
    assert "MissingDriveFileError" in err and "Traceback" not in err
    assert main(["simulate", str(tmp_path / "x"), "--scene", "no_such_scene", "--quiet"]) == 2
    assert "SceneSpecError" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_bad_image_spacing_is_refused_before_anything_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["simulate", str(tmp_path / "x"), "--image-every", "0", "--quiet"]) == 2
    assert "InvalidOptionError: image spacing must be positive" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_bad_image_size_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["simulate", "out", "--image-size", "big"])
    assert "WIDTHxHEIGHT" in capsys.readouterr().err
