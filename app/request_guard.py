"""What the REST API accepts before any route runs: requests addressed to this server, state
changes from its own pages only, and JSON bodies of bounded size.

- **Host**: a page on another site whose name resolves to this machine (DNS rebinding) sends its
  own name as ``Host``; only the names the server serves are answered (400 otherwise).
- **Origin**: a request that changes state (POST, PUT, PATCH, DELETE) and carries an ``Origin``
  other than the server's own is refused (403): a page of another site cannot relabel, train or
  activate a model through the operator's browser. Clients that are not browsers send no
  ``Origin`` and pass (the token, when the server has one, still applies).
- **JSON only**: such a request must say ``Content-Type: application/json``, or carry neither a
  body nor a type (415 otherwise). An HTML form always names its encoding (form or text), so a
  cross-site form fails even where a browser leaves ``Origin`` out.
- **Size**: a body over :data:`MAX_BODY_BYTES` is refused with 413, by its ``Content-Length``
  before it is read, or as it streams in.
"""

from __future__ import annotations

import socket
from collections.abc import Collection

from starlette.datastructures import Headers
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

#: The largest request body, bytes: a batch of 100,000 segment ids is about 1 MB.
MAX_BODY_BYTES = 4 * 1024 * 1024
#: Methods that change state.
UNSAFE_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
#: Names of this machine that need no ``--host`` to be answered.
LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})


class RequestGuard:
    """ASGI middleware in front of the app: the checks of this module's docstring.

    Parameters
    ----------
    app : the application
    allowed_hosts : the host names (without port) requests may address; None answers any
        (for tests that use another name)
    max_body_bytes : the body size limit
    """

    def __init__(
        self,
        app: ASGIApp,
        *,
        allowed_hosts: Collection[str] | None = None,
        max_body_bytes: int = MAX_BODY_BYTES,
    ) -> None:
        self.app = app
        self.allowed_hosts = None if allowed_hosts is None else {h.lower() for h in allowed_hosts}
        self.max_body_bytes = max_body_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        host = headers.get("host", "")
        refusal = self._refusal(scope["method"], host, headers)
        if refusal is not None:
            await JSONResponse({"detail": refusal[1]}, status_code=refusal[0])(scope, receive, send)
            return
        if scope["method"] not in UNSAFE_METHODS:
            await self.app(scope, receive, send)
            return
        await self._bounded(scope, receive, send)

    def _refusal(self, method: str, host: str, headers: Headers) -> tuple[int, str] | None:
        """(status, reason) for a request refused before it reaches the app, else None."""
        if self.allowed_hosts is not None and host_name(host) not in self.allowed_hosts:
            return 400, f"this server does not answer for the host {host[:100]!r}"
        if method not in UNSAFE_METHODS:
            return None
        origin = headers.get("origin")
        if origin is not None and origin_netloc(origin) != host.lower():
            return 403, f"a request from another origin ({origin[:100]!r}) may not change anything"
        media_type = headers.get("content-type", "").split(";")[0].strip().lower()
        bodyless = headers.get("content-length", "0") == "0" and "transfer-encoding" not in headers
        # A form always names its encoding: only JSON, or nothing at all (no body, no type), passes.
        if media_type != "application/json" and not (media_type == "" and bodyless):
            return 415, "a request that changes something must send Content-Type: application/json"
        length = headers.get("content-length")
        if length is not None and (not length.isdigit() or int(length) > self.max_body_bytes):
            return 413, f"the body is over the limit of {self.max_body_bytes} bytes"
        return None

    async def _bounded(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Read the body (at most the limit; 413 past it), then run the app on it."""
        chunks: list[bytes] = []
        size = 0
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                return
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.max_body_bytes:
                detail = {"detail": f"the body is over the limit of {self.max_body_bytes} bytes"}
                await JSONResponse(detail, status_code=413)(scope, receive, send)
                return
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        replayed = False

        async def replay() -> Message:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": b"".join(chunks), "more_body": False}
            return await receive()  # after the body: the client's disconnect

        await self.app(scope, replay, send)


def host_name(host: str) -> str:
    """The name of a ``Host`` header without its port, lower case (``[::1]:8000`` -> ``::1``)."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def origin_netloc(origin: str) -> str:
    """``host[:port]`` of an ``Origin`` header, lower case; ``""`` for ``null`` or garbage."""
    scheme, sep, rest = origin.strip().lower().partition("://")
    if not sep or scheme not in ("http", "https"):
        return ""
    return rest.split("/", 1)[0]


def allowed_hosts_for(bind_host: str, extra: Collection[str] = ()) -> set[str]:
    """The host names a server bound to ``bind_host`` answers: the loopback names, the bound
    address, ``extra`` (names it is reached by through a proxy or DNS), and for a wildcard bind
    (``0.0.0.0``, ``::``) this machine's name and addresses."""
    names = {*LOOPBACK_NAMES, bind_host.lower(), *(h.lower() for h in extra)}
    if bind_host in ("0.0.0.0", "::", ""):
        machine = socket.gethostname()
        names |= {machine.lower(), socket.getfqdn(machine).lower()}
        try:
            names |= {str(info[4][0]).lower() for info in socket.getaddrinfo(machine, None)}
        except OSError:  # a name that does not resolve: the loopback and the name remain
            pass
    return names
