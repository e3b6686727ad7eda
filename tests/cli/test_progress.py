"""Progress bars are drawn on a terminal only: a log or a pipe gets the summary lines alone."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from guardrail_core.cli import main
from guardrail_core.progress import progress_bar


class _Terminal(io.StringIO):
    """A stream that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def test_a_bar_is_drawn_on_a_terminal_only_and_only_when_asked() -> None:
    terminal, log = _Terminal(), io.StringIO()
    assert list(progress_bar(range(3), file=terminal, desc="work")) == [0, 1, 2]
    assert "\r" in terminal.getvalue() and "work" in terminal.getvalue()
    # Not a terminal, or not asked for: it still iterates and updates, and draws nothing.
    assert list(progress_bar(range(3), file=log, desc="work")) == [0, 1, 2]
    quiet = _Terminal()
    with progress_bar(total=3, file=quiet, enabled=False) as bar:
        bar.update(3)
        assert bar.disable
    assert log.getvalue() == "" and quiet.getvalue() == ""
    closed = io.StringIO()
    closed.close()
    with progress_bar(total=1, file=closed) as bar:  # a closed stream is no terminal
        assert bar.disable


def test_a_command_whose_stderr_is_not_a_terminal_draws_no_bars(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "drive"
    args = ["simulate", str(out), "--seed", "4", "--length", "25", "--image-size", "160x120"]
    assert main([*args, "--image-every", "10"]) == 0  # no --quiet: bars asked for
    captured = capsys.readouterr()  # pytest's streams are not terminals, as a log is not
    assert "\r" not in captured.err and "it/s" not in captured.err and "%|" not in captured.err
    assert captured.err == ""
    assert "guardrail runs" in captured.out and str(out.resolve()) in captured.out
