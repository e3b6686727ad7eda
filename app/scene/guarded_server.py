"""The 3D scene's viser server, with its websocket guarded as the REST API is.

viser accepts a websocket from any page: a page of another site the operator visits could
connect, move the shared selection and press the scene's buttons under the operator's name.
viser offers no hook for the handshake, so the server is started with the websockets library's
``process_request`` wrapped (only while viser starts it): before viser's own handling, a
websocket handshake is refused (403) when its ``Host`` is not a name the server answers, its
``Origin`` is another site's (browsers always send it; the scene's own page has the scene's
origin), or, when the server has a token, its URL lacks ``?token=`` with it (the review page
hands the scene its websocket URL with the token: ``?websocket=ws://HOST:PORT/?token=...``).
The scene's static files stay readable, like the review app's pages.
"""

from __future__ import annotations

import functools
import http
import secrets
import threading
from collections.abc import Callable, Collection, Iterator
from contextlib import contextmanager
from typing import Any
from urllib.parse import parse_qs, urlsplit

import viser

from app.request_guard import host_name, origin_netloc

#: viser starts one server at a time through the patched function.
_START_LOCK = threading.Lock()


def guarded_viser_server(
    host: str, port: int, *, allowed_hosts: Collection[str] | None, token: str | None
) -> viser.ViserServer:
    """A :class:`viser.ViserServer` on ``host:port`` whose websocket handshakes pass
    :func:`handshake_refusal` first."""
    hosts = None if allowed_hosts is None else {h.lower() for h in allowed_hosts}
    check = functools.partial(handshake_refusal, allowed_hosts=hosts, token=token)
    with _START_LOCK, _wrapped_process_request(check):
        return viser.ViserServer(host=host, port=port, verbose=False)


def handshake_refusal(
    headers: Any, path: str, allowed_hosts: Collection[str] | None, token: str | None
) -> str | None:
    """Why a websocket handshake (its headers, its request path with the query) is refused, or
    None to let it through."""
    hosts, origins = _all(headers, "Host"), _all(headers, "Origin")
    if len(hosts) != 1 or len(origins) > 1:
        return "a handshake needs one Host header and at most one Origin"
    host = hosts[0]
    if allowed_hosts is not None and host_name(host) not in allowed_hosts:
        return f"this server does not answer for the host {host[:100]!r}"
    origin = origins[0] if origins else None
    if origin is not None and origin_netloc(str(origin)) != host.lower():
        return f"a page of another origin ({str(origin)[:100]!r}) may not open the scene"
    if token is not None:
        given = parse_qs(urlsplit(path).query).get("token", [""])[0]
        if not secrets.compare_digest(given.encode(), token.encode()):
            return "the scene needs the server's token (?token= in its websocket URL)"
    return None


def _all(headers: Any, name: str) -> list[str]:
    """Every value of a header (websockets' Headers, or a plain mapping in tests)."""
    if hasattr(headers, "get_all"):
        return [str(v) for v in headers.get_all(name)]
    value = headers.get(name)
    return [] if value is None else [str(value)]


@contextmanager
def _wrapped_process_request(check: Callable[[Any, str], str | None]) -> Iterator[None]:
    import websockets.asyncio.server as ws_server

    original = ws_server.serve

    def serve(*args: Any, process_request: Any = None, **kwargs: Any) -> Any:
        def guarded(connection: Any, request: Any) -> Any:
            if str(request.headers.get("Upgrade", "")).lower() == "websocket":
                refusal = check(request.headers, request.path)
                if refusal is not None:
                    return connection.respond(http.HTTPStatus.FORBIDDEN, refusal + "\n")
                return None
            return None if process_request is None else process_request(connection, request)

        return original(*args, process_request=guarded, **kwargs)

    ws_server.serve = serve  # type: ignore[misc,assignment]
    try:
        yield
    finally:
        ws_server.serve = original  # type: ignore[misc,assignment]
