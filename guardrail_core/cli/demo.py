"""``guardrail demo``: simulate the sample drive, train a fast model on it, process and evaluate."""

from __future__ import annotations

import argparse
from pathlib import Path

from guardrail_core.cli import common

DEMO_SCENE = "sample"


def add_parser(subparsers: common.Subparsers) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="simulate the sample drive, train on it and process it",
        description="The end-to-end demo: simulate the sample drive "
        "(data_samples/scenes/sample.yaml) into --out, train a fast model on it (model/ beside "
        "it), process it (run/ beside it) and evaluate the run.",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("demo_output/sample_drive"),
        help="drive folder to simulate into; model/ and run/ go beside it",
    )
    parser.add_argument(
        "--fresh", action="store_true", help="simulate again even if the drive exists"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from guardrail_core.formats.drive import load_drive, open_drive
    from guardrail_core.formats.drive_summary import describe_drive
    from guardrail_core.synth.scene import load_scene_spec
    from guardrail_core.synth.simulate import simulate_drive

    out = Path(args.out)
    if (out / "drive.json").is_file() and not args.fresh:
        print(f"the sample drive is already there (--fresh to simulate it again): {out}")
    else:
        simulate_drive(
            load_scene_spec(DEMO_SCENE), out, seed=7, overwrite=True, progress=not args.quiet
        )
        print(f"simulated the sample drive into {out}")
    print(describe_drive(open_drive(out)))

    from guardrail_core.cli.train import held_out_report
    from guardrail_core.evaluate.detection import evaluate_run, format_report
    from guardrail_core.extract.classify.crop_classifier_params import ClassifierParams
    from guardrail_core.extract.classify.model_folder import save_model
    from guardrail_core.extract.classify.model_training import train_from_drives
    from guardrail_core.formats.drive import drive_parts
    from guardrail_core.formats.run_folder import load_run
    from guardrail_core.process import process_drive

    model_dir, run_dir = out.parent / "model", out.parent / "run"
    print(f"\ntraining a fast model on the sample drive's truth into {model_dir}")
    model = train_from_drives([out], params=ClassifierParams(mode="fast"), progress=not args.quiet)
    save_model(model, model_dir, overwrite=True, inputs=drive_parts(out))
    print(held_out_report(model.info))
    print(f"\nprocessing the sample drive into {run_dir}")
    drive = load_drive(out)
    process_drive(
        drive, model, run_dir, overwrite=True, inputs=[model_dir], progress=not args.quiet
    )
    print("\nthe model was trained on this drive, so these figures are in-sample:")
    print(format_report(evaluate_run(drive, load_run(run_dir))))
    return 0
