"""The review app's ``/openapi.json`` describes every answer the pages rely on.

Every route declares a 2xx answer with a real schema (a named model, or the media type of the
file it sends), and the models name the fields ``static/js`` reads. That the routes' answers fit
their models is checked by the app's other tests: FastAPI validates every answer, and the models
forbid fields they do not name.
"""

from __future__ import annotations

from typing import Any, cast

import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.routers.reconstruction import MEDIA_TYPES
from app.session import ReviewSession
from guardrail_core.reconstruct.pipeline import ReconstructionParams

#: Routes that send a file, and its media types.
FILE_ROUTES = {
    ("get", "/api/segments/{segment_id}/crop.jpg"): {"image/jpeg"},
    ("get", "/api/images/{image_id}/overlay"): {"image/png"},
    ("get", "/api/downloads/{name}"): set(MEDIA_TYPES.values()),
}

#: (method, path) -> fields static/js reads in the answer; ``[]`` steps into a list's items.
FIELDS_THE_PAGES_READ: dict[tuple[str, str], list[str]] = {
    ("get", "/api/info"): [
        "drive",
        "run",
        "operator",
        "scene_url",
        "n_segments",
        "n_points",
        "label_counts",
        "model.version",
        "model.mode",
        "model.metrics.held_out.guardrail.f1",
        "model.metrics.held_out.other.f1",
        "model.metrics.held_out.n_held_out",
        "model.metrics.held_out.n_reviewed_held_out",
        "model.metrics.held_out.against",
    ],
    ("get", "/api/segments"): [
        "total",
        "items[].id",
        "items[].crop_url",
        "items[].crop_status",
        "items[].label",
        "items[].model_label",
        "items[].reviewed",
        "items[].probability",
        "items[].n_points",
    ],
    ("get", "/api/segments/{segment_id}"): [
        "id",
        "image_id",
        "crop_url",
        "crop_status",
        "label",
        "raw_label",
        "model_label",
        "truth",
        "reviewed",
        "probability",
        "n_points",
        "slice_index",
        "component",
        "history[].at",
        "history[].who",
        "history[].old",
        "history[].new",
        "history[].kind",
        "history[].n_points",
        "history[].model_version",
        "history[].batch",
        "history[].undone",
    ],
    ("get", "/api/queue"): [
        "items[].id",
        "items[].crop_url",
        "items[].label",
        "items[].probability",
        "items[].reason",
        "asked",
        "reviewed",
        "done",
    ],
    ("get", "/api/selection"): ["segments", "lasso_points"],
    ("post", "/api/labels/lasso"): ["changed_points"],
    ("get", "/api/images/{image_id}/pick"): ["segment"],
    ("put", "/api/selection"): ["segments", "lasso_points"],
    ("put", "/api/segments/{segment_id}/label"): ["segments[].id", "changed_points"],
    ("post", "/api/labels/batch"): ["segments[].id", "segments[].label", "changed_points"],
    ("post", "/api/labels/undo"): ["undone_batch", "segments[].reviewed", "changed_points"],
    ("post", "/api/train"): ["job"],
    ("get", "/api/jobs"): ["items[].id", "items[].status"],
    ("get", "/api/jobs/{job_id}"): [
        "status",
        "progress",
        "message",
        "error",
        "result.version",
        "result.metrics_new.guardrail.f1",
        "result.metrics_new.other.f1",
        "result.metrics_new.accuracy",
        "result.metrics_new.n_held_out",
        "result.metrics_new.n_reviewed_held_out",
        "result.metrics_new.against",
        "result.metrics_current.guardrail.f1",
    ],
    ("post", "/api/models/{version}/activate"): ["active", "changed_segments"],
    ("get", "/api/overview"): [
        "trajectory",
        "length_m",
        "segments_off_runs",
        "runs[].run_id",
        "runs[].type",
        "runs[].signature",
        "runs[].length_m",
        "runs[].poles",
        "runs[].path",
        "runs[].segments",
        "runs[].reviewed",
        "runs[].changed",
        "runs[].asked",
        "runs[].progress",
        "runs[].state",
        "runs[].segment",
    ],
    ("post", "/api/lasso/cancel"): ["lasso_points"],
    ("get", "/api/queue/off-runs"): ["items[].id", "asked", "reviewed", "done"],
}

#: Models of figures read from stored model folders, which keep fields they do not name.
OPEN_MODELS = {"StoredMetrics", "ClassMetrics", "HeldOutMetrics", "ErrorDetail"}


@pytest.fixture(scope="module")
def spec() -> dict[str, Any]:
    # The schema never touches the session: no drive is needed to read it.
    with TestClient(create_app(cast(ReviewSession, None))) as client:
        response = client.get("/openapi.json")
    assert response.status_code == 200
    return cast(dict[str, Any], response.json())


def _operations(spec: dict[str, Any]) -> list[tuple[str, str, dict[str, Any]]]:
    return [
        (method, path, operation)
        for path, item in spec["paths"].items()
        for method, operation in item.items()
    ]


def _success(operation: dict[str, Any]) -> dict[str, Any]:
    """The content of the operation's one 2xx answer."""
    answers = [a for code, a in operation["responses"].items() if code.startswith("2")]
    assert len(answers) == 1
    return answers[0].get("content", {})


def _resolve(spec: dict[str, Any], schema: dict[str, Any]) -> list[dict[str, Any]]:
    """The object schemas a schema may be: $refs followed, ``null`` left out of unions."""
    if "$ref" in schema:
        name = schema["$ref"].removeprefix("#/components/schemas/")
        return _resolve(spec, spec["components"]["schemas"][name])
    if "anyOf" in schema:
        return [s for branch in schema["anyOf"] for s in _resolve(spec, branch)]
    if schema.get("type") == "null":
        return []
    return [schema]


