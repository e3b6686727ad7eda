"""``GET /api/runs/{run_id}/histogram``: the numbers behind a run's thresholds (§4.3, Fig. 14),
on the test drive's reconstructed run."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app import run_tuning
from app.run_tuning import RunTuner
from app.session import ReviewSession
from guardrail_core.reconstruct.pipeline import reconstruct_unit


def test_a_pipe_run_s_histogram_threshold_and_pipes(
    module_client: TestClient, module_session: ReviewSession
) -> None:
    tuner = RunTuner(module_session.run.root)
    pipe_runs = [r for r in tuner.tunable_runs() if r.model and r.model.type == "pipe"]
    assert pipe_runs, "the test street has a reconstructed pipe run"
    run = pipe_runs[0]
    assert run.model is not None
    before = (module_session.run.root / "reconstruction" / "models.json").read_bytes()
    body = module_client.get(f"/api/runs/{run.run_id}/histogram").json()
    params = tuner.params.pipes
    assert body["type"] == "pipe" and body["histogram_factor"] == params.histogram_factor
    counts = np.array(body["counts"])
    x = np.array(body["x_m"])
    assert len(counts) == len(x) > 10 and counts.sum() > 0
    np.testing.assert_allclose(np.diff(x), body["bin_m"])
    assert -body["bin_m"] < x[0] and x[-1] < run.model.length + body["bin_m"]
    # The threshold is the factor times the median count, at least the minimum count.
    expected = max(params.histogram_factor * float(np.median(counts)), params.histogram_min_count)
    assert body["threshold"] == pytest.approx(expected)
    # With the stored thresholds, the pipes are the stored model's (models.json keeps 0.1 mm).
    stored = sorted((p.kind, float(p.axis[:, 0].min())) for p in run.model.pipes)
    found = sorted((p["kind"], p["x_min_m"]) for p in body["pipes"])
    assert [k for k, _ in found] == [k for k, _ in stored]
    np.testing.assert_allclose([x for _, x in found], [x for _, x in stored], atol=1e-4)

    # The slider's value: the threshold follows; past the highest bar, no vertical pipe is left.
    higher = module_client.get(
        f"/api/runs/{run.run_id}/histogram", params={"histogram_factor": 6.0}
    ).json()
    assert higher["counts"] == body["counts"]
    assert higher["threshold"] == pytest.approx(
        max(6.0 * float(np.median(counts)), params.histogram_min_count)
    )
    if higher["threshold"] >= counts.max():
        assert not [p for p in higher["pipes"] if p["kind"] == "vertical"]
    # Nothing is written.
    assert (module_session.run.root / "reconstruction" / "models.json").read_bytes() == before


def test_unknown_runs_and_bad_factors_are_refused(
    module_client: TestClient, module_session: ReviewSession
) -> None:
    tuner = RunTuner(module_session.run.root)
    missing = max(r.run_id for r in tuner.runs) + 1
    assert module_client.get(f"/api/runs/{missing}/histogram").status_code == 404
    assert module_client.get("/api/runs/-1/histogram").status_code == 404
    run_id = tuner.tunable_runs()[0].run_id
    for factor in ("0.5", "6.5", "nan", "x"):
        answer = module_client.get(f"/api/runs/{run_id}/histogram?histogram_factor={factor}")
        assert answer.status_code == 422, factor
    without = [r for r in tuner.runs if r.model is None]
    if without:
        assert module_client.get(f"/api/runs/{without[0].run_id}/histogram").status_code == 404


def test_every_pipe_run_re_run_with_its_thresholds_is_the_stored_model(
    module_session: ReviewSession, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The app re-runs a unit model from the superimposed points and the unit each came from,
    # as the reconstruction did: strays behind one unit are left out alike.
    given = []

    def spy(*args, **kwargs):  # type: ignore[no-untyped-def]
        given.append(kwargs.get("unit_of_point"))
        return reconstruct_unit(*args, **kwargs)

    monkeypatch.setattr(run_tuning, "reconstruct_unit", spy)
    tuner = RunTuner(module_session.run.root)
    pipe_runs = [r for r in tuner.tunable_runs() if r.model and r.model.type == "pipe"]
    assert pipe_runs
    for run in pipe_runs:
        assert run.model is not None
        assert len(tuner.units(run.run_id)) == len(tuner.points(run.run_id))
        again = tuner.unit(run.run_id, tuner.params).model
        np.testing.assert_array_equal(given[-1], tuner.units(run.run_id))
        assert again.notes == run.model.notes
        assert [p.kind for p in again.pipes] == [p.kind for p in run.model.pipes]
        for a, b in zip(again.pipes, run.model.pipes, strict=True):
            np.testing.assert_allclose(a.axis, b.axis, atol=1e-4)
