"""``guardrail serve``'s options refused before anything starts, and where its token comes from."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from app.serve import check_scene_options, serve, token_from
from guardrail_core.cli import main
from guardrail_core.errors import InvalidOptionError


@pytest.mark.parametrize(
    ("window_m", "point_budget", "message"),
    [
        (-5.0, 400_000, "--window"),
        (0.0, 400_000, "--window"),
        (math.nan, 400_000, "--window"),
        (1e9, 400_000, "--window"),
        (100.0, -1, "--point-budget"),
        (100.0, 0, "--point-budget"),
        (100.0, 100_000_000, "--point-budget"),
    ],
)
def test_a_scene_window_or_budget_out_of_range_is_refused_before_anything_starts(
    tmp_path: Path, window_m: float, point_budget: int, message: str
) -> None:
    with pytest.raises(InvalidOptionError, match=message):
        check_scene_options(window_m, point_budget)
    # serve() checks them first: the drive (which does not exist) is never opened.
    with pytest.raises(InvalidOptionError, match=message):
        serve(tmp_path / "no drive", window_m=window_m, point_budget=point_budget)
    check_scene_options(100.0, 400_000)  # the defaults pass


def test_the_cli_names_a_bad_window(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["serve", str(tmp_path / "no drive"), "--window", "nan"]) == 2
    err = capsys.readouterr().err
    assert "InvalidOptionError" in err and "--window" in err and "Traceback" not in err


def test_the_token_comes_from_the_flag_a_file_or_the_environment(tmp_path: Path) -> None:
    file = tmp_path / "token"
    file.write_text("from-the-file\n")
    env = {"GUARDRAIL_TOKEN": "from-the-environment"}
    assert token_from("from-the-flag", None, env) == "from-the-flag"
    assert token_from(None, file, env) == "from-the-file"
    assert token_from(None, None, env) == "from-the-environment"
    assert token_from(None, None, {}) is None
    with pytest.raises(InvalidOptionError, match="not both"):
        token_from("x", file, {})
    with pytest.raises(InvalidOptionError, match="cannot read it"):
        token_from(None, tmp_path / "missing", {})
    (tmp_path / "empty").write_text("\n")
    with pytest.raises(InvalidOptionError, match="empty"):
        token_from(None, tmp_path / "empty", {})
