"""422 answers that always serialise and stay small.

FastAPI's own answer to an invalid body echoes the offending input: NaN, Infinity or 1e400 in a
field made the answer itself fail (JSON has no such numbers: a 500), and a 60 MB string came
back whole. Here the input is echoed as JSON can carry it (non-finite numbers as their names)
and cut to :data:`ECHO_CHARS` characters and :data:`ECHO_ITEMS` items.
"""

from __future__ import annotations

import math
from typing import Any

from fastapi import Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

ECHO_CHARS = 200
ECHO_ITEMS = 20


async def validation_error_response(request: Request, exc: Exception) -> JSONResponse:
    """The app's handler of :class:`RequestValidationError`."""
    assert isinstance(exc, RequestValidationError)
    return JSONResponse({"detail": [echo(error) for error in exc.errors()]}, status_code=422)


def echo(value: Any, depth: int = 0) -> Any:
    """``value`` as small, finite JSON."""
    if depth > 4:
        return "..."
    if isinstance(value, bool) or value is None or isinstance(value, int):
        return value if not isinstance(value, int) or abs(value) < 2**63 else str(value)
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if isinstance(value, str):
        if len(value) <= ECHO_CHARS:
            return value
        return f"{value[:ECHO_CHARS]}... ({len(value)} characters)"
    if isinstance(value, dict):
        items = list(value.items())
        out = {str(k)[:ECHO_CHARS]: echo(v, depth + 1) for k, v in items[:ECHO_ITEMS]}
        if len(items) > ECHO_ITEMS:
            out["..."] = f"{len(items) - ECHO_ITEMS} more"
        return out
    if isinstance(value, list | tuple):
        out_list = [echo(v, depth + 1) for v in value[:ECHO_ITEMS]]
        if len(value) > ECHO_ITEMS:
            out_list.append(f"... {len(value) - ECHO_ITEMS} more")
        return out_list
    return echo(str(value), depth + 1)
