"""Options several commands share, as argparse parent parsers, and their helpers.

A command lists its parents after its own options: argparse puts a parent's options before
the parser's own, so a command keeps the shared ones last by giving its own as the first parent.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from guardrail_core.extract.pipeline import ExtractionParams
    from guardrail_core.formats.run_info import ReconstructionSummary
    from guardrail_core.reconstruct.pipeline import ReconstructionParams

# What `add_parser` receives: the sub-parsers of `guardrail` or of `guardrail import`.
Subparsers = argparse._SubParsersAction  # argparse has no public name for it


class HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, with each option's default appended to its help where the help
    does not state it already.

    argparse's own ArgumentDefaultsHelpFormatter appends to every option: "(default: None)" on
    options that have none, "(default: False)" on flags, and a second default where the help
    gives one in its own words. This one appends only a default worth reading.
    """

    def _get_help_string(self, action: argparse.Action) -> str | None:
        help_text, default = action.help or "", action.default
        if (
            not action.option_strings  # a positional's default is its absence
            or default is None
            or default is argparse.SUPPRESS
            or isinstance(default, bool)  # a flag
            or (isinstance(default, (str, list, tuple)) and not default)
            or "default" in help_text.lower()
        ):
            return action.help
        shown = f"{default:g}" if isinstance(default, float) else str(default)
        # argparse %-formats the help: a literal % in the value must be doubled.
        return f"{help_text} (default: {shown.replace('%', '%%')})"


class ArgumentParser(argparse.ArgumentParser):
    """The parser of ``guardrail`` and, through ``add_subparsers``, of every sub-command: each
    formats its help with :class:`HelpFormatter`."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)


def options_parser() -> argparse.ArgumentParser:
    """An empty parent parser (no -h of its own) to add a command's options to."""
    return argparse.ArgumentParser(add_help=False)


def quiet_options() -> argparse.ArgumentParser:
    parser = options_parser()
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    return parser


def overwrite_options(help_text: str = "replace OUT if it exists") -> argparse.ArgumentParser:
    parser = options_parser()
    parser.add_argument("--overwrite", action="store_true", help=help_text)
    return parser


def las_options() -> argparse.ArgumentParser:
    """``--las`` of the commands that write a drive folder."""
    parser = options_parser()
    parser.add_argument(
        "--las", action="store_true", help="write the point tiles uncompressed (.las, not .laz)"
    )
    return parser


def reconstruction_options() -> argparse.ArgumentParser:
    """``--params`` and ``--set``; `reconstruction_params` turns them into parameters."""
    parser = options_parser()
    parser.add_argument(
        "--params",
        type=Path,
        metavar="JSON",
        help="reconstruction parameters: a JSON object {stage: {name: value}} (or a "
        "reconstruction/models.json, whose parameters are used)",
    )
    parser.add_argument(
        "--set",
        action="append",
        metavar="STAGE.NAME=VALUE",
        help="one reconstruction parameter, e.g. pipes.slice_interval_m=0.02 (repeatable)",
    )
    return parser


def reconstruction_params(args: argparse.Namespace) -> ReconstructionParams:
    """The defaults, replaced by the file of ``--params``, then by each ``--set``."""
    import json

    from guardrail_core.errors import InvalidOptionError
    from guardrail_core.reconstruct.pipeline import ReconstructionParams

    params = ReconstructionParams()
    if getattr(args, "params", None):
        try:
            data = json.loads(Path(args.params).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise InvalidOptionError(f"--params {args.params}: cannot read it ({exc})") from exc
        params = ReconstructionParams.from_json(data.get("params", data))
    return params.with_settings(getattr(args, "set", None) or [])


def process_params(settings: list[str]) -> tuple[ExtractionParams, ReconstructionParams]:
    """The extraction and reconstruction parameters of ``guardrail process --set``: each
    ``STAGE.NAME=VALUE`` goes to the parameters that have that stage.

    Raises :class:`~guardrail_core.params.ParameterError` for a setting of no stage of either.
    """
    from guardrail_core.extract.pipeline import ExtractionParams
    from guardrail_core.params import ParameterError
    from guardrail_core.reconstruct.pipeline import ReconstructionParams

    extraction_stages = [f.name for f in dataclasses.fields(ExtractionParams)]
    reconstruction_stages = list(ReconstructionParams.stage_classes())
    chosen: dict[str, list[str]] = {"extraction": [], "reconstruction": []}
    for setting in settings:
        stage = setting.partition("=")[0].partition(".")[0].strip()
        if stage in extraction_stages:
            chosen["extraction"].append(setting)
        elif stage in reconstruction_stages:
            chosen["reconstruction"].append(setting)
        else:
            raise ParameterError(
                f"unknown stage {stage!r} in {setting!r} (extraction: "
                f"{', '.join(extraction_stages)}; reconstruction: "
                f"{', '.join(reconstruction_stages)})"
            )
    return (
        ExtractionParams().with_settings(chosen["extraction"]),
        ReconstructionParams().with_settings(chosen["reconstruction"]),
    )


def reconstruction_summary(summary: ReconstructionSummary) -> str:
    """One line on a reconstruction, as `process` and `reconstruct` print it."""
    return (
        f"guardrail runs: {summary.runs} ({summary.reconstructed} reconstructed, "
        f"{summary.poles_only} poles only, {summary.not_reconstructed} not reconstructed) "
        f"in {summary.seconds or 0.0:.1f} s"
    )


def image_size(text: str) -> tuple[int, int]:
    """The argparse type of WIDTHxHEIGHT, each side 64..8192 pixels."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT, e.g. 1024x768, got {text!r}"
        ) from exc
    if not (64 <= width <= 8192 and 64 <= height <= 8192):
        raise argparse.ArgumentTypeError("image sides must lie within 64..8192 pixels")
    return width, height
