"""Tiles as Dask tasks: an embedded ``LocalCluster`` by default, any Dask scheduler beyond.

``guardrail process`` maps one task per tile over a :class:`dask.distributed.Client`. Without a
scheduler address it starts a ``LocalCluster`` of worker *processes* (one thread each: the CNN
and the geometry are single-threaded per tile, and processes keep one tile's memory from
another's); with ``--scheduler tcp://HOST:PORT`` the same tasks go to an existing cluster
(``dask-scheduler`` and ``dask-worker`` on several machines, or any Dask deployment). Tasks
carry paths on shared storage, never arrays of points.

A worker that dies is replaced and its task retried by Dask (the scheduler's
``allowed-failures``, 3 by default); a task that still fails is reported by :func:`map_tasks`
instead of stopping the others.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from guardrail_core.errors import InvalidOptionError
from guardrail_core.progress import progress_bar

#: The Dask setting behind the environment variable its nanny sets in every worker it spawns.
_TRIM_ENV = "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_"
_PROFILE = "distributed.worker.profile.enabled"

T = TypeVar("T")
R = TypeVar("R")


@dataclass(frozen=True)
class ClusterSpec:
    """Where tasks run.

    Attributes
    ----------
    workers : worker processes of the embedded LocalCluster; 0: no Dask, tasks run one after
        another in this process (ignored with ``scheduler``)
    scheduler : address of an existing Dask scheduler (``tcp://host:8786``), or None
    memory_limit : per worker of the LocalCluster, Dask's syntax (``"3GiB"``, ``"auto"``: the
        machine's memory shared equally)
    """

    workers: int = 0
    scheduler: str | None = None
    memory_limit: str = "auto"

    def __post_init__(self) -> None:
        if self.workers < 0:
            raise InvalidOptionError(f"workers must be 0 or more, got {self.workers}")

    @property
    def label(self) -> str:
        """``"none"`` (in this process), ``"local"`` (a LocalCluster) or the scheduler address."""
        if self.scheduler:
            return self.scheduler
        return "local" if self.workers > 0 else "none"


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


@contextmanager
def dask_client(spec: ClusterSpec) -> Iterator[Any]:
    """A ``dask.distributed.Client`` for ``spec`` (None when tasks run in this process); an
    embedded LocalCluster is closed on exit.

    Raises
    ------
    InvalidOptionError
        The scheduler cannot be reached.
    """
    if not spec.scheduler and spec.workers == 0:
        yield None
        return
    import dask
    from dask.distributed import Client, LocalCluster

    if spec.scheduler:
        try:
            client = Client(spec.scheduler, timeout="20s")
        except OSError as exc:
            raise InvalidOptionError(
                f"cannot reach the Dask scheduler at {spec.scheduler} ({exc})"
            ) from exc
        try:
            yield client
        finally:
            client.close()
        return
    # Dask's nanny sets MALLOC_TRIM_THRESHOLD_=64 KiB in its workers by default, which also
    # switches off glibc's adaptive mmap threshold: every array over 128 KiB is then mapped and
    # faulted in afresh, and a tile took about 30 % longer (benchmarks/bench_scale.py).
    # glibc's own defaults keep the freed arrays of one stage for the next. Dask's statistical
    # profiler samples every worker's stack 100 times a second, for the dashboard's profile
    # page only: about 1 % of a worker's CPU that the tiles need more.
    with dask.config.set({_TRIM_ENV: None, _PROFILE: False}):
        cluster = LocalCluster(
            n_workers=spec.workers,
            threads_per_worker=1,
            processes=True,
            memory_limit=spec.memory_limit,
            dashboard_address=":0",  # a free port: never a clash with another cluster
            silence_logs=logging.ERROR,
        )
    client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        cluster.close()


def on_every_worker(client: Any, target: str, *args: Any) -> list[Any]:
    """Start ``module:function`` (``target``) with ``args`` once on every worker of ``client`` as
    a task (one that prepares the worker, say) and return its futures without waiting. Named,
    not passed, so that this process need not import the function's module."""
    workers = list(client.scheduler_info()["workers"])
    return [
        client.submit(call, target, *args, workers=[w], allow_other_workers=False, pure=False)
        for w in workers
    ]


def call(target: str, *args: Any) -> Any:
    """``module:function`` (``target``) called with ``args``."""
    import importlib

    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)(*args)


@dataclass(frozen=True)
class TaskFailure(Generic[T]):
    """A task that failed beyond Dask's retries: its input and the error, as text."""

    item: T
    error: str


