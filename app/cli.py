"""The ``guardrail serve`` command, plugged into the ``guardrail`` CLI through the
``guardrail.commands`` entry point (the library's CLI never imports the app)."""

from __future__ import annotations

import argparse
import getpass
import os
from pathlib import Path


def add_serve_command(sub: argparse._SubParsersAction) -> None:
    """Add ``serve`` to the ``guardrail`` command's subcommands."""
    serve = sub.add_parser(
        "serve",
        help="review a run in the browser: 3D scene, labels, fine-tuning, thresholds",
        description="Serve the review app: a FastAPI server (REST API, OpenAPI at /docs, the "
        "pages) and a viser 3D scene on the next port. Labels are kept per point in "
        "DRIVE/review/labels.sqlite with their history.",
    )
    serve.add_argument("drive", type=Path, metavar="DRIVE", help="drive folder to review")
    serve.add_argument(
        "--run", type=Path, metavar="RUN_DIR", help="the run folder (default: DRIVE/../run)"
    )
    serve.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    serve.add_argument("--port", type=int, default=8000, help="the app's port (default 8000)")
    serve.add_argument(
        "--scene-port", type=int, help="the 3D scene's port (default: the app's port + 1)"
    )
    serve.add_argument(
        "--token",
        help="secret every API call must carry; required beyond 127.0.0.1. Visible to every "
        "user of the machine (ps): prefer --token-file or $GUARDRAIL_TOKEN",
    )
    serve.add_argument(
        "--token-file", type=Path, metavar="FILE", help="read the token from FILE's first line"
    )
    serve.add_argument(
        "--allowed-host",
        action="append",
        default=[],
        metavar="NAME",
        help="a further host name browsers reach the app by (a proxy's, a DNS name); the "
        "loopback, the --host address and, for 0.0.0.0, this machine's names are answered "
        "already (repeatable)",
    )
    serve.add_argument(
        "--operator", default=None, help="name recorded with labels (default: your user name)"
    )
    serve.add_argument(
        "--model", type=Path, help="the model folder that made the run (to re-activate it)"
    )
    serve.add_argument(
        "--review-dir",
        type=Path,
        help="where labels and fine-tuned models are kept (default: DRIVE/review)",
    )
    serve.add_argument(
        "--window", type=float, default=100.0, help="metres of drive in the 3D scene"
    )
    serve.add_argument(
        "--point-budget", type=int, default=400_000, help="most points in the 3D scene"
    )
    serve.set_defaults(func=_serve)


def _serve(args: argparse.Namespace) -> int:
    from app.serve import serve, token_from  # viser and uvicorn load only when serving

    serve(
        args.drive,
        args.run,
        host=args.host,
        allowed_hosts=args.allowed_host,
        port=args.port,
        scene_port=args.scene_port,
        token=token_from(args.token, args.token_file, os.environ),
        operator=args.operator or getpass.getuser(),
        model_dir=args.model,
        review_dir=args.review_dir,
        window_m=args.window,
        point_budget=args.point_budget,
    )
    return 0
