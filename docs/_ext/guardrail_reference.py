"""Sphinx extension: the reference pages, generated from the code so that they cannot drift.

A page holds its title and a hand-written introduction, and a marker line where the generated
part goes::

    <!-- generated: parameters -->

On ``source-read`` the marker is replaced by MyST Markdown written from the code:

* ``cli``: every command of the real ``guardrail`` parser (:mod:`guardrail_reference_cli`),
* ``parameters``: every ``StageParams`` class of ``guardrail_core``
  (:mod:`guardrail_reference_params`),
* ``rest-api``: every operation and model of the review app's OpenAPI schema
  (:mod:`guardrail_reference_rest`).

A marker of another name fails the build. The pages are read again on every build: Sphinx
sees only their text, which does not change when the code does.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sphinx.application import Sphinx
from sphinx.environment import BuildEnvironment
from sphinx.errors import ExtensionError

MARKER = re.compile(r"^<!--\s*generated:\s*([\w-]+)\s*-->[ \t]*$", re.M)


def _cli() -> str:
    from guardrail_reference_cli import cli_reference

    return cli_reference()


def _parameters() -> str:
    from guardrail_reference_params import parameters_reference

    return parameters_reference()


def _rest() -> str:
    from guardrail_reference_rest import rest_reference

    return rest_reference()


#: Marker name -> the function writing its Markdown (imported on use: the REST one loads the app).
GENERATORS: dict[str, Callable[[], str]] = {
    "cli": _cli,
    "parameters": _parameters,
    "rest-api": _rest,
}


def expand(text: str, generators: dict[str, Callable[[], str]] = GENERATORS) -> str:
    """``text`` with every marker replaced by its generator's Markdown.

    Raises
    ------
    ExtensionError
        A marker names no generator.
    """

    def replace(match: re.Match[str]) -> str:
        name = match.group(1)
        if name not in generators:
            raise ExtensionError(
                f"unknown generated section {name!r} (known: {', '.join(generators)})"
            )
        return generators[name]().rstrip("\n")

    return MARKER.sub(replace, text)


def on_source_read(app: Sphinx, docname: str, source: list[str]) -> None:
    if MARKER.search(source[0]):
        source[0] = expand(source[0])


def on_env_get_outdated(
    app: Sphinx, env: BuildEnvironment, added: set[str], changed: set[str], removed: set[str]
) -> list[str]:
    """The pages with a marker: always read again, their text is the code's."""
    outdated = []
    for docname in env.found_docs:
        path = Path(env.doc2path(docname))
        if path.is_file() and MARKER.search(path.read_text(encoding="utf-8")):
            outdated.append(docname)
    return outdated


def setup(app: Sphinx) -> dict[str, Any]:
    app.connect("source-read", on_source_read)
    app.connect("env-get-outdated", on_env_get_outdated)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
