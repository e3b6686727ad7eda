"""Sphinx configuration of the documentation site: ``make docs`` builds it into ``docs/_build``.

Pages are Markdown (MyST). The reference pages are generated from the code by the extension in
``docs/_ext`` so that they cannot drift from it. Warnings are errors (``make docs`` passes ``-W``).
"""

from __future__ import annotations

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS / "_ext"))

project = "guardrail"
author = "the guardrail authors"
copyright = "2026, the guardrail authors"  # noqa: A001 (Sphinx's own name)

extensions = ["myst_parser", "sphinxarg.ext", "guardrail_reference"]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "_ext", "examples", "Thumbs.db", ".DS_Store"]
myst_heading_anchors = 4
myst_enable_extensions = ["colon_fence", "deflist"]

html_theme = "furo"
html_title = "guardrail"
html_static_path: list[str] = []

# Examples of JSON and YAML shorten with "..." on purpose; they are drawn without colour.
suppress_warnings = ["misc.highlighting_failure"]
