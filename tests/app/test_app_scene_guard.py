"""The 3D scene's websocket refuses what the REST API refuses: another site's page, another host
name, and (with a token) a client without it; the scene's own page connects."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import pytest
import viser
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from app.request_guard import allowed_hosts_for
from app.scene.guarded_server import guarded_viser_server, handshake_refusal

SUBPROTOCOL = f"viser-v{viser.__version__}"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture()
def scene_port() -> Iterator[int]:
    port = _free_port()
    server = guarded_viser_server(
        "127.0.0.1", port, allowed_hosts=allowed_hosts_for("127.0.0.1"), token="s3cret"
    )
    try:
        yield server.get_port()
    finally:
        server.stop()


def _status(port: int, path: str = "/", **headers: str) -> int:
    """101 when the handshake succeeds, else the HTTP status it was refused with."""
    try:
        with connect(
            f"ws://127.0.0.1:{port}{path}",
            subprotocols=[SUBPROTOCOL],  # type: ignore[list-item]
            additional_headers=headers,
            origin=None,
            open_timeout=10,
        ):
            return 101
    except InvalidStatus as exc:
        return exc.response.status_code


def _raw_status(port: int, host: str) -> int:
    """The status of a handshake sent by hand with this Host header (a client library sets its
    own)."""
    request = (
        f"GET /?token=s3cret HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\n"
        "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
        f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {SUBPROTOCOL}\r\n\r\n"
    )
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(request.encode())
        status_line = s.makefile("rb").readline().decode()
    return int(status_line.split()[1])


def test_the_scene_refuses_foreign_pages_hosts_and_tokenless_clients(scene_port: int) -> None:
    own = f"http://127.0.0.1:{scene_port}"
    assert _status(scene_port, "/?token=s3cret", Origin=own) == 101
    assert _status(scene_port, "/?token=s3cret") == 101  # not a browser: no Origin
    assert _status(scene_port, "/?token=s3cret", Origin="http://evil.example") == 403
    assert _status(scene_port, "/?token=wrong", Origin=own) == 403
    assert _status(scene_port, "/", Origin=own) == 403
    assert _raw_status(scene_port, "evil.example") == 403  # DNS rebinding
    assert _raw_status(scene_port, f"127.0.0.1:{scene_port}") == 101


def test_handshake_rules() -> None:
    hosts = {"127.0.0.1", "localhost"}
    ok = {"Host": "127.0.0.1:8001", "Origin": "http://127.0.0.1:8001"}
    assert handshake_refusal(ok, "/", hosts, None) is None
    assert "another origin" in (handshake_refusal({**ok, "Origin": "null"}, "/", hosts, None) or "")
    assert "host" in (
        handshake_refusal({**ok, "Host": "evil.example:8001"}, "/", hosts, None) or ""
    )
    assert "token" in (handshake_refusal(ok, "/?token=", hosts, "t") or "")
    assert handshake_refusal(ok, "/?token=t", hosts, "t") is None
