"""Wall-clock timings of pipeline stages, for ``timings.json`` and the benchmarks."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager


class StageTimer:
    """Records the seconds and the number of input points of every stage, in order.

    >>> timer = StageTimer(points_in=1000)
    >>> with timer.stage("road", points=1000):
    ...     pass
    >>> list(timer.as_json()["stages"])
    ['road']
    """

    def __init__(self, points_in: int) -> None:
        self.points_in = int(points_in)
        self.stages: dict[str, dict[str, float | int]] = {}
        self._start = time.perf_counter()

    @contextmanager
    def stage(self, name: str, *, points: int | None = None) -> Iterator[None]:
        """Time the enclosed block as stage ``name`` working on ``points`` points."""
        start = time.perf_counter()
        try:
            yield
        finally:
            entry: dict[str, float | int] = {"seconds": round(time.perf_counter() - start, 4)}
            if points is not None:
                entry["points"] = int(points)
            self.stages[name] = entry

    def seconds(self, *names: str) -> float:
        """Total seconds of the named stages."""
        return float(sum(self.stages[name]["seconds"] for name in names))

    def as_json(self) -> dict:
        return {
            "points_in": self.points_in,
            "stages": self.stages,
            "total_seconds": round(time.perf_counter() - self._start, 4),
        }
