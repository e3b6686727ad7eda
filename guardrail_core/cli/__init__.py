"""The ``guardrail`` command line: one module per sub-command, shared options in `common`."""

from __future__ import annotations

import argparse
import sys

from guardrail_core.cli import (
    demo,
    evaluate,
    export,
    imports,
    info,
    process,
    reconstruct,
    simulate,
    train,
)
from guardrail_core.cli.plugins import add_plugin_commands
from guardrail_core.errors import GuardrailError

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="guardrail",
        description="Find, reconstruct and review guardrails in mobile-mapping point clouds and images.",
    )
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    # The order of `guardrail --help`.
    for command in (simulate, info, train, process, evaluate, reconstruct, imports, export):
        command.add_parser(subparsers)
    add_plugin_commands(subparsers)
    demo.add_parser(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except GuardrailError as exc:
        print(f"guardrail: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("guardrail: interrupted; nothing half-written was kept", file=sys.stderr)
        return 130
