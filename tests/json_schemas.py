"""The official JSON schemas vendored in ``tests/data/schemas`` (sources and licences in its
README), as validators: the exports' files are checked against the standards' own schemas."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

import jsonschema
from referencing import Registry, Resource

SCHEMAS = Path(__file__).parent / "data" / "schemas"


@cache
def _validator(root: Path) -> Any:
    """A validator of the schema file ``root``, its ``$ref``s resolved among the files of its
    folder by their paths (the 3D Tiles schemas' ``$id``s are bare file names, their references
    paths relative to the referring file: each file's ``$id`` becomes its own file URI)."""
    resources = []
    for path in sorted(root.parent.rglob("*.json")):
        contents = json.loads(path.read_text())
        contents["$id"] = path.resolve().as_uri()
        resources.append((contents["$id"], Resource.from_contents(contents)))
    registry: Registry = Registry().with_resources(resources)
    schema = registry.contents(root.resolve().as_uri())
    return jsonschema.validators.validator_for(schema)(schema, registry=registry)


def schema_errors(document: Any, schema: str) -> list[str]:
    """Where and why ``document`` breaks the schema ``schema`` (a path below
    ``tests/data/schemas``, e.g. ``"3d-tiles-1.1/tileset.schema.json"``); [] when it is valid."""
    validator = _validator(SCHEMAS / schema)
    return [
        f"{'/'.join(str(p) for p in error.absolute_path)}: {error.message[:300]}"
        for error in validator.iter_errors(document)
    ]
