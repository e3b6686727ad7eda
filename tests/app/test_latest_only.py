"""The slider's re-run: at once when idle, asks made meanwhile collapse into one more run."""

from __future__ import annotations

import threading

from app.scene.latest_only import LatestOnly


def test_asks_made_during_a_run_collapse_into_one_more_run() -> None:
    started = threading.Semaphore(0)
    release = threading.Event()
    runs: list[int] = []

    def work() -> None:
        runs.append(len(runs))
        started.release()
        release.wait()

    runner = LatestOnly(work)
    runner.request()
    assert started.acquire(timeout=30)  # the first ask runs at once, without waiting for more
    assert not runner.pending
    for _ in range(5):  # a drag's steps while it runs
        runner.request()
    assert runner.pending  # what the run now running computes is stale
    release.set()
    assert runner.wait_idle(timeout_s=30)
    assert runs == [0, 1]  # the five steps made one more run, with the sliders as they were last
    assert not runner.pending
    runner.request()
    assert runner.wait_idle(timeout_s=30)
    assert runs == [0, 1, 2]


def test_a_failing_run_does_not_stop_the_next_and_close_stops_all() -> None:
    calls: list[str] = []

    def work() -> None:
        calls.append("run")
        if len(calls) == 1:
            raise RuntimeError("the first run fails")

    runner = LatestOnly(work)
    runner.request()
    assert runner.wait_idle(timeout_s=30)
    runner.request()
    assert runner.wait_idle(timeout_s=30)
    assert calls == ["run", "run"]
    runner.close()
    runner.request()
    assert runner.wait_idle(timeout_s=30)
    assert calls == ["run", "run"]
