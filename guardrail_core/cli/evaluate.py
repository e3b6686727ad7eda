"""``guardrail evaluate``: compare a run with the drive's truth (Tables 1 and 2, the units sweep)."""

from __future__ import annotations

import argparse
from pathlib import Path

from guardrail_core.cli import common


def add_parser(subparsers: common.Subparsers) -> None:
    own = common.options_parser()
    own.add_argument(
        "drive",
        type=Path,
        metavar="DRIVE",
        help="the drive folder, with its truth (a simulated drive)",
    )
    own.add_argument("--run", type=Path, required=True, help="run folder (guardrail process)")
    own.add_argument("--json", action="store_true", help="print one JSON object instead")
    own.add_argument(
        "--units-sweep",
        metavar="K,...",
        help="also reconstruct every run from only its first K units, for each K, and report "
        "the pipes found per design (the experiment of §5.2), e.g. 1,2,4,8,16,32",
    )
    own.add_argument(
        "--plot",
        type=Path,
        help="PNG of the units sweep (default RUN/units_sweep.png)",
    )
    parser = subparsers.add_parser(
        "evaluate",
        help="compare a run with the drive's truth",
        description="Print the paper's Table 1 (segments per class) and Table 2 (recall, "
        "precision, F-measure per class) before and after label correction.",
        parents=[own, common.reconstruction_options(), common.quiet_options()],
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json

    from guardrail_core.evaluate.detection import evaluate_run_folder, format_report
    from guardrail_core.formats.drive import load_drive
    from guardrail_core.formats.run_folder import load_run

    # Tile by tile: a survey's drive never whole in memory.
    result = evaluate_run_folder(args.drive, args.run)
    sweep = None
    if args.units_sweep:
        drive, run_folder = load_drive(args.drive), load_run(args.run)
        from guardrail_core.evaluate.units_sweep import (
            format_units_sweep,
            parse_units,
            plot_units_sweep,
            units_sweep,
        )

        units = parse_units(args.units_sweep)
        sweep = units_sweep(
            drive,
            run_folder,
            units,
            params=common.reconstruction_params(args),
            progress=not args.quiet,
        )
        plot = plot_units_sweep(sweep, args.plot or Path(args.run) / "units_sweep.png")
    if args.json:
        document = result.to_json()
        if sweep is not None:
            document["units_sweep"] = {**sweep.to_json(), "plot": str(plot)}
        print(json.dumps(document, indent=2))
    else:
        print(format_report(result))
        if sweep is not None:
            print()
            print(format_units_sweep(sweep))
            print(f"plot: {plot}")
    return 0
