"""Background jobs (fine-tuning, activating a model, re-running the reconstruction), one at a time.

A job runs on a single worker thread so that two trainings never compete for the two cores; the
REST API polls its progress. A job that fails keeps its error message; nothing it was writing is
half-written (model folders and run folders are written atomically by guardrail_core).

Jobs are bounded: at most one queued or running job of a kind (:class:`JobBusyError` for a
second), each with a time limit (:data:`TIME_LIMIT_S`), and cancellable. A thread cannot be
stopped from outside, so a job stops where it next reports its progress: ``report`` raises
:class:`JobCancelled` (or :class:`JobTimeLimitError`), and the job's writer throws its staging
folder away.
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

#: Seconds a job of a kind may run (a full fine-tune on the CPU takes minutes; a reconstruction of
#: a few hundred metres seconds); other kinds: :data:`DEFAULT_TIME_LIMIT_S`.
TIME_LIMIT_S = {"train": 3600.0, "reconstruct": 900.0}
DEFAULT_TIME_LIMIT_S = 900.0


class JobCancelled(Exception):
    """Raised inside a job's work, at its next progress report, once it is cancelled."""


class JobTimeLimitError(Exception):
    """Raised inside a job's work, at its next progress report, past its time limit."""


class JobFailed(Exception):
    """A job's failure told in an operator's words: ``advice`` says what went wrong and what to
    do; the exception it is raised from keeps the technical error (the job's ``error``)."""

    def __init__(self, advice: str) -> None:
        super().__init__(advice)
        self.advice = advice


class JobBusyError(Exception):
    """A job of that kind is already queued or running."""

    def __init__(self, job: Job) -> None:
        super().__init__(f"a {job.kind} job is already {job.status} (job {job.id})")
        self.job = job


@dataclass
class Job:
    id: str
    kind: str
    status: str = "queued"  # queued | running | done | failed | cancelled
    progress: float = 0.0
    message: str = ""
    error: str | None = None
    advice: str | None = None
    result: dict[str, Any] | None = None
    created: float = field(default_factory=time.time)
    finished: float | None = None
    time_limit_s: float = DEFAULT_TIME_LIMIT_S
    cancel_requested: bool = False
    on_end: Callable[[Job], None] | None = None  # told how it ended, on the job's thread

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "kind": self.kind,
            "status": self.status,
            "progress": round(self.progress, 4),
            "message": self.message,
            "error": self.error,
            "advice": self.advice,
            "result": self.result,
        }


class JobRunner:
    """Runs jobs in submission order on one thread and remembers them."""

    def __init__(self) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="review-job")
        self._jobs: dict[str, Job] = {}
        self._lock = threading.Lock()

    def submit(self, kind: str, work: Work, on_end: Callable[[Job], None] | None = None) -> Job:
        """Queue ``work`` as a job of ``kind``; ``on_end(job)`` is called once it has ended
        (done, failed or cancelled after it started).

        Raises
        ------
        JobBusyError
            A job of that kind is queued or running (the queue holds one per kind).
        """
        job = Job(
            id=uuid.uuid4().hex[:12],
            kind=kind,
            time_limit_s=TIME_LIMIT_S.get(kind, DEFAULT_TIME_LIMIT_S),
            on_end=on_end,
        )
        with self._lock:
            for other in self._jobs.values():
                if other.kind == kind and other.status in ("queued", "running"):
                    raise JobBusyError(other)
            self._jobs[job.id] = job
        self._pool.submit(self._run, job, work)
        return job

    def cancel(self, job_id: str) -> Job:
        """Ask a job to stop: a queued job never starts, a running one stops at its next
        progress report.

        Raises
        ------
        KeyError
            No such job.
        """
        with self._lock:
            job = self._jobs[job_id]
            if job.status == "queued":
                job.status, job.message, job.finished = "cancelled", "cancelled", time.time()
            elif job.status == "running":
                job.cancel_requested = True
                job.message = "cancelling"
        return job

    def get(self, job_id: str) -> Job | None:
        with self._lock:
            return self._jobs.get(job_id)

    def list(self, kind: str | None = None) -> list[Job]:
        """Jobs (of one kind when given), newest first."""
        with self._lock:
            jobs = [j for j in self._jobs.values() if kind is None or j.kind == kind]
        return sorted(jobs, key=lambda j: j.created, reverse=True)

    def _run(self, job: Job, work: Work) -> None:
        deadline = time.monotonic() + job.time_limit_s

        def report(fraction: float, message: str) -> None:
            if job.cancel_requested:
                raise JobCancelled
            if time.monotonic() > deadline:
                raise JobTimeLimitError(f"the job ran past its limit of {job.time_limit_s:g} s")
            job.progress = min(max(float(fraction), 0.0), 1.0)
            job.message = message

        with self._lock:
            if job.status == "cancelled":  # cancelled while queued
                return
            job.status = "running"
        try:
            job.result = work(report)
        except JobCancelled:
            job.status, job.message = "cancelled", "cancelled"
        except Exception as exc:  # a job's failure is reported, never lost in a thread
            cause = exc.__cause__ if isinstance(exc, JobFailed) and exc.__cause__ else exc
            job.error = f"{type(cause).__name__}: {cause}"
            job.advice = exc.advice if isinstance(exc, JobFailed) else None
            job.message = "failed"
            job.status = "failed"
            if not isinstance(exc, JobTimeLimitError):
                traceback.print_exc()
        else:
            job.progress = 1.0
            job.status = "done"
        # Told before the job counts as finished, so that whoever waits on it sees what it did.
        if job.on_end is not None:
            try:
                job.on_end(job)
            except Exception:  # whoever listens must not take the runner down
                traceback.print_exc()
        job.finished = time.time()

    def wait(self, job_id: str, timeout: float = 60.0) -> Job:
        """Block until the job ends (for tests and scripts)."""
        deadline = time.monotonic() + timeout
        while True:
            job = self.get(job_id)
            if job is None:
                raise KeyError(job_id)
            if job.finished is not None:
                return job
            if time.monotonic() > deadline:
                raise TimeoutError(f"job {job_id} still {job.status} after {timeout} s")
            time.sleep(0.05)

    def shutdown(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
