"""Every example the user is shown works: the commands of the README and of the documentation
pages, and the ``--help`` texts' ones.

Each ``guardrail`` command of their shell blocks is parsed by the real parser and its ``--set``
settings by the parameters classes; those that run on a small drive (info, process, evaluate,
reconstruct, export) are run on the test drive, with the documents' options. Every
``STAGE.NAME`` setting the pages name in backticks is a parameter of that stage.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import shlex
from pathlib import Path

import pytest

from guardrail_core.cli import build_parser, main
from guardrail_core.cli.common import process_params
from guardrail_core.extract.pipeline import ExtractionParams
from guardrail_core.reconstruct.pipeline import ReconstructionParams

ROOT = Path(__file__).resolve().parents[1]
SETTING = re.compile(r"\b([a-z_]+\.[a-z_0-9]+=[^\s,;)]+)")


def documents() -> list[Path]:
    """The README and the documentation site's Markdown pages (not the built site)."""
    pages = sorted(p for p in (ROOT / "docs").rglob("*.md") if "_build" not in p.parts)
    return [ROOT / "README.md", *pages]


def document_commands() -> list[str]:
    """The ``guardrail ...`` lines of the documents' bash blocks, continuations joined, each once
    in the order the documents give them."""
    commands: list[str] = []
    for document in documents():
        for block in re.findall(r"```(?:bash|sh)\n(.*?)```", document.read_text(), flags=re.S):
            for line in block.replace("\\\n", " ").splitlines():
                line = re.sub(r"\s+#.*$", "", line).strip()
                line = line.removeprefix(".venv/bin/")
                if line.startswith("guardrail ") and line not in commands:
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


def test_the_documents_show_commands():
    commands = document_commands()
    assert len(commands) >= 40
    assert any("--set" in c for c in commands)
    readme = (ROOT / "README.md").read_text().replace("\\\n    ", "")
    assert sum(command in readme for command in commands) >= 8  # the README's tour


FILE_SUFFIXES = {"csv", "npz", "npy", "json", "geojson", "laz", "las", "glb", "ply", "obj"}


def _settable() -> set[str]:
    """Every ``STAGE.NAME`` of ``guardrail process --set`` and ``guardrail reconstruct --set``."""
    extraction = ExtractionParams()
    names = {
        f"{stage.name}.{f.name}"
        for stage in dataclasses.fields(extraction)
        for f in dataclasses.fields(getattr(extraction, stage.name))
    }
    for stage, cls in ReconstructionParams.stage_classes().items():
        names |= {f"{stage}.{f.name}" for f in dataclasses.fields(cls)}
    return names


def test_every_parameter_the_documents_name_exists():
    settable = _settable()
    stages = {name.split(".")[0] for name in settable}
    named = {
        (document.name, match.group(1))
        for document in documents()
        for match in re.finditer(r"`([a-z_]+\.[a-z_0-9]+)(?:=[^`]*)?`", document.read_text())
        if match.group(1).split(".")[0] in stages
        and match.group(1).split(".")[1] not in FILE_SUFFIXES  # `segments.csv` is a file
    }
    assert len(named) >= 10
    assert {(doc, name) for doc, name in named if name not in settable} == set()


@pytest.mark.parametrize("command", document_commands())
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


#: The documents' commands the tests parse but do not run here, each with why and where the same
#: code runs instead: they need data the tests cannot make in reasonable time, or run until
#: stopped. Every other command runs on the test drive.
NOT_RUN: dict[str, str] = {
    r"^guardrail --help$": "prints the help; test_every_document_command_parses runs it",
    r"^guardrail simulate ": "simulates 40 m to 3 km with cameras, a minute or more each; "
    "tests/synth/test_simulate*.py and tests/cli/test_cli.py run `guardrail simulate` on short streets",
    r"^guardrail serve ": "serves until stopped; tests/app/test_app_serve_*.py and "
    "tests/browser/ start `guardrail serve` and use it",
    r"^guardrail train ": "trains on 150 m streets; tests/cli/test_cli_extract.py runs `guardrail "
    "train` on the test drive and tests/app/test_app_jobs.py fine-tunes from operators' labels",
    r"kitti|\$S/": "needs the KITTI scans of ../shared/realdata; tests/test_kitti_end_to_end.py "
    "imports and processes frame 280 where they are",
    r"cloud_00|route_12|frame_000123|drives/pandar\b": "the user's own delivery or frame, named "
    "for the example; tests/importers/test_import_las.py and tests/importers/test_import_lidar.py import such files",
    r"lidar_frames/|drives/pandar64|drives/os1": "frames docs/examples/lidar_frames.py makes from "
    "simulated drives; tests/importers/test_import_lidar.py imports and processes the same frames",
    r"import las sim/|info imported": "a 40 m street simulated first; tests/importers/test_import_las.py "
    "imports a simulated drive's points the same way",
    r"drives/survey|/shared/": "a 3 km survey or a Dask cluster; tests/process/test_process_tiles.py "
    "processes the test drive in tiles on Dask",
}


