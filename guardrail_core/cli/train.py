"""``guardrail train``: the guardrail classifier, from drives' truth or operators' labels."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from guardrail_core.cli import common

if TYPE_CHECKING:
    from guardrail_core.extract.classify.crop_classifier import GuardrailClassifier
    from guardrail_core.extract.classify.crop_classifier_params import ClassifierParams
    from guardrail_core.extract.classify.segment_head import SegmentHeadParams


def add_parser(subparsers: common.Subparsers) -> None:
    own = common.options_parser()
    own.add_argument(
        "drives",
        type=Path,
        nargs="*",
        metavar="DRIVE",
        help="drive folders to train on, from their truth (none with --run)",
    )
    own.add_argument(
        "--run",
        type=Path,
        metavar="RUN_DIR",
        help="train from a run folder and the operators' labels instead of drives' truth",
    )
    own.add_argument(
        "--labels",
        type=Path,
        help="the label store (default: DRIVE/review/labels.sqlite of the run's drive)",
    )
    own.add_argument(
        "--start-from",
        type=Path,
        metavar="MODEL_DIR",
        help="with --run: fine-tune this model's segment head (default: that of the model that "
        "made the run, found by its version among the shipped default model and the models the "
        "review app fine-tuned next to the label store; what its training drives taught stays "
        "where the labels do not say otherwise)",
    )
    own.add_argument(
        "--fresh-head",
        action="store_true",
        help="with --run: train a new segment head on the run alone instead of fine-tuning one",
    )
    own.add_argument(
        "--reviewed-only",
        action="store_true",
        help="with --run: only segments an operator labelled (default: the others keep the "
        "run's corrected labels)",
    )
    own.add_argument("--out", type=Path, required=True, help="model folder to write")
    own.add_argument(
        "--mode",
        choices=("fast", "full"),
        default="fast",
        help="fast: frozen backbone and a small head, seconds; full: the whole network, minutes "
        "(default fast)",
    )
    own.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    own.add_argument(
        "--ignore-features",
        default="",
        metavar="NAMES",
        help="segment features the segment head does not read, comma-separated; "
        "'intensity_mean,intensity_std' for a model meant for scanners whose intensity is "
        "calibrated otherwise than the training drives' (default: it reads them all)",
    )
    own.add_argument(
        "--feature-dropout",
        type=float,
        default=None,
        metavar="SHARE",
        help="share of the shape features hidden from each segment at each step of the segment "
        "head's training, so that a shape it never saw does not veto what the crop says; it "
        "trades precision on the training designs for recall on others (default 0: none)",
    )
    parser = subparsers.add_parser(
        "train",
        help="train the guardrail classifier on labelled drives or on operators' labels",
        description="Extract the segments of each DRIVE, label their crops from truth/, and "
        "fine-tune the ImageNet-pretrained EfficientNet-Lite0 (two classes: guardrail, other). "
        "With --run RUN_DIR instead, train on that run's segments labelled by operators in the "
        "review app (`guardrail serve`).",
        parents=[
            own,
            common.overwrite_options("replace the model folder"),
            common.quiet_options(),
        ],
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from guardrail_core.extract.classify.crop_classifier_params import ClassifierParams
    from guardrail_core.extract.classify.model_folder import save_model
    from guardrail_core.extract.classify.model_training import train_from_drives
    from guardrail_core.extract.classify.segment_head import SegmentHeadParams
    from guardrail_core.formats.atomic import check_output
    from guardrail_core.formats.drive import drive_parts

    params = ClassifierParams(mode=args.mode, seed=args.seed)
    head = SegmentHeadParams(ignored_features=args.ignore_features)
    if args.feature_dropout is not None:
        head = dataclasses.replace(head, feature_dropout=args.feature_dropout)
    if bool(args.drives) == bool(args.run):
        from guardrail_core.errors import InvalidOptionError

        raise InvalidOptionError(
            "give either DRIVE... (labels from their truth/) or --run RUN_DIR (labels from the "
            "review app's label store), not both or neither"
        )
    if (args.start_from is not None or args.fresh_head) and not args.run:
        from guardrail_core.errors import InvalidOptionError

        raise InvalidOptionError(
            "--start-from and --fresh-head train on a run's labels: give --run RUN_DIR"
        )
    if args.start_from is not None and args.fresh_head:
        from guardrail_core.errors import InvalidOptionError

        raise InvalidOptionError("give --start-from MODEL_DIR or --fresh-head, not both")
    if args.run:
        model, inputs = _train_from_labels(args, params, head)
    else:
        inputs = [part for drive in args.drives for part in drive_parts(drive)]
        check_output(args.out, folder=True, overwrite=args.overwrite, inputs=inputs)  # first
        model = train_from_drives(args.drives, params=params, head=head, progress=not args.quiet)
    save_model(model, args.out, overwrite=args.overwrite, inputs=inputs)
    print(f"trained a {model.mode} model {model.version} into {args.out}")
    print(held_out_report(model.info))
    return 0


def _train_from_labels(
    args: argparse.Namespace, params: ClassifierParams, head: SegmentHeadParams
) -> tuple[GuardrailClassifier, list[Path]]:
    """The model trained on the run's operator labels, and the inputs it was trained from
    (the model folder is checked against them before training)."""
    from guardrail_core.formats.atomic import check_output
    from guardrail_core.formats.drive import drive_parts
    from guardrail_core.formats.label_store import LabelStore, default_store_path
    from guardrail_core.formats.run_folder import load_run
    from guardrail_core.review.training import train_from_run

    run = load_run(args.run)
    path = args.labels or default_store_path(Path(run.info.drive.path))
    if not Path(path).is_file():
        from guardrail_core.errors import LabelStoreError

        raise LabelStoreError(f"{path}: no label store there; give it with --labels")
    inputs = [*run.folder.parts(), *drive_parts(run.info.drive.path), Path(path)]
    check_output(args.out, folder=True, overwrite=args.overwrite, inputs=inputs)
    with LabelStore(path, n_points=len(run.point_segment)) as store:
        labels = store.point_labels().copy()
    counts = int((labels >= 0).sum())
    print(f"{counts:,} operator-labelled points from {path}")
    start = _start_model(args, run.info.model.version, Path(path).parent)
    model = train_from_run(
        run,
        labels,
        params=params,
        head=head,
        include_unreviewed=not args.reviewed_only,
        start_from=start,
    ).model
    return model, inputs


def _start_model(
    args: argparse.Namespace, run_model: str, review_dir: Path
) -> GuardrailClassifier | None:
    """The model whose segment head the training fine-tunes: ``--start-from``'s, else the one
    the review app would start from (the model that made the run, found by its version among
    the shipped default model and the models fine-tuned in ``review_dir``); None for a new
    head (``--fresh-head``, or that model's folder not at hand, which is said)."""
    from guardrail_core.extract.classify.model_folder import load_model
    from guardrail_core.review.model_lineage import (
        FINE_TUNED_MODELS_DIR,
        fine_tuned_models,
        fine_tuning_start_folder,
    )

    if args.start_from is not None:
        return load_model(args.start_from)
    if args.fresh_head:
        return None
    folders = fine_tuned_models(review_dir / FINE_TUNED_MODELS_DIR)
    folder = fine_tuning_start_folder(run_model, folders)
    if folder is None:
        print(
            f"the run was predicted by model {run_model}, whose folder is not at hand: a new "
            "segment head is drawn (give --start-from MODEL_DIR to fine-tune that model)"
        )
        return None
    start = load_model(folder)
    print(
        f"fine-tuning the segment head of model {start.version} ({folder}); --fresh-head for a new one"
    )
    return start


def held_out_report(info: dict) -> str:
    """What the model was trained on and its scores on held-out segments and crops."""
    metrics = info.get("metrics", {})
    trained = info.get("trained_on", {})
    lines = [
        f"trained on {trained.get('segments', '?')} segments, {trained.get('crops', '?')} with a "
        f"crop ({trained.get('guardrail', '?')} guardrail, {trained.get('other', '?')} other)"
    ]
    for key, what in (("held_out", "segments"), ("held_out_crops", "crops alone")):
        held = metrics.get(key)
        if not held:
            continue
        lines.append(f"held out {held['n_held_out']} {what}:")
        for name in ("guardrail", "other"):
            m = held.get(name)
            if m and m["f1"] is not None:
                lines.append(
                    f"  {name:10s} recall {100 * m['recall']:5.1f}%  precision "
                    f"{100 * m['precision']:5.1f}%  F {100 * m['f1']:5.1f}%  (n={m['n']})"
                )
    return "\n".join(lines)
