"""``guardrail export`` writes any subset of its formats in one call, and refuses a call that
names none."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from guardrail_core.cli import main


def test_every_map_format_in_one_call(
    run_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = {
        "--cityjson": tmp_path / "guardrails.city.json",
        "--opendrive": tmp_path / "guardrails.xodr",
        "--3dtiles": tmp_path / "tiles",
        "--osm": tmp_path / "guardrails.osm",
    }
    argv = ["export", str(run_path)] + [word for pair in out.items() for word in map(str, pair)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    for path in out.values():
        assert f"wrote {path}" in printed or str(path) in printed, printed
    assert json.loads(out["--cityjson"].read_text())["type"] == "CityJSON"
    assert (out["--3dtiles"] / "tileset.json").is_file()
    assert out["--opendrive"].read_text().lstrip().startswith("<?xml")
    assert "barrier" in out["--osm"].read_text()


def test_a_call_without_a_format_is_refused(
    run_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["export", str(run_path)]) == 2
    err = capsys.readouterr().err
    assert "InvalidOptionError" in err and "--cityjson" in err
