"""``guardrail serve``: the review app (FastAPI) and its 3D scene (viser) in one process."""

from __future__ import annotations

import errno
import secrets
import socket
from collections.abc import Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import uvicorn
import viser
from fastapi import FastAPI

from app.auth import TOKEN_ENV, is_loopback
from app.jobs import JobRunner
from app.main import create_app
from app.request_guard import allowed_hosts_for
from app.scene.guarded_server import guarded_viser_server
from app.scene.viewer import ReviewScene
from app.session import ReviewSession
from guardrail_core.errors import GuardrailError, InvalidOptionError, RunFolderError
from guardrail_core.formats.run_folder_paths import RunFolder


def default_run(drive: Path) -> Path:
    """The run folder beside the drive that ``guardrail demo`` writes (``DRIVE/../run``).

    Raises
    ------
    RunFolderError
        There is none: the caller must name the run folder.
    """
    candidate = Path(drive).resolve().parent / "run"
    if not RunFolder(candidate).exists():
        raise RunFolderError(
            f"no run folder given and none at {candidate}; process the drive with "
            "`guardrail process DRIVE --model MODEL --out RUN` and pass --run RUN"
        )
    return candidate


def new_token() -> str:
    return secrets.token_urlsafe(18)


#: The 3D scene's window along the trajectory, metres, and its point budget: every scene client
#: receives the window's points (about 15 bytes each), so both are bounded.
WINDOW_RANGE_M = (1.0, 1000.0)
POINT_BUDGET_RANGE = (1000, 2_000_000)
#: Seconds Ctrl+C waits for requests in flight (a long poll of the selection among them).
SHUTDOWN_S = 2


def check_scene_options(window_m: float, point_budget: int) -> None:
    """Raise :class:`InvalidOptionError` for a scene window or point budget out of range."""
    lo, hi = WINDOW_RANGE_M
    if not lo <= window_m <= hi:  # NaN fails too
        raise InvalidOptionError(f"--window: expected {lo:g} to {hi:g} metres, got {window_m}")
    lo_n, hi_n = POINT_BUDGET_RANGE
    if not lo_n <= point_budget <= hi_n:
        raise InvalidOptionError(
            f"--point-budget: expected {lo_n} to {hi_n} points, got {point_budget}"
        )


def token_from(flag: str | None, file: Path | None, environ: Mapping[str, str]) -> str | None:
    """The server's token: ``--token``, else the first line of ``--token-file``, else
    ``$GUARDRAIL_TOKEN``; None when none is given.

    Raises
    ------
    InvalidOptionError
        Both the flag and the file, an unreadable file, or an empty token.
    """
    if flag is not None and file is not None:
        raise InvalidOptionError("give --token or --token-file, not both")
    if file is not None:
        try:
            lines = Path(file).read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise InvalidOptionError(f"--token-file {file}: cannot read it ({exc})") from exc
        flag = lines[0].strip() if lines else ""
    token = flag if flag is not None else environ.get(TOKEN_ENV)
    if token is not None and not token.strip():
        raise InvalidOptionError("the token is empty")
    return token


class PortInUseError(GuardrailError):
    """The app's port is held by another server: nothing was started, printed or written."""


def bind_app_port(host: str, port: int) -> socket.socket:
    """The app's socket, bound to ``host:port`` before anything else starts: a taken port fails
    before a URL is printed, and the port stays the app's while the run loads.

    Raises
    ------
    PortInUseError
        Another server holds the port.
    InvalidOptionError
        A port out of range, or an address this machine cannot serve on.
    """
    if not 0 <= port <= 65535:  # getaddrinfo would wrap it round
        raise InvalidOptionError(f"--port: expected 0 to 65535, got {port}")
    try:
        family, kind, proto, _, address = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
    except socket.gaierror as exc:
        raise InvalidOptionError(f"--host {host}: not an address to serve on ({exc})") from exc
    sock = socket.socket(family, kind, proto)
    # As uvicorn binds: the port of a server just stopped (in TIME_WAIT) is free again.
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise PortInUseError(
                f"port {port} on {host} is in use by another server; choose another with --port"
            ) from exc
        raise InvalidOptionError(f"--host {host} --port {port}: cannot bind ({exc})") from exc
    return sock


