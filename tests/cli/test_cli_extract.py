"""The extraction commands: ``guardrail train``, ``process`` and ``evaluate``, and their errors."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import laspy
import numpy as np
import pytest

from guardrail_core.cli import main
from guardrail_core.errors import InvalidOptionError
from guardrail_core.extract.classify.segment_head import SegmentHeadParams
from tests.drive_files import tile_file
from tests.file_tree import file_tree


def test_evaluate_prints_both_tables(
    drive_path: Path, run_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["evaluate", str(drive_path), "--run", str(run_path)]) == 0
    out = capsys.readouterr().out
    assert "Table 1" in out and "Table 2. Classification, after label correction" in out
    assert "before label correction" in out


def test_evaluate_json_is_one_object_with_the_documented_keys(
    drive_path: Path, run_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["evaluate", str(drive_path), "--run", str(run_path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    for block in ("detection", "detection_raw"):
        for name in ("guardrail", "other"):
            entry = result[block][name]
            assert {"recall", "precision", "f1", "n_true"} <= set(entry)
            assert 0.0 <= entry["f1"] <= 1.0
    n_true = result["detection"]["guardrail"]["n_true"] + result["detection"]["other"]["n_true"]
    assert n_true == result["segments"]["total"]


def test_train_then_process_from_the_command_line(
    drive_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = tmp_path / "model"
    assert main(["train", str(drive_path), "--out", str(model), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "trained a fast model" in out and "held out" in out
    info = json.loads((model / "model.json").read_text())
    assert info["trained_on"]["drives"][0]["drive"] == str(drive_path.resolve())
    run = tmp_path / "run"
    settings = ["--set", "classify.crop_probability_clip=0.05", "--set", "runs.min_points=150"]
    command = ["process", str(drive_path), "--model", str(model), "--out", str(run), "--quiet"]
    assert main(command + settings) == 0
    out = capsys.readouterr().out
    assert "segments from" in out and "after label correction" in out
    assert (run / "timings.json").is_file()
    params = json.loads((run / "run.json").read_text())["params"]
    assert params["classify"]["crop_probability_clip"] == 0.05
    models = json.loads((run / "reconstruction" / "models.json").read_text())
    assert models["params"]["runs"]["min_points"] == 150


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("classify.crop_probability_clip=0.7", "crop_probability_clip must lie within"),
        ("classify.bogus=1", "unknown extraction parameter classify.bogus"),
        ("lanes.width_m=3", "unknown stage 'lanes'"),
        ("poles", "expected STAGE.NAME=VALUE"),
    ],
)
def test_process_refuses_a_bad_setting_before_any_work(
    drive_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], setting: str, message: str
) -> None:
    run = tmp_path / "run"
    assert main(["process", str(drive_path), "--out", str(run), "--set", setting]) == 2
    err = capsys.readouterr().err
    assert "ParameterError" in err and message in err
    assert not run.exists()


def test_process_refuses_a_model_of_another_format_version(
    drive_path: Path, model_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = tmp_path / "model"
    shutil.copytree(model_path, model)
    info = json.loads((model / "model.json").read_text())
    info["format_version"] = 999
    (model / "model.json").write_text(json.dumps(info))
    run = tmp_path / "run"
    code = main(["process", str(drive_path), "--model", str(model), "--out", str(run), "--quiet"])
    assert code == 2
    assert "IncompatibleModelError" in capsys.readouterr().err
    assert not run.exists()


def test_process_refuses_nan_coordinates(
    drive_path: Path, model_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    copy = tmp_path / "drive"
    shutil.copytree(drive_path, copy)
    las = laspy.read(str(tile_file(copy)))
    times = np.array(las.gps_time)
    times[5] = np.nan
    las.gps_time = times
    las.write(str(tile_file(copy)))
    run = tmp_path / "run"
    code = main(["process", str(copy), "--model", str(model_path), "--out", str(run), "--quiet"])
    assert code == 2
    assert "NonFiniteCoordinatesError" in capsys.readouterr().err
    assert not run.exists()


def test_train_needs_truth(
    drive_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    copy = tmp_path / "drive"
    shutil.copytree(drive_path, copy)
    shutil.rmtree(copy / "truth")
    model = tmp_path / "model"
    assert main(["train", str(copy), "--out", str(model), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "MissingDriveFileError" in err and "truth" in err
    assert not model.exists()


def test_train_refuses_an_unknown_feature_to_ignore(
    drive_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = tmp_path / "model"
    args = ["train", str(drive_path), "--out", str(model), "--quiet"]
    assert main([*args, "--ignore-features", "intensity_mean,colour"]) == 2
    err = capsys.readouterr().err
    assert "ParameterError" in err and "ignored_features" in err and "colour" in err
    assert not model.exists()


def test_train_passes_the_feature_dropout_to_the_segment_head(
    drive_path: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    model = tmp_path / "model"
    args = ["train", str(drive_path), "--out", str(model), "--quiet"]
    assert main([*args, "--feature-dropout", "1"]) == 2
    err = capsys.readouterr().err
    assert "ParameterError" in err and "feature_dropout" in err
    heads = []

    def captured(*drives: object, head: object, **kwargs: object) -> None:
        heads.append(head)
        raise InvalidOptionError("stopped before training")

    monkeypatch.setattr(
        "guardrail_core.extract.classify.model_training.train_from_drives", captured
    )
    assert main([*args, "--feature-dropout", "0.3"]) == 2
    assert main(args) == 2
    assert [h.feature_dropout for h in heads] == [0.3, SegmentHeadParams().feature_dropout]
    assert not model.exists()
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    # The help names the default the params hold (it is written out so that --help needs no torch).
    help_text = " ".join(capsys.readouterr().out.split())
    assert re.search(rf"\(default {SegmentHeadParams().feature_dropout:g}[;:)]", help_text)


def test_train_refuses_an_output_holding_its_drive_before_training(
    drive_path: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    out = tmp_path / "out"
    copy = out / "drive"
    shutil.copytree(drive_path, copy)
    before = file_tree(out)

    def no_training(*args: object, **kwargs: object) -> None:
        raise AssertionError("the output is checked before training")

    monkeypatch.setattr(
        "guardrail_core.extract.classify.model_training.train_from_drives", no_training
    )
    for target in (out, copy, copy / "truth"):
        assert main(["train", str(copy), "--out", str(target), "--overwrite", "--quiet"]) == 2
        assert "InputInsideOutputError" in capsys.readouterr().err
    assert file_tree(out) == before


def test_evaluate_without_a_run_folder_is_a_named_error(
    drive_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["evaluate", str(drive_path), "--run", str(tmp_path / "nothing")]) == 2
    assert "RunFolderError" in capsys.readouterr().err
