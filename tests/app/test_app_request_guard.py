"""What the REST API refuses before any route runs (a page of another site, another host name, a
form post, a huge body) and the answers to bodies no route can take (ids beyond int64, NaN)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.jobs import JobRunner
from app.main import create_app
from app.request_guard import MAX_BODY_BYTES, allowed_hosts_for, host_name, origin_netloc
from app.session import ReviewSession
from tests.app_fixtures import copy_run, new_session

OWN = "http://127.0.0.1:8000"


@pytest.fixture()
def session(drive_path: Path, run_path: Path, model_path: Path, tmp_path: Path):
    s = new_session(drive_path, copy_run(run_path, tmp_path), tmp_path / "review", model_path)
    yield s
    s.close()


@pytest.fixture()
def client(session: ReviewSession) -> Iterator[TestClient]:
    """A client of a server bound to 127.0.0.1:8000, as ``guardrail serve`` starts it."""
    jobs = JobRunner()
    app = create_app(session, jobs=jobs, allowed_hosts=allowed_hosts_for("127.0.0.1"))
    with TestClient(app, base_url=OWN) as c:
        yield c
    jobs.shutdown()


def _labelled(session: ReviewSession) -> int:
    return int(session.store.counts()["labelled_points"])


def test_a_page_of_another_site_changes_nothing(client: TestClient, session: ReviewSession):
    evil = {"Origin": "http://evil.example"}
    for origin in ("http://evil.example", "null", "http://127.0.0.1:9999", "file://"):
        answer = client.put(
            "/api/segments/0/label", json={"label": "guardrail"}, headers={"Origin": origin}
        )
        assert answer.status_code == 403, origin
        assert "another origin" in answer.json()["detail"]
    assert client.post("/api/labels/undo", json={}, headers=evil).status_code == 403
    assert client.post("/api/train", json={}, headers=evil).status_code == 403
    assert client.put("/api/selection", json={"segments": [0]}, headers=evil).status_code == 403
    assert _labelled(session) == 0 and client.get("/api/selection").json()["segments"] == []
    # The app's own pages (same origin) and clients that are not browsers (no Origin) may.
    own = client.put("/api/segments/0/label", json={"label": "guardrail"}, headers={"Origin": OWN})
    assert own.status_code == 200 and _labelled(session) > 0
    assert client.post("/api/labels/undo", json={}).status_code == 200
    assert _labelled(session) == 0
    # Reading stays open to any origin (the token guards it when the server has one).
    assert client.get("/api/info", headers=evil).status_code == 200


def test_a_cross_site_form_post_is_refused_without_an_origin(client: TestClient):
    """An HTML form can send only form encodings or text/plain: every state change needs JSON."""
    for content_type in ("application/x-www-form-urlencoded", "multipart/form-data", "text/plain"):
        answer = client.post(
            "/api/train", content=b"mode=fast", headers={"Content-Type": content_type}
        )
        assert answer.status_code == 415, content_type
    empty_form = {"Content-Type": "application/x-www-form-urlencoded"}  # a form with no fields
    assert client.post("/api/labels/undo", headers=empty_form).status_code == 415
    assert client.post("/api/labels/undo").status_code == 200  # no body and no type: not a form
    assert client.get("/api/jobs").status_code == 200


def test_another_host_name_is_not_answered(client: TestClient, session: ReviewSession):
    """DNS rebinding: a page of evil.example resolved to 127.0.0.1 sends Host: evil.example."""
    for host in ("evil.example", "evil.example:8000", "127.0.0.1.evil.example"):
        answer = client.get("/api/info", headers={"Host": host})
        assert answer.status_code == 400, host
        relabel = client.put(
            "/api/segments/0/label", json={"label": "guardrail"}, headers={"Host": host}
        )
        assert relabel.status_code == 400
    assert _labelled(session) == 0
    for host in ("127.0.0.1:8000", "localhost:8000", "[::1]:8000"):
        assert client.get("/api/info", headers={"Host": host}).status_code == 200, host


def test_a_body_over_the_limit_is_refused_before_it_is_read(client: TestClient):
    big = b'{"segments": [' + b"0, " * (MAX_BODY_BYTES // 3) + b'0], "label": "other"}'
    assert len(big) > MAX_BODY_BYTES
    answer = client.post(
        "/api/labels/batch", content=big, headers={"Content-Type": "application/json"}
    )
    assert answer.status_code == 413 and "limit" in answer.json()["detail"]

    def chunks() -> Iterator[bytes]:  # no Content-Length: cut off as it streams
        yield b'{"segments": ['
        for _ in range(MAX_BODY_BYTES // 65536 + 2):
            yield b"0, " * 21845 + b"0,"
        yield b'0], "label": "other"}'

    streamed = client.post(
        "/api/labels/batch", content=chunks(), headers={"Content-Type": "application/json"}
    )
    assert streamed.status_code == 413


def test_ids_beyond_int64_and_non_finite_numbers_get_a_422_that_serialises(
    client: TestClient, session: ReviewSession
):
    huge = "99999999999999999999999"
    answer = client.put(f"/api/segments/{huge}/label", json={"label": "other"})
    assert answer.status_code == 422
    for path, body in (
        ("/api/labels/batch", f'{{"segments": [{huge}], "label": "other"}}'),
        ("/api/selection", f'{{"segments": [{huge}]}}'),
    ):
        method = client.post if path.endswith("batch") else client.put
        answer = method(path, content=body, headers={"Content-Type": "application/json"})
        assert answer.status_code == 422, path
    # NaN, Infinity and 1e400 where the body wants something else: echoed as their names.
    for value in ("NaN", "Infinity", "-Infinity", "1e400"):
        answer = client.post(
            "/api/labels/batch",
            content=f'{{"segments": [{value}], "label": "other"}}',
            headers={"Content-Type": "application/json"},
        )
        assert answer.status_code == 422, value
        json.loads(answer.text)  # it serialised
    # A long invalid field is not echoed whole.
    long_label = "x" * 1_000_000
    answer = client.put("/api/segments/0/label", json={"label": long_label})
    assert answer.status_code == 422 and len(answer.content) < 2_000
    assert _labelled(session) == 0
    assert len(session.run) < 2**31  # the ids above are out of range however the run grows


def test_header_parsing() -> None:
    assert host_name("127.0.0.1:8000") == "127.0.0.1"
    assert host_name("[::1]:8000") == "::1"
    assert host_name("LOCALHOST") == "localhost"
    assert origin_netloc("http://127.0.0.1:8000") == "127.0.0.1:8000"
    assert origin_netloc("null") == "" and origin_netloc("file://") == ""
    hosts = allowed_hosts_for("0.0.0.0", ["review.example"])
    assert {"127.0.0.1", "localhost", "::1", "review.example"} <= hosts


def test_reconstruction_parameters_out_of_range_are_a_422_and_start_nothing(client: TestClient):
    for params in (
        {"pipes": {"slice_interval_m": 1e-5}},  # minutes and 4 GB before
        {"pipes": {"slice_interval_m": -1}},
        {"pipes": {"slice_interval_m": "abc"}},
        {"pipes": {"slice_interval_m": None}},
        {"poles": {"min_circle_points": 1e308}},
    ):
        answer = client.post("/api/reconstruction/apply", json={"params": params})
        assert answer.status_code == 422, params
        stage, name = next((stage, name) for stage, values in params.items() for name in values)
        assert answer.json()["detail"][0]["loc"] == ["body", "params", stage, name]
    assert client.get("/api/jobs").json()["items"] == []


def test_a_rule_between_parameters_is_a_422_of_the_same_shape(client: TestClient):
    """JSON Schema cannot say "taubin_mu below -taubin_lambda": the route refuses it itself."""
    answer = client.post(
        "/api/reconstruction/apply", json={"params": {"beams": {"taubin_mu": -0.1}}}
    )
    assert answer.status_code == 422
    [error] = answer.json()["detail"]
    assert error["loc"] == ["body", "params"] and error["type"] == "value_error"
    assert "taubin_mu must be below -taubin_lambda" in error["msg"]
    assert client.get("/api/jobs").json()["items"] == []