@dataclass
class ReviewServers:
    """The review app, ready to serve on its bound socket, and its 3D scene, serving already.

    ``close`` stops both and closes the session.
    """

    app: FastAPI
    app_socket: socket.socket
    scene: viser.ViserServer
    session: ReviewSession
    jobs: JobRunner
    host: str

    @property
    def port(self) -> int:
        """The app's port (the one asked for, or the one the system gave for 0)."""
        return int(self.app_socket.getsockname()[1])

    def run(self) -> None:
        """Serve the app on its socket until interrupted (Ctrl+C ends it quietly)."""
        config = uvicorn.Config(
            self.app,
            host=self.host,
            port=self.port,
            log_level="warning",
            # A page's long poll of the selection may wait 20 s: Ctrl+C need not.
            timeout_graceful_shutdown=SHUTDOWN_S,
        )
        server = uvicorn.Server(config)
        try:
            server.run(sockets=[self.app_socket])
        except KeyboardInterrupt:  # uvicorn raises the signal again once it has shut down
            pass
        if not server.started:  # as uvicorn.run: a failed start (logged by uvicorn) exits 1
            raise SystemExit(1)

    def close(self) -> None:
        """Stop the jobs and the scene, close the session and the app's socket."""
        self.jobs.shutdown()
        self.scene.stop()
        self.session.close()
        self.app_socket.close()


def start_review(
    drive: Path,
    run: Path | None = None,
    *,
    host: str = "127.0.0.1",
    allowed_hosts: Sequence[str] = (),
    port: int = 8000,
    scene_port: int | None = None,
    token: str | None = None,
    operator: str = "operator",
    model_dir: Path | None = None,
    review_dir: Path | None = None,
    window_m: float = 100.0,
    point_budget: int = 400_000,
) -> ReviewServers:
    """Check the options, bind the app's port, load the session, start the 3D scene and print
    the URLs; :meth:`ReviewServers.run` then serves the app.

    Parameters
    ----------
    drive, run : the drive folder and its run folder (default: ``DRIVE/../run``)
    host : the address both servers bind to; beyond the loopback a token is required
    allowed_hosts : further host names the app answers (:func:`app.request_guard.allowed_hosts_for`)
    port : the app's port; the 3D scene takes ``scene_port`` (default ``port + 1``), or the next
        free one after it (viser moves on when it is taken: the URLs say which it took)
    token : every API call must carry it (``Authorization: Bearer`` or ``?token=``)
    operator : the name recorded with labels made in the 3D scene
    model_dir : the model folder that made the run, so it can be activated again
    review_dir : where labels and fine-tuned models are kept (default ``DRIVE/review``)
    window_m, point_budget : the 3D scene's window along the trajectory and its point budget

    Raises
    ------
    InvalidOptionError
        A host beyond the loopback without a token; a window or point budget out of range.
    PortInUseError
        The app's port is taken; raised before anything is printed or opened.
    """
    check_scene_options(window_m, point_budget)
    if not is_loopback(host) and not token:
        raise InvalidOptionError(
            f"--host {host} serves beyond this machine: give --token (any secret string) so that "
            "only those who have it can change labels"
        )
    run = run or default_run(drive)
    with ExitStack() as undo:  # a failure part way closes what was opened
        app_socket = bind_app_port(host, port)
        undo.callback(app_socket.close)
        port = int(app_socket.getsockname()[1])
        print(f"loading {drive} and {run} …", flush=True)
        session = ReviewSession(
            drive, run, review_dir=review_dir, operator=operator, model_dir=model_dir
        )
        undo.callback(session.close)
        jobs = JobRunner()
        undo.callback(jobs.shutdown)
        hosts = allowed_hosts_for(host, allowed_hosts)
        scene = guarded_viser_server(host, scene_port or port + 1, allowed_hosts=hosts, token=token)
        undo.callback(scene.stop)
        scene.gui.configure_theme(control_width="medium", show_share_button=False)
        # The panel docked beside the 3D view, not floating over it: nothing covers the selection.
        scene.gui.main_panel.dock_right()
        ReviewScene(session, scene, window_m=window_m, point_budget=point_budget, jobs=jobs)
        # viser takes the next free port when the one asked for is taken: the page embeds, and
        # the operator is shown, the port it listens on.
        scene_port = scene.get_port()
        app = create_app(
            session,
            token=token,
            jobs=jobs,
            scene_port=scene_port,
            scene_clients=lambda: len(scene.get_clients()),
            allowed_hosts=hosts,
        )
        undo.pop_all()
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    # The token is never printed whole (terminals are logged and shared).
    query = f"?token={token[:2]}… (your token)" if token else ""
    print(f"review app: http://{shown}:{port}/{query}", flush=True)
    print(f"3D scene:   http://{shown}:{scene_port}", flush=True)
    print(f"labels:     {session.store.path}", flush=True)
    return ReviewServers(app, app_socket, scene, session, jobs, host)


def serve(drive: Path, run: Path | None = None, **options: Any) -> None:
    """Serve the review app until interrupted: the servers of :func:`start_review` (which takes
    the same arguments and raises what it raises), run, then closed."""
    servers = start_review(drive, run, **options)
    try:
        servers.run()
    finally:
        servers.close()
