"""The REST API reference, written from the review app's own OpenAPI schema.

The schema is FastAPI's ``app.openapi()`` of an app built around no session: building the
schema reads the routes and their models only, never the session, so the docs need no drive
folder and start no server (``tests/app/test_app_openapi.py`` reads it the same way).
"""

from __future__ import annotations

import json
from typing import Any

from guardrail_reference_markdown import code, first_paragraph, heading, join, prose, table

METHODS = ("get", "put", "post", "patch", "delete", "head", "options")


def openapi_schema() -> dict[str, Any]:
    """The review app's ``/openapi.json``, made in this process."""
    from app.main import create_app

    return create_app(session=None).openapi()  # type: ignore[arg-type]


def operations(spec: dict[str, Any]) -> list[tuple[str, str, dict[str, Any]]]:
    """Every (method, path, operation) of the schema, in the schema's order."""
    return [
        (method, path, operation)
        for path, item in spec["paths"].items()
        for method, operation in item.items()
        if method in METHODS
    ]


def schema_label(name: str) -> str:
    """The MyST target of a model's section."""
    return "rest-schema-" + name.lower()


def operation_label(operation: dict[str, Any]) -> str:
    """The MyST target of an operation's section."""
    return "rest-op-" + operation["operationId"].lower()


def schema_text(schema: dict[str, Any]) -> str:
    """A schema in a few words: a model's name (linked), ``list of X``, ``integer in [1, 1000]``,
    ``one of a, b``, ``X or null``."""
    if "$ref" in schema:
        name = schema["$ref"].rsplit("/", 1)[-1]
        return f"{{ref}}`{name} <{schema_label(name)}>`"
    for union in ("anyOf", "oneOf"):
        if union in schema:
            return " or ".join(schema_text(s) for s in schema[union])
    if "allOf" in schema and len(schema["allOf"]) == 1:
        return schema_text(schema["allOf"][0])
    if "enum" in schema:
        return "one of " + ", ".join(code(repr(v) if v is None else v) for v in schema["enum"])
    if "const" in schema:
        return code(schema["const"])
    kind = schema.get("type", "any")
    if kind == "array":
        text = "list of " + schema_text(schema.get("items", {}))
    elif kind == "object" and isinstance(schema.get("additionalProperties"), dict):
        text = "object of " + schema_text(schema["additionalProperties"])
    elif kind == "string" and schema.get("format") == "binary":
        text = "file"
    else:
        text = kind + (f" ({schema['format']})" if "format" in schema else "")
    low = "[" if "minimum" in schema else "(" if "exclusiveMinimum" in schema else None
    high = "]" if "maximum" in schema else ")" if "exclusiveMaximum" in schema else None
    if low or high:
        lo = _number(schema.get("minimum", schema.get("exclusiveMinimum", "-inf")))
        hi = _number(schema.get("maximum", schema.get("exclusiveMaximum", "inf")))
        text += " in " + code(f"{low or '('}{lo}, {hi}{high or ')'}")
    if "maxLength" in schema:
        text += f", at most {schema['maxLength']} characters"
    return text


def _number(value: Any) -> Any:
    """A bound as written: ``0`` and ``9007199254740992``, not ``0.0`` and ``9.0072e+15``."""
    return int(value) if isinstance(value, float) and value.is_integer() else value


def _default(schema: dict[str, Any]) -> str:
    return code(json.dumps(schema["default"])) if "default" in schema else ""


def _content(content: dict[str, Any]) -> str:
    """A request's or an answer's content: its schema, with the media type where not JSON."""
    parts = []
    for media, body in content.items():
        text = schema_text(body.get("schema", {}))
        parts.append(text if media == "application/json" else f"{text} ({code(media)})")
    return "; ".join(parts)


def first_sentence(operation: dict[str, Any]) -> str:
    """What an operation does in one sentence: the first of its route's docstring, else
    FastAPI's summary (made from the function's name, "Get Info")."""
    description = " ".join((operation.get("description") or "").split())
    if description:
        end = description.find(". ")
        return description if end < 0 else description[: end + 1]
    return operation.get("summary", "")


def operation_section(method: str, path: str, operation: dict[str, Any], level: int) -> str:
    """One operation: its description, parameters, request body and answers."""
    blocks = [heading(level, f"{method.upper()} `{path}`", label=operation_label(operation))]
    description = operation.get("description", "")
    blocks.append(prose(description) if description else prose(operation.get("summary", "")))
    parameters = operation.get("parameters", [])
    if parameters:
        rows = [
            [
                code(p["name"]),
                p["in"],
                schema_text(p.get("schema", {})),
                "yes" if p.get("required") else "no",
                _default(p.get("schema", {})),
                prose(p.get("description") or p.get("schema", {}).get("description")),
            ]
            for p in parameters
        ]
        blocks.append(table(["Parameter", "In", "Type", "Required", "Default", "Meaning"], rows))
    body = operation.get("requestBody")
    if body:
        required = "required" if body.get("required") else "optional"
        blocks.append(f"Request body ({required}): {_content(body.get('content', {}))}\n")
    rows = [
        [code(status), prose(answer.get("description")), _content(answer.get("content", {}))]
        for status, answer in sorted(operation.get("responses", {}).items())
    ]
    blocks.append(table(["Status", "Answer", "Schema"], rows))
    return join(blocks)


def model_section(name: str, schema: dict[str, Any], level: int) -> str:
    """One model of ``components/schemas``: its description and a row per field."""
    blocks = [heading(level, name, label=schema_label(name))]
    if schema.get("description"):
        blocks.append(first_paragraph(schema["description"]) + "\n")
    properties = schema.get("properties", {})
    required = set(schema.get("required", []))
    if properties:
        rows = [
            [
                code(field),
                schema_text(prop),
                "yes" if field in required else "no",
                _default(prop),
                prose(prop.get("description")),
            ]
            for field, prop in properties.items()
        ]
        blocks.append(table(["Field", "Type", "Required", "Default", "Meaning"], rows))
    elif "enum" in schema or "type" in schema:
        blocks.append(schema_text(schema) + "\n")
    if schema.get("additionalProperties") is False:
        blocks.append("No other fields are accepted or sent.\n")
    return join(blocks)


def rest_reference(spec: dict[str, Any] | None = None, level: int = 2) -> str:
    """The Markdown of every operation of the review app, by tag, then every model."""
    spec = openapi_schema() if spec is None else spec
    ops = operations(spec)
    blocks = [heading(level, "Operations")]
    overview = [
        [method.upper(), f"{{ref}}`{path} <{operation_label(op)}>`", prose(first_sentence(op))]
        for method, path, op in ops
    ]
    blocks.append(table(["Method", "Path", "What it does"], overview))
    tags: dict[str, list[tuple[str, str, dict[str, Any]]]] = {}
    for method, path, op in ops:
        tags.setdefault((op.get("tags") or ["other"])[0], []).append((method, path, op))
    for tag, tagged in tags.items():
        blocks.append(heading(level + 1, tag.capitalize()))
        blocks.extend(operation_section(m, p, op, level + 2) for m, p, op in tagged)
    models = spec.get("components", {}).get("schemas", {})
    if models:
        blocks.append(heading(level, "Models"))
        blocks.append("The request and answer bodies named above, with their fields.\n")
        blocks.extend(model_section(name, schema, level + 1) for name, schema in models.items())
    return join(blocks)
