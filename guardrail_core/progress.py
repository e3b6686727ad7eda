"""Progress bars on a terminal only.

A bar is redrawn with carriage returns many times a second: on a terminal it is one line, in a
log or a pipe it is thousands. Every bar of the project comes from :func:`progress_bar`, which
draws nothing unless asked for and its stream (stderr by default) is a terminal; the summary
lines the commands print are plain ``print`` and stay.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any

from tqdm import tqdm


def progress_bar(
    iterable: Iterable[Any] | None = None, *, enabled: bool = True, **kwargs: Any
) -> Any:
    """A :class:`tqdm.tqdm` over ``iterable`` (or a manual one, with ``total=``), disabled
    unless ``enabled`` and its stream (``file=``, default stderr) is a terminal.

    A disabled bar still iterates, takes updates and works as a context manager; it draws nothing.
    """
    stream = kwargs.get("file") or sys.stderr  # looked up now: tests and tools replace stderr
    return tqdm(iterable, disable=not (enabled and is_terminal(stream)), **kwargs)


def is_terminal(stream: Any) -> bool:
    """Whether ``stream`` is an open terminal (False for files, pipes, closed or odd streams)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed file
        return False
