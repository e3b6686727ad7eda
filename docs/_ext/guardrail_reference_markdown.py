"""Helpers shared by the reference generators: MyST Markdown text, code spans and tables.

Help texts, docstrings and schema descriptions are written for a terminal or for reST, not for
Markdown: a ``*`` or ``<`` in them would start emphasis or HTML, a ``|`` would split a table
cell, and Sphinx's smart quotes turn the ``--`` of an option into an en dash. ``prose`` makes
such text safe and keeps the code spans it already has.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence

#: A code span (any run of backticks up to the same run), a reST role (``:class:`~a.B```), or
#: anything else up to the next backtick or colon.
_CODE = re.compile(r"(?P<ticks>`+)(?P<code>.+?)(?P=ticks)|:[a-z]+:`(?P<role>[^`]+)`", re.S)
#: Options (``--tile-m``, ``--set=a.b=1``) and ``$VARIABLES`` in prose: shown as code, out of smart quotes' way.
_OPTION = re.compile(r"(?<![\w`-])(--[a-z][\w-]*(?:=[^\s);]+)?|\$[A-Z][A-Z0-9_]+)")
#: Characters that mean something to Markdown (or MyST) outside a code span.
_SPECIAL = re.compile(r"([\\`*_\[\]<>|#~])")


def code(text: str) -> str:
    """``text`` as one inline code span."""
    text = str(text).replace("\n", " ")
    ticks = "`" * (max((len(run) for run in re.findall(r"`+", text)), default=0) + 1)
    pad = " " if text.startswith("`") or text.endswith("`") else ""
    return f"{ticks}{pad}{text}{pad}{ticks}"


def _plain(text: str) -> str:
    """Text outside code spans: special characters escaped, options as code."""
    parts = []
    last = 0
    for match in _OPTION.finditer(text):
        parts.append(_SPECIAL.sub(r"\\\1", text[last : match.start()]))
        parts.append(code(match.group(0)))
        last = match.end()
    parts.append(_SPECIAL.sub(r"\\\1", text[last:]))
    return "".join(parts)


def prose(text: str | None) -> str:
    """Help or docstring text as one Markdown line: whitespace joined (argparse and the reST of
    docstrings reflow it anyway), Markdown's special characters escaped outside code spans,
    reST roles and double-backtick literals turned into code spans."""
    text = " ".join((text or "").split())
    parts = []
    last = 0
    for match in _CODE.finditer(text):
        parts.append(_plain(text[last : match.start()]))
        if match.group("role") is not None:
            target = match.group("role").lstrip("~!")
            # `:class:`~a.b.C`` shows C; any other role its whole target.
            shown = target.rsplit(".", 1)[-1] if match.group("role").startswith("~") else target
            parts.append(code(shown))
        else:
            parts.append(code(match.group("code").strip()))
        last = match.end()
    parts.append(_plain(text[last:]))
    return "".join(parts)


def first_paragraph(doc: str | None) -> str:
    """The first paragraph of a docstring (``inspect.getdoc`` output), as prose."""
    return prose((doc or "").strip().split("\n\n", 1)[0])


def heading(level: int, text: str, label: str | None = None) -> str:
    """A Markdown heading, after a MyST target ``(label)=`` when one is given."""
    target = f"({label})=\n" if label else ""
    return f"{target}{'#' * level} {text}\n"


def table(header: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A Markdown table; cells are Markdown already (see :func:`cell`)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def cell(text: str) -> str:
    """Markdown as a table cell: on one line, its pipes escaped (in code spans too: the table
    rule takes ``\\|`` for ``|`` before it reads the spans), an empty cell shown as a dash."""
    return re.sub(r"(?<!\\)\|", r"\\|", " ".join(text.split())) or "—"


def fenced(text: str, language: str = "text") -> str:
    """A fenced code block, its fence longer than any backtick run in ``text``."""
    fence = "`" * max(3, max((len(r) for r in re.findall(r"`+", text)), default=0) + 1)
    return f"{fence}{language}\n{text.rstrip()}\n{fence}\n"


def join(blocks: Iterable[str]) -> str:
    """Markdown blocks separated by one blank line."""
    return "\n".join(b.rstrip("\n") + "\n" for b in blocks if b.strip())
