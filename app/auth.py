"""The API token: checked on every API call when the server was started with ``--token``."""

from __future__ import annotations

import ipaddress
import secrets

from fastapi import HTTPException, Request, status

#: The environment variable ``guardrail serve`` reads its token from (kept off the command line,
#: which every user of the machine sees in ``ps``).
TOKEN_ENV = "GUARDRAIL_TOKEN"


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or an address) only reaches this machine."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def require_token(request: Request) -> None:
    """FastAPI dependency: 401 unless the request carries the server's token.

    The token comes as ``Authorization: Bearer <token>`` or, for image and download links that
    cannot set headers, as a ``token`` query parameter.
    """
    expected: str | None = request.app.state.token
    if expected is None:
        return
    given = request.query_params.get("token", "")
    header = request.headers.get("authorization", "")
    if header.lower().startswith("bearer "):
        given = header[7:].strip()
    if not secrets.compare_digest(given.encode(), expected.encode()):
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            detail="this server needs its token: Authorization: Bearer <token> or ?token=",
        )