def _field(spec: dict[str, Any], schema: dict[str, Any], dotted: str) -> dict[str, Any] | None:
    """The schema of ``dotted`` (``a.b[].c``) inside ``schema``, None when a step is missing."""
    current = [schema]
    for step in dotted.split("."):
        name, into_list = step.removesuffix("[]"), step.endswith("[]")
        found = [
            s["properties"][name]
            for c in current
            for s in _resolve(spec, c)
            if name in s.get("properties", {})
        ]
        if not found:
            return None
        if into_list:
            found = [f["items"] for f in found if "items" in f]
            if not found:
                return None
        current = found
    return current[0]


def test_the_api_has_the_routes_the_pages_call(spec: dict[str, Any]) -> None:
    operations = {(method, path) for method, path, _ in _operations(spec)}
    assert set(FIELDS_THE_PAGES_READ) <= operations
    assert set(FILE_ROUTES) <= operations


def test_every_json_answer_names_its_model(spec: dict[str, Any]) -> None:
    for method, path, operation in _operations(spec):
        if (method, path) in FILE_ROUTES:
            continue
        content = _success(operation)
        assert list(content) == ["application/json"], (method, path)
        schema = content["application/json"]["schema"]
        assert schema.get("$ref", "").startswith("#/components/schemas/"), (method, path, schema)
        (model,) = _resolve(spec, schema)
        assert model["type"] == "object" and model["properties"], (method, path)


def test_every_file_answer_names_its_media_types(spec: dict[str, Any]) -> None:
    for (method, path), media_types in FILE_ROUTES.items():
        content = _success(spec["paths"][path][method])
        assert set(content) == media_types, (method, path)
        for media in content.values():
            assert media["schema"] == {"type": "string", "format": "binary"}


def test_the_models_name_the_fields_the_pages_read(spec: dict[str, Any]) -> None:
    missing = []
    for (method, path), fields in FIELDS_THE_PAGES_READ.items():
        schema = _success(spec["paths"][path][method])["application/json"]["schema"]
        missing += [f"{method} {path}: {f}" for f in fields if _field(spec, schema, f) is None]
    assert missing == []


def test_the_pages_fields_have_their_types(spec: dict[str, Any]) -> None:
    segment = spec["paths"]["/api/segments/{segment_id}"]["get"]
    schema = _success(segment)["application/json"]["schema"]
    label = _field(spec, schema, "label")
    assert label is not None and label["enum"] == ["guardrail", "other"]
    probability = _field(spec, schema, "probability")
    assert probability is not None
    assert {s.get("type") for s in probability["anyOf"]} == {"number", "null"}
    crop_status = _field(spec, schema, "crop_status")
    assert crop_status is not None and set(crop_status["enum"]) == {"ok", "no_image", "too_small"}
    reason = _field(
        spec,
        _success(spec["paths"]["/api/queue"]["get"])["application/json"]["schema"],
        "items[].reason",
    )
    assert reason is not None and set(reason["enum"]) == {"disagrees", "unchecked", "uncertain"}
    job = _success(spec["paths"]["/api/jobs/{job_id}"]["get"])["application/json"]["schema"]
    status = _field(spec, job, "status")
    assert status is not None and set(status["enum"]) == {
        "queued",
        "running",
        "done",
        "failed",
        "cancelled",
    }
    progress = _field(spec, job, "progress")
    assert progress is not None and progress["type"] == "number"


def test_every_field_is_typed_and_every_answer_closed(spec: dict[str, Any]) -> None:
    """No field is the empty (any) schema; the answers' models list every field they have."""
    untyped, open_models = [], []
    for name, model in spec["components"]["schemas"].items():
        if name.startswith(("HTTPValidationError", "ValidationError")):
            continue  # FastAPI's own
        for field, schema in model.get("properties", {}).items():
            if not set(schema) & {"type", "$ref", "anyOf", "enum", "const"}:
                untyped.append(f"{name}.{field}")
        if name not in OPEN_MODELS and not name.endswith("Body"):
            if model.get("additionalProperties") is not False:
                open_models.append(name)
    assert untyped == []
    assert open_models == []


def test_the_reconstruction_parameters_state_every_range(spec: dict[str, Any]) -> None:
    """The apply route's body names every stage and parameter with the stage's own bounds, so a
    client can build a valid request from the schema alone (test_app_fuzz does)."""
    body = spec["paths"]["/api/reconstruction/apply"]["post"]["requestBody"]["content"]
    body_schema = body["application/json"]["schema"]
    checked = 0
    for stage, cls in ReconstructionParams.stage_classes().items():
        for param in cls.specs():
            field = _field(spec, body_schema, f"params.{stage}.{param.name}")
            assert field is not None, f"{stage}.{param.name}"
            bounds = field if "prefixItems" not in field else field["prefixItems"][0]
            for ours, theirs in (
                (param.ge, "minimum"),
                (param.gt, "exclusiveMinimum"),
                (param.le, "maximum"),
                (param.lt, "exclusiveMaximum"),
            ):
                if ours is not None:
                    assert bounds[theirs] == ours, f"{stage}.{param.name} {theirs}"
            checked += 1
    assert checked > 100
    slice_interval = _field(spec, body_schema, "params.pipes.slice_interval_m")
    assert slice_interval is not None and slice_interval["minimum"] == 0.005
