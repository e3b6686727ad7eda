"""Run a function in the background whenever asked: at once when idle, and asks made while it
runs collapse into one more run.

A slider fires on every step of a drag. A debounce timer would make every move wait; this
answers the first step at once, drops the steps a run was too slow for, and always runs once
more after the last step, with the sliders as they are then.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

logger = logging.getLogger(__name__)


class LatestOnly:
    """Runs ``work()`` on a background thread, one run at a time, after each :meth:`request`."""

    def __init__(self, work: Callable[[], object]) -> None:
        self._work = work
        self._lock = threading.Lock()
        self._idle = threading.Condition(self._lock)
        self._wanted = False
        self._running = False
        self._closed = False

    def request(self) -> None:
        """Ask for a run: one starts now if none is running, else once the running one ends."""
        with self._lock:
            if self._closed:
                return
            self._wanted = True
            if self._running:
                return
            self._running = True
        threading.Thread(target=self._loop, name="latest-only", daemon=True).start()

    @property
    def pending(self) -> bool:
        """Whether a run was asked for since the one now running started (that run's result
        is already stale)."""
        with self._lock:
            return self._wanted

    def _loop(self) -> None:
        while True:
            with self._lock:
                if not self._wanted or self._closed:
                    self._running = False
                    self._idle.notify_all()
                    return
                self._wanted = False
            try:
                self._work()
            except Exception:  # logged: one failed run must not stop the runs asked after it
                logger.exception("a background run failed")

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Wait until nothing runs or is asked for; False if ``timeout_s`` passed first."""
        with self._lock:
            return self._idle.wait_for(lambda: not self._running, timeout_s)

    def close(self) -> None:
        """Run nothing more (a run in progress ends as it would)."""
        with self._lock:
            self._closed = True
