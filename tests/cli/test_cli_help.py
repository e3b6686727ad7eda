"""``guardrail --version``, and the help of every sub-command: each positional explained, each
default shown once."""

from __future__ import annotations

import argparse
import importlib.metadata
from collections.abc import Iterator
from typing import Any

import pytest

import guardrail_core
from guardrail_core.cli import build_parser, main, package_version


def test_version_prints_the_installed_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out == f"guardrail {importlib.metadata.version('guardrail')}\n"


def test_version_outside_an_installation(monkeypatch: pytest.MonkeyPatch) -> None:
    def not_installed(name: str) -> str:
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "version", not_installed)
    assert package_version() == "unknown"
    monkeypatch.setattr(guardrail_core, "__version__", "9.8.7", raising=False)
    assert package_version() == "9.8.7"


def _commands(
    parser: argparse.ArgumentParser, name: str = "guardrail"
) -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """(name, parser) of the command and of every sub-command below it."""
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub, subparser in action.choices.items():
                yield from _commands(subparser, f"{name} {sub}")


def _has_default(action: argparse.Action) -> bool:
    """An option whose default says something: not None, not a flag's, not an empty list."""
    default = action.default
    if not action.option_strings or default is None or default is argparse.SUPPRESS:
        return False
    if isinstance(default, bool) or isinstance(action, argparse._VersionAction):
        return False
    return not (isinstance(default, (str, list, tuple)) and not default)


def _spellings(default: Any) -> set[str]:
    """How a help text may write the default: 5.0 as 5, 250000 as 250,000, (1024, 768) as
    1024x768."""
    if isinstance(default, float):
        return {str(default), f"{default:g}"}
    if isinstance(default, int):
        return {str(default), f"{default:,}"}
    if isinstance(default, tuple):
        return {str(default), "x".join(map(str, default))}
    return {str(default)}


def _flat(text: str) -> str:
    return " ".join(text.split())


def test_every_positional_has_help_and_every_default_is_shown_once() -> None:
    commands = dict(_commands(build_parser()))
    # The walk reaches the nested and the plugged-in commands.
    assert {"guardrail import kitti", "guardrail import lidar", "guardrail serve"} <= set(commands)
    checked = 0
    for name, parser in commands.items():
        page = _flat(parser.format_help())
        assert "default: None" not in page and "default: False" not in page, name
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                continue
            if not action.option_strings:
                assert action.help and action.help.strip(), f"{name}: {action.dest} has no help"
            if not _has_default(action):
                continue
            shown = _flat(parser._get_formatter()._expand_help(action))  # as --help prints it
            option = f"{name} {action.option_strings[0]}"
            assert shown in page, option
            assert shown.lower().count("default") == 1, f"{option}: {shown!r}"
            assert any(s in shown for s in _spellings(action.default)), f"{option}: {shown!r}"
            checked += 1
    assert checked >= 20  # every command's defaults, not a walk that found none


def test_serve_shows_its_point_budget_default(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["serve", "--help"])
    out = _flat(capsys.readouterr().out)
    assert "most points in the 3D scene (default: 400000)" in out
    assert "metres of drive in the 3D scene (default: 100)" in out
