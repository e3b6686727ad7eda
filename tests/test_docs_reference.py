"""The reference pages of the docs are written from the code and say all of it.

The generators of ``docs/_ext`` are called directly (no Sphinx) and their Markdown checked
against the code read here independently: every command and option of the real parser, every
field of every ``StageParams`` subclass with its default, unit and range, every operation and
model of the review app's ``/openapi.json``. One test builds the whole site as ``make docs``
does, warnings as errors.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import pkgutil
import re
import subprocess
import sys
import textwrap
import typing
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

import guardrail_core
from app.main import create_app
from guardrail_core.cli import build_parser
from guardrail_core.extract.pipeline import ExtractionParams
from guardrail_core.params import StageParams
from guardrail_core.reconstruct.pipeline import ReconstructionParams

ROOT = Path(__file__).resolve().parents[1]
EXT = ROOT / "docs" / "_ext"
if str(EXT) not in sys.path:  # the extension's modules, as docs/conf.py finds them
    sys.path.insert(0, str(EXT))
reference = importlib.import_module("guardrail_reference")
reference_cli = importlib.import_module("guardrail_reference_cli")
reference_params = importlib.import_module("guardrail_reference_params")
reference_rest = importlib.import_module("guardrail_reference_rest")


def _section(text: str, start: str, next_start: str) -> str:
    """The part of ``text`` from the line ``start`` to the next line starting ``next_start``."""
    begin = text.index(start)
    following = re.compile("^" + re.escape(next_start), re.M).search(text, begin + len(start))
    return text[begin : following.start() if following else len(text)]


def _row(section: str, first_cell: str) -> list[str]:
    """The cells of the table row whose first cell is ``first_cell``."""
    for line in section.splitlines():
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        if cells and cells[0] == first_cell:
            return cells
    raise AssertionError(f"no row {first_cell} in:\n{section[:400]}")


# ----------------------------------------------------------------------------- the CLI


def _parsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    found = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):
                found += _parsers(child)
    return found


@pytest.fixture(scope="module")
def cli_text() -> str:
    return str(reference_cli.cli_reference())


def _command(text: str, prog: str) -> str:
    label = f"(cli-{prog.replace(' ', '-')})="
    return _section(text, label, "(cli-")


def test_the_cli_reference_has_every_command_and_sub_command(cli_text: str) -> None:
    progs = [p.prog for p in _parsers(build_parser())]
    assert {"guardrail serve", "guardrail import las", "guardrail import lidar"} <= set(progs)
    for prog in progs:
        assert re.search(rf"^#{{2,}} {re.escape(prog)}$", cli_text, re.M), prog
    headings = re.findall(r"^#{2,} (guardrail\b.*)$", cli_text, re.M)
    assert headings == progs  # each once, in --help order


def test_every_argument_is_stated_with_its_default(cli_text: str) -> None:
    for parser in _parsers(build_parser()):
        section = _command(cli_text, parser.prog)
        if parser.description:
            assert " ".join(parser.description.split()[:3]) in section.replace("\\_", "_")
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction | argparse._HelpAction):
                continue
            written = action.option_strings or [action.metavar or action.dest]
            for name in written:  # in a code span: `--tile-m METRES`, `[DRIVE ...]`
                assert re.search(rf"`[^`|]*{re.escape(name)}\b", section), (parser.prog, name)
            default = action.default
            if action.option_strings and action.nargs != 0 and default not in (None, [], ""):
                shown = f"{default:g}" if isinstance(default, float) else str(default)
                row = _row(section, reference_cli._argument(parser, action))
                assert row[1] == f"`{shown}`", (parser.prog, action.option_strings, row)


def test_an_epilog_keeps_its_example_lines() -> None:
    parser = argparse.ArgumentParser(
        prog="guardrail x",
        description="Do x with --fast.",
        epilog="examples:\n  guardrail x drives/c --out runs/c\n  guardrail x a --set b.c=1\n",
    )
    parser.add_argument("--fast", action="store_true", help="quickly, see --out")
    text = reference_cli.cli_reference(parser)
    assert "```text\nexamples:\n  guardrail x drives/c --out runs/c\n  guardrail x a --set" in text
    assert "Do x with `--fast`." in text  # not an en dash of smart quotes


def test_the_commands_epilogs_are_kept_line_for_line(cli_text: str) -> None:
    for parser in _parsers(build_parser()):
        epilog = textwrap.dedent(parser.epilog or "").strip("\n")
        if "\n" in epilog:
            assert f"```text\n{epilog}\n```" in _command(cli_text, parser.prog), parser.prog


# ----------------------------------------------------------------------------- parameters


def _subclasses(cls: type) -> set[type]:
    found = set()
    for sub in cls.__subclasses__():
        found |= {sub} | _subclasses(sub)
    return found


@pytest.fixture(scope="module")
def every_stage_class() -> set[type]:
    """Every StageParams subclass once every module of guardrail_core is imported."""
    for module in pkgutil.walk_packages(guardrail_core.__path__, "guardrail_core."):
        if not module.name.endswith(".__main__"):
            importlib.import_module(module.name)
    return _subclasses(StageParams)


@pytest.fixture(scope="module")
def params_text() -> str:
    return str(reference_params.parameters_reference())


def _expected_value(value: Any) -> str:
    if hasattr(value, "tolist"):
        value = value.tolist()
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return repr(value + 0.0)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_expected_value(v) for v in value) + "]"
    if isinstance(value, str):
        return value or '""'
    return str(value)


def test_every_stage_class_is_found(every_stage_class: set[type], params_text: str) -> None:
    assert len(every_stage_class) >= 22
    assert set(reference_params.stage_classes()) == every_stage_class
    labels = re.findall(r"^\(param-(\w+)\)=$", params_text, re.M)
    assert sorted(labels) == sorted(c.__name__.lower() for c in every_stage_class)


def test_every_field_has_its_default_unit_and_range(
    every_stage_class: set[type], params_text: str
) -> None:
    for cls in every_stage_class:
        section = _section(params_text, f"(param-{cls.__name__.lower()})=", "(param-")
        hints = typing.get_type_hints(cls)
        specs = {s.name: s for s in cls.specs()}
        for field in dataclasses.fields(cls):
            row = _row(section, f"`{field.name}`")
            value = field.default
            if value is dataclasses.MISSING:
                value = field.default_factory()  # type: ignore[misc]
            if field.name in specs:
                spec = specs[field.name]
                assert row[1] == f"`{_expected_value(value)}`", (cls, row)
                assert row[2] == (f"`{spec.unit}`" if spec.unit else "—"), (cls, row)
                if hints[field.name] is not bool and hints[field.name] is not str:
                    assert spec.range_text() in row[3], (cls, row)
                assert (spec.doc == "") == (row[4] == "—"), (cls, row)
            elif isinstance(value, StageParams):  # a section
                assert row[1] == f"`{type(value).__name__}()`", (cls, row)
            else:  # a value without a range (a scanner's mounting matrix)
                assert row[1] == f"`{_expected_value(value)}`", (cls, row)


def test_the_sections_of_set_are_those_the_cli_takes(params_text: str) -> None:
    # The sections `process_params` sends each setting to (guardrail_core/cli/common.py).
    extraction = typing.get_type_hints(ExtractionParams)
    sections = {f.name: extraction[f.name] for f in dataclasses.fields(ExtractionParams)}
    sections.update(ReconstructionParams.stage_classes())
    for name, cls in sections.items():
        assert f"### `{name}`: {cls.__name__}\n" in params_text, name
    for simulator in ("ScannerParams", "RenderParams", "VehicleParams", "ReturnModel"):
        assert re.search(rf"^### {simulator}$", params_text, re.M), simulator


# ----------------------------------------------------------------------------- REST API


@pytest.fixture(scope="module")
def served_schema() -> dict[str, Any]:
    """The schema the app serves at /openapi.json (it never touches the session)."""
    with TestClient(create_app(typing.cast(Any, None))) as client:
        response = client.get("/openapi.json")
    assert response.status_code == 200
    return typing.cast(dict[str, Any], response.json())


def test_the_rest_reference_has_every_operation(served_schema: dict[str, Any]) -> None:
    text = reference_rest.rest_reference()
    assert reference_rest.openapi_schema() == served_schema
    operations = [
        (method, path, op)
        for path, item in served_schema["paths"].items()
        for method, op in item.items()
    ]
    assert len(operations) >= 20
    for method, path, op in operations:
        label = f"(rest-op-{op['operationId'].lower()})="
        section = _section(text, label, "(rest-")
        assert f"#### {method.upper()} `{path}`\n" in section
        assert f"| {method.upper()} | {{ref}}`{path} <" in text
        for parameter in op.get("parameters", []):
            assert _row(section, f"`{parameter['name']}`")[1] == parameter["in"]
        for content in [op.get("requestBody", {}).get("content", {})] + [
            answer.get("content", {}) for answer in op["responses"].values()
        ]:
            for media in content.values():
                ref = media.get("schema", {}).get("$ref", "")
                assert ref.rsplit("/", 1)[-1] in section, (path, ref)
        for status in op["responses"]:
            assert f"| `{status}` |" in section, (path, status)
    for name, schema in served_schema["components"]["schemas"].items():
        section = _section(text, f"(rest-schema-{name.lower()})=", "(rest-")
        for field in schema.get("properties", {}):
            _row(section, f"`{field}`")


def test_every_operation_says_what_it_does_in_its_own_words(served_schema: dict[str, Any]) -> None:
    """The reference's overview gives each route's docstring, not FastAPI's name-made summary
    ("Get Job"), so every route has one."""
    undocumented = [
        f"{method.upper()} {path}"
        for path, item in served_schema["paths"].items()
        for method, op in item.items()
        if not (op.get("description") or "").strip()
    ]
    assert undocumented == []


# ----------------------------------------------------------------------------- the build


def test_an_unknown_marker_fails_and_a_known_one_is_replaced() -> None:
    text = "# T\n\n<!-- generated: parameters -->\n"
    assert reference.expand(text, {"parameters": lambda: "table\n"}) == "# T\n\ntable\n"
    with pytest.raises(Exception, match="unknown generated section 'nope'"):
        reference.expand("<!-- generated: nope -->", {})


def test_the_site_builds_without_a_warning(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "-q", "-b", "html", "docs", str(tmp_path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-4000:]
    parameters = tmp_path / "reference" / "parameters.html"
    assert parameters.is_file()
    assert "slice_interval_m" in parameters.read_text()
    cli = (tmp_path / "reference" / "cli.html").read_text()
    assert "guardrail import las" in cli and "guardrail serve" in cli
    assert "\u2013seed" not in cli  # --seed, not an en dash