def map_tasks(
    client: Any,
    function: Callable[[T], R],
    items: Sequence[T],
    *,
    desc: str,
    unit: str,
    progress: bool,
    points: Callable[[R], int] | None = None,
    failures: tuple[type[BaseException], ...] = (),
    scatter: bool = False,
    on_result: Callable[[int, R | TaskFailure[T]], None] | None = None,
) -> list[R | TaskFailure[T]]:
    """``function`` over ``items`` on the cluster (or here, without a client), in the order of
    ``items``, with a progress bar (tasks done / total, and points/s where ``points`` counts
    a result's points).

    A task that raises one of ``failures``, or whose workers kept dying (Dask's
    ``KilledWorker``, after its retries), becomes a :class:`TaskFailure` and the other tasks go
    on; any other exception is a defect and propagates. ``scatter``: the items hold arrays;
    send them to the workers as data first rather than inside the task graph. ``on_result(i,
    result)`` is called here as each task ends, in the order they end (the work that follows a
    task overlaps the tasks still running).
    """
    results: list[R | TaskFailure[T] | None] = [None] * len(items)
    done_points = 0
    start = time.perf_counter()
    with progress_bar(total=len(items), desc=desc, unit=unit, enabled=progress) as bar:

        def record(i: int, result: R | TaskFailure[T]) -> None:
            nonlocal done_points
            results[i] = result
            if on_result is not None:
                on_result(i, result)
            if points is not None and not isinstance(result, TaskFailure):
                done_points += points(result)
                rate = done_points / max(time.perf_counter() - start, 1e-9)
                bar.set_postfix_str(f"{rate / 1e3:,.0f} k points/s")
            bar.update()

        if client is None:
            for i, item in enumerate(items):
                try:
                    result = function(item)
                except failures as exc:
                    record(i, TaskFailure(item, f"{type(exc).__name__}: {exc}"))
                else:
                    record(i, result)
        else:
            from dask.distributed import as_completed
            from distributed.scheduler import KilledWorker

            inputs = client.scatter(list(items)) if scatter else list(items)
            futures = client.map(function, inputs, pure=False)
            position = {future.key: i for i, future in enumerate(futures)}
            for future in as_completed(futures):
                i = position[future.key]
                if future.status == "finished":
                    record(i, future.result())
                else:
                    error = future.exception()
                    if not isinstance(error, (KilledWorker, *failures)):
                        client.cancel(futures)
                        raise error
                    record(i, TaskFailure(items[i], f"{type(error).__name__}: {error}"))
    return [r for r in results if r is not None]


class LaterTasks(Generic[T, R]):
    """Tasks of ``function`` started one by one while other work runs (from the ``on_result``
    of :func:`map_tasks`, say), and collected at the end.

    On the cluster each starts at once, ahead of the tasks still queued (Dask ``priority``):
    its work overlaps theirs instead of waiting for the last of them. Without a client each
    runs here when it is started. Failures are as in :func:`map_tasks`.
    """

    def __init__(
        self,
        client: Any,
        function: Callable[[T], R],
        *,
        failures: tuple[type[BaseException], ...] = (),
        priority: int = 1,
    ) -> None:
        self.client = client
        self.function = function
        self.failures = failures
        self.priority = priority
        self._items: list[T] = []
        self._done: dict[int, R | TaskFailure[T]] = {}
        self._futures: list[Any] = []

    @property
    def items(self) -> list[T]:
        """The items started, in order."""
        return list(self._items)

    def start(self, item: T) -> None:
        """Start ``function(item)``."""
        self._items.append(item)
        if self.client is None:
            try:
                self._done[len(self._items) - 1] = self.function(item)
            except self.failures as exc:
                self._done[len(self._items) - 1] = TaskFailure(item, f"{type(exc).__name__}: {exc}")
            return
        self._futures.append(
            self.client.submit(self.function, item, pure=False, priority=self.priority)
        )

    def results(self, *, desc: str, unit: str, progress: bool) -> list[R | TaskFailure[T]]:
        """Every task's result, in the order they were started, once all have ended (with a
        progress bar)."""
        if self._futures:
            from dask.distributed import as_completed
            from distributed.scheduler import KilledWorker

            position = {future.key: i for i, future in enumerate(self._futures)}
            with progress_bar(
                total=len(self._futures), desc=desc, unit=unit, enabled=progress
            ) as bar:
                for future in as_completed(self._futures):
                    self._collect(future, position[future.key], KilledWorker)
                    bar.update()
        return [self._done[i] for i in range(len(self._items))]

    def _collect(self, future: Any, i: int, killed: type[BaseException]) -> None:
        if future.status == "finished":
            self._done[i] = future.result()
            return
        error = future.exception()
        if not isinstance(error, (killed, *self.failures)):
            self.client.cancel(self._futures)
            raise error
        self._done[i] = TaskFailure(self._items[i], f"{type(error).__name__}: {error}")
