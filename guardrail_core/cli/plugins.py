"""Commands other packages add under the ``guardrail.commands`` entry points.

The review app's ``serve`` comes in this way: the library never imports the app, the app
plugs into the CLI.
"""

from __future__ import annotations

from guardrail_core.cli import common


def add_plugin_commands(subparsers: common.Subparsers) -> None:
    from importlib.metadata import entry_points

    for entry in sorted(entry_points(group="guardrail.commands"), key=lambda e: e.name):
        entry.load()(subparsers)
