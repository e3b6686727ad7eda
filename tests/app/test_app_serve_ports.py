"""``guardrail serve`` with its ports taken: the page embeds the port the 3D scene took, and a
taken app port is named before any URL is printed."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import viser
from fastapi.testclient import TestClient
from websockets.sync.client import connect

from app.serve import PortInUseError, bind_app_port, start_review
from guardrail_core.cli import main
from guardrail_core.errors import InvalidOptionError
from tests.app_fixtures import copy_run


@contextmanager
def _other_server() -> Iterator[int]:
    """A port another program listens on (a plain socket, the system's choice of port)."""
    with socket.socket() as other:
        other.bind(("127.0.0.1", 0))
        other.listen()
        yield int(other.getsockname()[1])


def _scene_handshake(port: int) -> int:
    """101 when a viser client's websocket handshake on ``port`` succeeds."""
    with connect(
        f"ws://127.0.0.1:{port}/",
        subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
        origin=None,
        open_timeout=10,
    ) as ws:
        assert ws.response is not None
        return ws.response.status_code


def test_the_page_embeds_the_port_the_scene_took_when_its_own_is_taken(
    drive_path: Path, run_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with _other_server() as taken:
        servers = start_review(
            drive_path,
            copy_run(run_path, tmp_path),
            port=0,
            scene_port=taken,
            review_dir=tmp_path / "review",
            operator="tester",
        )
        try:
            scene_port = servers.scene.get_port()
            assert scene_port != taken
            assert _scene_handshake(scene_port) == 101  # viser listens there
            out = capsys.readouterr().out
            assert f"3D scene:   http://127.0.0.1:{scene_port}\n" in out
            assert f"review app: http://127.0.0.1:{servers.port}/\n" in out
            with TestClient(servers.app, base_url="http://127.0.0.1") as client:
                info = client.get("/api/info")
            assert info.status_code == 200
            assert info.json()["scene_url"] == f"http://127.0.0.1:{scene_port}"
        finally:
            servers.close()


def test_a_taken_app_port_is_named_before_anything_is_printed(
    drive_path: Path, run_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    review = tmp_path / "review"
    with _other_server() as taken:
        with pytest.raises(PortInUseError, match=f"port {taken} .*--port"):
            bind_app_port("127.0.0.1", taken)
        command = ["serve", str(drive_path), "--run", str(run_path), "--port", str(taken)]
        assert main([*command, "--review-dir", str(review)]) == 2
    out, err = capsys.readouterr()
    assert out == ""  # no URL, not even the loading line
    assert err == (
        f"guardrail: error: PortInUseError: port {taken} on 127.0.0.1 is in use by another "
        "server; choose another with --port\n"
    )
    assert not review.exists()  # the session was never opened


def test_a_port_out_of_range_is_refused() -> None:
    with pytest.raises(InvalidOptionError, match="--port: expected 0 to 65535"):
        bind_app_port("127.0.0.1", 70_000)
