"""Background jobs (fine-tuning, activating a model, re-running the reconstruction), one at a time.

A job runs on a single worker thread so that two trainings never compete for the two cores; the
REST API polls its progress. A job that fails keeps its error message; nothing it was writing is
half-written (model folders and run folders are written atomically by guardrail_core).
"""

from __future__ import annotations

import threading
import time
import traceback
import uuid
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

#: A job's work: called with a ``report(fraction, message)`` function, returns its JSON result.
Work = Callable[[Callable[[float, str], None]], dict[str, Any]]


@dataclass
class Job:
    id: str
    kind: str
    status: str = "queued"  # queued | running | done | failed
    progress: float = 0.0
    message: str = ""
    error: str | None = None
    result: dict[str, Any] | None = None
    created: float = field(default_factory=time.time)
    finished: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "kind": self.kind,
            "status": self.status,
            "progress": round(self.progress, 4),
            "message": self.message,
            "error": self.error,
            "result": self.result,
        }


class JobRunner:
    """Runs jobs in submission order on one thread and remembers them."""

    def __init__(self) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="review-job")
        self._jobs: dict[str, Job] = {}
        self._lock = threading.Lock()

    def submit(self, kind: str, work: Work) -> Job:
        job = Job(id=uuid.uuid4().hex[:12], kind=kind)
        with self._lock:
            self._jobs[job.id] = job
        self._pool.submit(self._run, job, work)
        return job

    def get(self, job_id: str) -> Job | None:
        with self._lock:
            return self._jobs.get(job_id)

    def list(self, kind: str | None = None) -> list[Job]:
        """Jobs (of one kind when given), newest first."""
        with self._lock:
            jobs = [j for j in self._jobs.values() if kind is None or j.kind == kind]
        return sorted(jobs, key=lambda j: j.created, reverse=True)

    def busy(self, kind: str) -> Job | None:
        """A queued or running job of that kind, if any."""
        with self._lock:
            for job in self._jobs.values():
                if job.kind == kind and job.status in ("queued", "running"):
                    return job
        return None

    def _run(self, job: Job, work: Work) -> None:
        def report(fraction: float, message: str) -> None:
            job.progress = min(max(float(fraction), 0.0), 1.0)
            job.message = message

        job.status = "running"
        try:
            job.result = work(report)
        except Exception as exc:  # a job's failure is reported, never lost in a thread
            job.error = f"{type(exc).__name__}: {exc}"
            job.message = "failed"
            job.status = "failed"
            traceback.print_exc()
        else:
            job.progress = 1.0
            job.status = "done"
        finally:
            job.finished = time.time()

    def wait(self, job_id: str, timeout: float = 60.0) -> Job:
        """Block until the job ends (for tests and scripts)."""
        deadline = time.monotonic() + timeout
        while True:
            job = self.get(job_id)
            if job is None:
                raise KeyError(job_id)
            if job.status in ("done", "failed"):
                return job
            if time.monotonic() > deadline:
                raise TimeoutError(f"job {job_id} still {job.status} after {timeout} s")
            time.sleep(0.05)

    def shutdown(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
