"""The command-line reference, written from the real ``guardrail`` parser.

Why not sphinx-argparse's directive: it reflows epilogs (their example command lines run into
one paragraph), shows ``Default: False`` for every flag and a second default beside the one the
help states, and leaves ``--option`` in prose to smart quotes (an en dash). Here each command is a
section: description, usage, one table per argument group, and the epilog as preformatted text.
"""

from __future__ import annotations

import argparse
import textwrap
from collections.abc import Iterator

from guardrail_reference_markdown import code, fenced, heading, join, prose, table

#: Columns the usage lines wrap at (argparse's own default follows the terminal's width).
USAGE_WIDTH = 88


def subcommands(
    parser: argparse.ArgumentParser,
) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """The parser's sub-commands in ``--help`` order: (name, help, parser), aliases left out."""
    found = []
    for action in parser._actions:  # argparse has no public way to reach its sub-parsers
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            seen: set[int] = set()
            for name, child in action.choices.items():
                if id(child) not in seen:
                    seen.add(id(child))
                    found.append((name, helps.get(name, ""), child))
    return found


def walk(parser: argparse.ArgumentParser) -> Iterator[argparse.ArgumentParser]:
    """The parser and every sub-command's parser below it, depth first, in ``--help`` order."""
    yield parser
    for _, _, child in subcommands(parser):
        yield from walk(child)


def _formatter(parser: argparse.ArgumentParser) -> argparse.HelpFormatter:
    # The parser's own formatter class, at a fixed width so that the page does not depend on
    # the terminal the docs were built in.
    return parser.formatter_class(prog=parser.prog, width=USAGE_WIDTH)


def usage(parser: argparse.ArgumentParser) -> str:
    """The usage lines of ``--help``, at :data:`USAGE_WIDTH` columns."""
    formatter = _formatter(parser)
    formatter.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups)
    return formatter.format_help().strip()


def default_text(action: argparse.Action) -> str:
    """The default worth stating, as Markdown; "" for none (flags, unset options, positionals)."""
    default = action.default
    if (
        not action.option_strings
        or action.nargs == 0  # a flag, a --version, a --help
        or default is None
        or default is argparse.SUPPRESS
        or (isinstance(default, str | list | tuple) and not default)
    ):
        return ""
    if isinstance(default, float):
        return code(f"{default:g}")
    return code(str(default))  # as the project's --help states it


def help_text(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """The action's help as ``--help`` expands it (``%(default)s`` and the like), without the
    "(default: ...)" the project's formatter appends: the table has a column for it."""
    if not action.help:
        return ""
    params = dict(vars(action), prog=parser.prog)
    params = {k: getattr(v, "__name__", v) for k, v in params.items() if v is not argparse.SUPPRESS}
    if params.get("choices") is not None:
        params["choices"] = ", ".join(str(c) for c in params["choices"])
    text = prose(action.help % params)
    if action.choices is not None and action.metavar is not None:  # else the metavar lists them
        text += " (one of " + ", ".join(code(str(c)) for c in action.choices) + ")"
    if action.required and action.option_strings:
        text = "**Required.** " + text
    return text


def _argument(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """How the argument is written: ``--tile-m METRES``, ``-h, --help``, ``DRIVE``."""
    formatter = _formatter(parser)
    if not action.option_strings:
        return code(formatter._format_args(action, action.dest))
    metavar = ""
    if action.nargs != 0:
        metavar = " " + formatter._format_args(
            action, formatter._get_default_metavar_for_optional(action)
        )
    return ", ".join(code(option + metavar) for option in action.option_strings)


def _group_tables(parser: argparse.ArgumentParser) -> Iterator[str]:
    """A table per argument group (positionals, options, and the groups a command names)."""
    for group in parser._action_groups:
        actions = [
            a
            for a in group._group_actions
            if a.help is not argparse.SUPPRESS
            and not isinstance(a, argparse._SubParsersAction | argparse._HelpAction)
        ]
        if not actions:
            continue
        title = (group.title or "arguments").capitalize()
        description = f" {prose(group.description)}" if group.description else ""
        yield f"**{prose(title)}**{description}\n"
        if all(not a.option_strings for a in actions):
            yield table(
                ["Argument", "Meaning"],
                [[_argument(parser, a), help_text(parser, a)] for a in actions],
            )
        else:
            rows = [[_argument(parser, a), default_text(a), help_text(parser, a)] for a in actions]
            yield table(["Option", "Default", "Meaning"], rows)


def _is_raw(parser: argparse.ArgumentParser) -> bool:
    return issubclass(parser.formatter_class, argparse.RawDescriptionHelpFormatter)


def command_section(parser: argparse.ArgumentParser, level: int) -> str:
    """One command's section: heading, description, usage, its arguments, sub-commands, epilog."""
    blocks = [heading(level, parser.prog, label="cli-" + parser.prog.replace(" ", "-"))]
    if parser.description:
        raw = _is_raw(parser)
        blocks.append(
            fenced(textwrap.dedent(parser.description)) if raw else prose(parser.description)
        )
    blocks.append(fenced(usage(parser)))
    blocks.extend(_group_tables(parser))
    children = subcommands(parser)
    if children:
        blocks.append("**Sub-commands**\n")
        rows = [
            [f"{{ref}}`{name} <cli-{child.prog.replace(' ', '-')}>`", prose(text)]
            for name, text, child in children
        ]
        blocks.append(table(["Command", "What it does"], rows))
    if parser.epilog:
        # Epilogs hold example command lines: kept line for line, as the terminal shows them
        # (a one-line epilog of prose stays prose).
        epilog = textwrap.dedent(parser.epilog).strip("\n")
        preformatted = _is_raw(parser) or "\n" in epilog or "guardrail " in epilog
        blocks.append(fenced(epilog) if preformatted else prose(epilog))
    return join(blocks)


def cli_reference(parser: argparse.ArgumentParser | None = None, level: int = 2) -> str:
    """The Markdown of every command and sub-command of ``parser`` (default: ``guardrail``'s,
    with the commands other packages plug in, such as the review app's ``serve``)."""
    if parser is None:
        from guardrail_core.cli import build_parser

        parser = build_parser()
    sections = []
    for command in walk(parser):
        depth = command.prog.count(" ")
        # `guardrail` and its commands side by side, `guardrail import las` one level below.
        sections.append(command_section(command, level + max(depth - 1, 0)))
    return join(sections)