def _not_run_reasons(command: str) -> list[str]:
    return [reason for pattern, reason in NOT_RUN.items() if re.search(pattern, command)]


def test_every_document_command_runs_or_says_why_not():
    commands = document_commands()
    unexplained = [c for c in commands if not _runnable(c) and not _not_run_reasons(c)]
    assert unexplained == []
    # Each reason still stands for a command, and no command both runs and is excused.
    assert all(any(re.search(p, c) for c in commands) for p in NOT_RUN), "a stale reason"
    assert [c for c in commands if _runnable(c) and _not_run_reasons(c)] == []


def _runnable(command: str) -> bool:
    """The documents' commands on the folders the workspace makes of the test drive."""
    words = shlex.split(command)
    folders = {
        "drives/c",
        "drives/mine",
        "runs/c",
        "runs/mine",
        "runs/kitti_01",
        "models/fast",
        "demo_output/sample_drive",
        "demo_output/run",
    }
    return (
        words[1] in {"info", "process", "evaluate", "reconstruct", "export"}
        and "--units-sweep" not in words
        and words[2] in folders  # the units-sweep street's commands need that street
    )


@pytest.fixture
def workspace(tmp_path: Path, drive_path: Path, model_path: Path) -> Path:
    """The documents' folders, made of the test drive, its model and its run (the fine-tuned
    model of the tutorial stands for the model it was tuned from)."""
    for name, source in [
        ("drives/c", drive_path),
        ("models/fast", model_path),
        ("models/tuned", model_path),
        ("demo_output/sample_drive", drive_path),
        ("demo_output/model", model_path),
    ]:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).symlink_to(source, target_is_directory=True)
    (tmp_path / "runs").mkdir()  # `guardrail process drives/c ... --out runs/c` comes first
    (tmp_path / "runs/kitti_01").symlink_to(tmp_path / "runs/c", target_is_directory=True)
    (tmp_path / "demo_output/run").symlink_to(tmp_path / "runs/c", target_is_directory=True)
    (tmp_path / "my_params.json").write_text(json.dumps({"poles": {"section_step_m": 0.04}}))
    return tmp_path


def test_the_document_commands_run_on_a_small_drive(
    workspace: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
):
    monkeypatch.chdir(workspace)
    commands = [c for c in document_commands() if _runnable(c)]
    commands = [c.replace("drives/mine", "drives/c") for c in commands]
    commands = [c for c in commands if "drives/kitti_01" not in c]  # needs the KITTI import
    # The pages' `process` commands make the runs the others read, whichever page comes first;
    # runs/kitti_01 stands for runs/c.
    commands.sort(key=lambda c: (shlex.split(c)[1] != "process", "runs/kitti_01" in c))
    assert {shlex.split(c)[1] for c in commands} >= {"process", "evaluate", "reconstruct"}
    for command in commands:
        argv = shlex.split(command)[1:]
        if _accepts_quiet(argv[0]):
            argv.append("--quiet")
        if argv[0] == "process" and "--overwrite" not in argv:
            argv.append("--overwrite")  # the pages' runs/c, whichever page makes it first
        assert main(argv) == 0, command
    assert "guardrail runs" in capsys.readouterr().out


def _accepts_quiet(command: str) -> bool:
    parser = next(p for p in _subparsers(build_parser()) if p.prog.endswith(f" {command}"))
    return any("--quiet" in action.option_strings for action in parser._actions)


def test_the_document_python_blocks_run(drive_path: Path):
    """The documents' Python blocks that read the demo's drive, on the test drive instead."""
    blocks = [
        block
        for document in documents()
        for block in re.findall(r"```python\n(.*?)```", document.read_text(), flags=re.S)
        if "demo_output/sample_drive" in block
    ]
    assert blocks
    for block in blocks:
        namespace: dict[str, object] = {}
        exec(block.replace("demo_output/sample_drive", str(drive_path)), namespace)  # noqa: S102
        assert "drive" in namespace
