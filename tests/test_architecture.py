"""Which packages may import which: the layers of docs/architecture.md, checked on the source.

Every ``import`` of the project's own code, at module level or inside a function, is read from
the syntax tree; a package may import only itself and the layers its rule names. The review app
sits on top and may import the library; the library never imports the app or its web stack.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ROOT / "guardrail_core"

BASE = {"classes", "errors", "params", "progress", "timing"}
DATA = BASE | {"geom", "sensors", "io", "formats"}
#: package (or root module) of guardrail_core -> what it may import besides itself
ALLOWED: dict[str, set[str]] = {
    "classes": set(),
    "errors": set(),
    "timing": set(),
    "progress": set(),
    "params": {"errors"},
    "geom": BASE,
    "sensors": BASE | {"geom"},
    "io": BASE | {"geom"},
    "formats": BASE | {"geom", "sensors", "io"},
    "synth": DATA,
    "importers": DATA,
    "extract": DATA,
    "reconstruct": DATA,
    "distributed": BASE,
    "process": DATA | {"extract", "reconstruct", "distributed"},
    "evaluate": DATA | {"extract", "reconstruct"},
    "review": DATA | {"extract"},
    "export": DATA | {"reconstruct"},
    "cli": DATA
    | {"synth", "importers", "extract", "reconstruct", "process", "evaluate", "review", "export"}
    | {"distributed"},
}
#: third-party packages only the review app may use
APP_ONLY = {"app", "fastapi", "viser", "uvicorn", "starlette"}


def _layer(module: str) -> str | None:
    """The layer of a ``guardrail_core.*`` module name, None for other packages."""
    parts = module.split(".")
    if parts[0] != "guardrail_core":
        return None
    return parts[1] if len(parts) > 1 else "guardrail_core"


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import in a file, absolute names."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module == "guardrail_core":  # from guardrail_core import drive
                found += [(node.lineno, f"guardrail_core.{a.name}") for a in node.names]
            else:
                found.append((node.lineno, node.module))
    return found


def _library_files() -> list[Path]:
    return sorted(LIBRARY.rglob("*.py"))


def _own_layer(path: Path) -> str:
    relative = path.relative_to(LIBRARY)
    return relative.parts[0] if len(relative.parts) > 1 else relative.stem


def test_every_package_has_a_rule():
    layers = {_own_layer(p) for p in _library_files()} - {"__init__"}
    assert layers - set(ALLOWED) == set(), "a new package needs its rule in ALLOWED"


@pytest.mark.parametrize("path", _library_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_library_imports_follow_the_layers(path: Path):
    own = _own_layer(path)
    allowed = ALLOWED.get(own, set()) | {own}
    wrong = []
    for line, module in _imports(path):
        top = module.split(".")[0]
        if top in APP_ONLY:
            wrong.append(f"{path.name}:{line} imports {module} (the library never imports the app)")
        layer = _layer(module)
        if layer is not None and layer not in allowed and own != "__init__":
            wrong.append(
                f"{path.name}:{line} imports {module} ({own} may import {sorted(allowed)})"
            )
    assert wrong == []


def test_the_rules_catch_an_upward_import(tmp_path: Path):
    """The check itself: a formats module importing extract breaks the rule."""
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from guardrail_core.extract.crops import CROP_OK\n")
    layers = {_layer(module) for _, module in _imports(bad)}
    assert layers == {"extract"} and "extract" not in ALLOWED["formats"]


#: The most lines a module of the library or the app may have: one idea per file.
MAX_MODULE_LINES = 600


def test_no_module_is_over_600_lines():
    sizes = {
        path.relative_to(ROOT).as_posix(): len(path.read_text().splitlines())
        for folder in (LIBRARY, ROOT / "app")
        for path in folder.rglob("*.py")
    }
    over = {name: n for name, n in sizes.items() if n > MAX_MODULE_LINES}
    assert not over, f"modules over {MAX_MODULE_LINES} lines (split them): {over}"
