"""Schemathesis against the review app's own ``/openapi.json``: every operation gets valid and
invalid requests built from the schema alone, and every answer must be no server error, a status
the schema documents, a body that fits the schema, an invalid request refused and a valid one
accepted.

The examples are derandomised (the same requests every run: a failure reproduces) and bounded
(:data:`EXAMPLES` per operation, about half a minute in all). The job runner is kept busy with one
held job of each kind, so that a valid training or reconstruction request is answered 409 (busy)
rather than starting minutes of work; the routes' 202 answers are tested in ``test_app_api``.
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from schemathesis import GenerationMode
from schemathesis.checks import positive_data_acceptance
from schemathesis.core.failures import FailureGroup

from app.jobs import JobRunner
from app.main import create_app
from app.session import ReviewSession
from guardrail_core.params import ParameterError
from guardrail_core.reconstruct.pipeline import ReconstructionParams
from tests.app_fixtures import copy_run, new_session

#: Requests per operation (valid and invalid together).
EXAMPLES = 60
#: The route whose body has rules between fields that JSON Schema cannot state.
APPLY = "POST /api/reconstruction/apply"


@pytest.fixture(scope="module")
def schema(
    drive_path: Path, run_path: Path, model_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Any]:
    tmp = tmp_path_factory.mktemp("fuzz")
    session: ReviewSession = new_session(
        drive_path, copy_run(run_path, tmp), tmp / "review", model_path
    )
    jobs = JobRunner()
    release = threading.Event()
    for kind in ("train", "reconstruct"):
        jobs.submit(kind, lambda report: {"released": release.wait(3600)})
    yield schemathesis.openapi.from_asgi("/openapi.json", create_app(session, jobs=jobs))
    release.set()
    jobs.shutdown()
    session.close()


def _apply_refusal(case: Any, answer: Any) -> str | None:
    """What is wrong with an answer of the apply route that the schema's checks cannot judge: a
    valid body is refused (422 at ``body.params``) exactly when the parameters break a rule between
    fields, and otherwise accepted (202, or 409 while a reconstruction runs)."""
    if not isinstance(case.body, dict) or not isinstance(case.body.get("params"), dict):
        return None
    refused = answer.status_code == 422
    error: dict[str, Any] = answer.json()["detail"][0] if refused else {}
    if refused and error["loc"] != ["body", "params"]:
        return None  # the schema's own refusal: the generic checks judge it
    try:
        ReconstructionParams.from_json(case.body["params"])
    except ParameterError as exc:
        if not refused or error["msg"] != str(exc):
            return f"broken rule {exc} answered {answer.status_code}"
        return None
    if answer.status_code not in (202, 409):
        return f"valid parameters answered {answer.status_code}: {answer.text[:300]}"
    return None


def _fuzz(operation: Any, failures: list[str], statuses: Counter[int]) -> None:
    """Send :data:`EXAMPLES` valid and invalid requests to one operation; note what is wrong."""
    label = operation.label
    excluded = [positive_data_acceptance] if label == APPLY else []
    cases = operation.as_strategy(generation_mode=GenerationMode.POSITIVE) | (
        operation.as_strategy(generation_mode=GenerationMode.NEGATIVE)
    )

    @settings(
        max_examples=EXAMPLES,
        derandomize=True,
        database=None,
        deadline=None,
        phases=[Phase.explicit, Phase.generate],
        # Some operations have nothing invalid to send (no parameters): the negative branch is
        # filtered away and the positive one serves.
        suppress_health_check=[HealthCheck.filter_too_much, HealthCheck.too_slow],
    )
    @given(case=cases)
    def check(case: Any) -> None:
        answer = case.call()
        statuses[answer.status_code] += 1
        try:
            case.validate_response(answer, excluded_checks=excluded)
        except FailureGroup as group:
            failures.extend(f"{label}: {f.title}: {f.message[:300]}" for f in group.exceptions)
        if label == APPLY and (wrong := _apply_refusal(case, answer)):
            failures.append(f"{label}: {wrong}")

    check()


def test_every_operation_answers_as_its_schema_says(schema: Any) -> None:
    failures: list[str] = []
    statuses: Counter[int] = Counter()
    operations = [result.ok() for result in schema.get_all_operations()]
    for operation in operations:
        _fuzz(operation, failures, statuses)
    assert len(operations) >= 21  # every route the app has (a route lost from the schema shows)
    assert sorted(set(failures)) == []
    # Both kinds of request reached the routes: answered, refused as invalid, and not found.
    assert statuses[200] > 100 and statuses[422] > 100 and statuses[404] > 20, statuses
    assert not any(code >= 500 for code in statuses), statuses
