"""The ``guardrail`` command line: one module per sub-command, shared options in `common`."""

from __future__ import annotations

import argparse
import sys

from guardrail_core.cli import (
    common,
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

__all__ = ["build_parser", "main", "package_version"]


def package_version() -> str:
    """The installed distribution's version; the package's ``__version__`` where it is not
    installed (run from a source tree), else "unknown"."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("guardrail")
    except PackageNotFoundError:  # the package is imported already: this module is in it
        return str(getattr(sys.modules["guardrail_core"], "__version__", "unknown"))


def build_parser() -> argparse.ArgumentParser:
    parser = common.ArgumentParser(
        prog="guardrail",
        description="Find, reconstruct and review guardrails in mobile-mapping point clouds and images.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
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
