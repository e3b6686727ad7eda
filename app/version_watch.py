"""A version number that changes from any thread and that a request can wait on.

The 3D scene changes the selection from viser's threads; the page asks the server with a
long poll (``GET /api/selection?after=N``) that answers as soon as the version passes ``N``.
The request waits on an :class:`asyncio.Event` of its own loop, set with
``call_soon_threadsafe``: no worker thread is held while it waits, and nothing is polled.
"""

from __future__ import annotations

import asyncio
import threading


class VersionWatch:
    """A counter bumped on every change; :meth:`wait_past` waits until it moves."""

    def __init__(self) -> None:
        self.version = 0
        self._lock = threading.Lock()
        self._waiters: set[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = set()

    def bump(self) -> int:
        """Count a change and wake every waiter; returns the new version. Any thread."""
        with self._lock:
            self.version += 1
            waiters = list(self._waiters)
        for loop, event in waiters:
            try:
                loop.call_soon_threadsafe(event.set)
            except RuntimeError:  # that request's loop has closed: nobody waits there
                pass
        return self.version

    async def wait_past(self, version: int, timeout_s: float) -> int:
        """Wait until the version differs from ``version``, at most ``timeout_s`` seconds;
        returns the version then (``version`` itself when the time ran out)."""
        event = asyncio.Event()
        waiter = (asyncio.get_running_loop(), event)
        with self._lock:
            if self.version != version:
                return self.version
            self._waiters.add(waiter)
        try:
            await asyncio.wait_for(event.wait(), timeout_s)
        except TimeoutError:
            pass
        finally:
            with self._lock:
                self._waiters.discard(waiter)
        return self.version
