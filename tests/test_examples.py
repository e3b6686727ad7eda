"""Every example the user is shown works: the README's commands and the ``--help`` texts' ones.

Each ``guardrail`` command of the README's shell blocks is parsed by the real parser and its
``--set`` settings by the parameters classes; those that run on a small drive (info, process,
evaluate, reconstruct, export) are run on the test drive, with the README's options.
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
from pathlib import Path

import pytest

from guardrail_core.cli import build_parser, main
from guardrail_core.cli.common import process_params
from guardrail_core.reconstruct.pipeline import ReconstructionParams

ROOT = Path(__file__).resolve().parents[1]
SETTING = re.compile(r"\b([a-z_]+\.[a-z_0-9]+=[^\s,;)]+)")


def readme_commands() -> list[str]:
    """The ``guardrail ...`` lines of the README's bash blocks, continuations joined."""
    text = (ROOT / "README.md").read_text()
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            line = line.removeprefix(".venv/bin/")
            if line.startswith("guardrail "):
                commands.append(line)
    return commands


def _subparsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    found = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                found += _subparsers(child)
    return found


def help_texts() -> list[str]:
    """Every description, epilog and option help of the command and its sub-commands."""
    texts = []
    for parser in _subparsers(build_parser()):
        texts += [parser.description or "", parser.epilog or ""]
        texts += [action.help or "" for action in parser._actions]
    return [t for t in texts if t]


def _settings(argv: list[str]) -> list[str]:
    return [argv[i + 1] for i, arg in enumerate(argv[:-1]) if arg == "--set"]


def test_the_readme_shows_commands():
    commands = readme_commands()
    assert len(commands) >= 20
    assert any("--set" in c for c in commands)


@pytest.mark.parametrize("command", readme_commands())
def test_every_readme_command_parses(command: str):
    argv = shlex.split(command)[1:]
    if "--help" in argv:
        with pytest.raises(SystemExit) as exited:
            build_parser().parse_args(argv)
        assert exited.value.code == 0
        return
    args = build_parser().parse_args(argv)  # argparse exits on an unknown command or option
    assert callable(args.func)
    if argv[0] == "process":  # extraction and reconstruction settings
        process_params(_settings(argv))
    else:
        ReconstructionParams().with_settings(_settings(argv))


def test_every_setting_in_the_help_texts_is_valid():
    settings = [s for text in help_texts() for s in SETTING.findall(text)]
    assert settings, "the --set help gives an example"
    for setting in settings:  # process takes both; the other commands' are reconstruction's
        process_params([setting])


def test_every_command_line_in_the_help_texts_parses():
    commands = {p.prog.split()[1] for p in _subparsers(build_parser())[1:]}
    lines = [
        line.strip().removeprefix("$ ")
        for text in help_texts()
        for line in text.splitlines()
        if line.strip().removeprefix("$ ").split()[:1] == ["guardrail"]
        and line.split("guardrail", 1)[1].split()[:1] in ([c] for c in commands)
    ]
    for line in lines:
        build_parser().parse_args(shlex.split(line)[1:])


def _runnable(command: str) -> bool:
    """The README's commands on drives/c, runs/c and models/fast: the test drive can play them."""
    words = shlex.split(command)
    folders = {"drives/c", "drives/mine", "runs/c", "runs/kitti_01", "models/fast"}
    return (
        words[1] in {"info", "process", "evaluate", "reconstruct", "export"}
        and "--units-sweep" not in words
        and words[2] in folders  # the units-sweep street's commands need that street
    )


@pytest.fixture
def workspace(tmp_path: Path, drive_path: Path, model_path: Path) -> Path:
    """The README's folders, made of the test drive, its model and its run."""
    for name, source in [("drives/c", drive_path), ("models/fast", model_path)]:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).symlink_to(source, target_is_directory=True)
    (tmp_path / "runs").mkdir()  # `guardrail process drives/c ... --out runs/c` comes first
    (tmp_path / "runs/kitti_01").symlink_to(tmp_path / "runs/c", target_is_directory=True)
    (tmp_path / "my_params.json").write_text(json.dumps({"poles": {"section_step_m": 0.04}}))
    return tmp_path


def test_the_readme_commands_run_on_a_small_drive(
    workspace: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
):
    monkeypatch.chdir(workspace)
    commands = [c for c in readme_commands() if _runnable(c)]
    commands = [c.replace("drives/mine", "drives/c") for c in commands]
    commands = [c for c in commands if "drives/kitti_01" not in c]  # needs the KITTI import
    # runs/kitti_01 stands for runs/c, which the README's `process` makes further down
    commands.sort(key=lambda c: "runs/kitti_01" in c)
    assert {shlex.split(c)[1] for c in commands} >= {"process", "evaluate", "reconstruct"}
    for command in commands:
        argv = shlex.split(command)[1:]
        if _accepts_quiet(argv[0]):
            argv.append("--quiet")
        assert main(argv) == 0, command
    assert "guardrail runs" in capsys.readouterr().out


def _accepts_quiet(command: str) -> bool:
    parser = next(p for p in _subparsers(build_parser()) if p.prog.endswith(f" {command}"))
    return any("--quiet" in action.option_strings for action in parser._actions)


def test_the_readme_python_blocks_run(drive_path: Path):
    """The README's Python blocks, on the test drive instead of the demo's."""
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)
    assert blocks
    for block in blocks:
        namespace: dict[str, object] = {}
        exec(block.replace("demo_output/sample_drive", str(drive_path)), namespace)  # noqa: S102
        assert "drive" in namespace
