"""``guardrail serve``: the review app (FastAPI) and its 3D scene (viser) in one process."""

from __future__ import annotations

import secrets
from collections.abc import Mapping, Sequence
from pathlib import Path

import uvicorn

from app.auth import TOKEN_ENV, is_loopback
from app.jobs import JobRunner
from app.main import create_app
from app.request_guard import allowed_hosts_for
from app.scene.guarded_server import guarded_viser_server
from app.scene.viewer import ReviewScene
from app.session import ReviewSession
from guardrail_core.errors import InvalidOptionError, RunFolderError
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


def serve(
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
) -> None:
    """Serve the review app until interrupted.

    Parameters
    ----------
    drive, run : the drive folder and its run folder (default: ``DRIVE/../run``)
    host : the address both servers bind to; beyond the loopback a token is required
    allowed_hosts : further host names the app answers (:func:`app.request_guard.allowed_hosts_for`)
    port : the app's port; the 3D scene takes ``scene_port`` (default ``port + 1``)
    token : every API call must carry it (``Authorization: Bearer`` or ``?token=``)
    operator : the name recorded with labels made in the 3D scene
    model_dir : the model folder that made the run, so it can be activated again
    review_dir : where labels and fine-tuned models are kept (default ``DRIVE/review``)
    window_m, point_budget : the 3D scene's window along the trajectory and its point budget

    Raises
    ------
    InvalidOptionError
        A host beyond the loopback without a token; a window or point budget out of range.
    """
    check_scene_options(window_m, point_budget)
    if not is_loopback(host) and not token:
        raise InvalidOptionError(
            f"--host {host} serves beyond this machine: give --token (any secret string) so that "
            "only those who have it can change labels"
        )
    run = run or default_run(drive)
    scene_port = scene_port or port + 1
    print(f"loading {drive} and {run} …", flush=True)
    session = ReviewSession(
        drive, run, review_dir=review_dir, operator=operator, model_dir=model_dir
    )
    jobs = JobRunner()
    hosts = allowed_hosts_for(host, allowed_hosts)
    server = guarded_viser_server(host, scene_port, allowed_hosts=hosts, token=token)
    server.gui.configure_theme(control_width="large", show_share_button=False)
    ReviewScene(
        session,
        server,
        window_m=window_m,
        point_budget=point_budget,
        jobs=jobs,
    )
    app = create_app(
        session,
        token=token,
        jobs=jobs,
        scene_port=scene_port,
        scene_clients=lambda: len(server.get_clients()),
        allowed_hosts=hosts,
    )
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    # The token is never printed whole (terminals are logged and shared).
    query = f"?token={token[:2]}… (your token)" if token else ""
    print(f"review app: http://{shown}:{port}/{query}", flush=True)
    print(f"3D scene:   http://{shown}:{scene_port}", flush=True)
    print(f"labels:     {session.store.path}", flush=True)
    try:
        uvicorn.run(app, host=host, port=port, log_level="warning")
    finally:
        jobs.shutdown()
        server.stop()
        session.close()
