"""The review loop's learning curve: how many operator labels a model needs on a street whose
design it never saw.

Usage::

    .venv/bin/python benchmarks/review_loop.py DRIVE [--model MODEL] [--run RUN]
        [--labels 0,25,50,100,200] [--order queue|random|both] [--seed 0] [--train-seed 0]
        [--frame-labels NPZ] [--json]

DRIVE is processed with MODEL (default: the shipped default model) into a run (``--run``: an
existing run of DRIVE instead). Then, for each order, on a copy of that run, an oracle operator
labels segments with the truth (the class of most of a segment's points) in batches, up to each
count of ``--labels``:

- ``queue``: the review queue's order (:mod:`guardrail_core.review.queue`: disagreement with the
  label correction and one segment of every guardrail run not looked at yet first, then the
  expected change: uncertainty weighted by the points moved and by a run's join or split;
  segments under 10 points left out), ranked again after every batch from the new predictions
  and the labels given so far, as the app's queue is;
- ``random``: a random order (``--seed``).

After each batch it fine-tunes exactly as the app's "Train" and "Activate" do
(:func:`~guardrail_core.review.training.train_from_run` in fast mode on the reviewed labels and
the run's corrected labels elsewhere, but for those an operator contradicted on their component
(``--keep-contradicted`` keeps them), its segment head fine-tuned from MODEL's (``--fresh-head``
draws it anew, as before 2026-11-29), then :func:`~guardrail_core.review.predictions.predict_run`
and :func:`~guardrail_core.review.predictions.write_predictions`), and measures guardrail F (after
label correction) on the rest of the street: every segment the oracle has not labelled yet,
counted per segment (``guardrail_f1``) and per point (``guardrail_f1_points``: a segment weighs
its points, so tiny segments, which the queue leaves out, count for little).

A real frame (``--frame-labels``: its hand labels, ``tests/data/real_frames/``; DRIVE imported
from that frame alone) takes its truth from the labels (a segment is guardrail when most of its
judged points are), and the metres of rail found within reach and the share of the points called
guardrail that lie off guardrails are measured on the rest of the frame too
(:mod:`guardrail_core.evaluate.labelled_frames`, as ``benchmarks/real_frames.py`` does).

Prints ``{"labels": [...], "guardrail_f1": [...]}`` per order (``--json``), or a table. Goal
(issue 21): guardrail F >= 0.98 within 100 labels, and the queue reaching it with at most half
the labels random order needs.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from guardrail_core.distributed import ClusterSpec  # noqa: E402
from guardrail_core.evaluate.detection import detection_metrics  # noqa: E402
from guardrail_core.evaluate.labelled_frames import (  # noqa: E402
    FrameLabels,
    found_within,
    load_frame_labels,
    off_guardrail_share,
    rail_metres,
)
from guardrail_core.extract.classify.crop_classifier import GuardrailClassifier  # noqa: E402
from guardrail_core.extract.classify.crop_classifier_params import ClassifierParams  # noqa: E402
from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR, load_model  # noqa: E402
from guardrail_core.extract.segment_truth import segment_truth  # noqa: E402
from guardrail_core.formats.drive import open_drive  # noqa: E402
from guardrail_core.formats.run_folder import load_run  # noqa: E402
from guardrail_core.process import process_drive_folder  # noqa: E402
from guardrail_core.review.predictions import predict_run, write_predictions  # noqa: E402
from guardrail_core.review.queue import queue_order, segment_queue_scores  # noqa: E402
from guardrail_core.review.training import train_from_run  # noqa: E402

GOAL_F = 0.98
GOAL_LABELS = 100


def true_segments(drive: Path, run: Path) -> np.ndarray:
    """(S,) bool: the true class of every segment of ``run`` (guardrail: most points are)."""
    source = open_drive(drive)
    if not source.has_truth:
        raise SystemExit(f"{drive}: no truth/ folder; the oracle needs a simulated drive")
    points, truth = source.read_tiles(range(len(source.tiles)))
    assert truth is not None
    folder = load_run(run)
    return segment_truth(truth.point_class, folder.point_segment, len(folder))


def labelled_segments(labels: FrameLabels, run: Path) -> np.ndarray:
    """(S,) bool: the true class of every segment of a real frame's ``run`` from its hand labels
    (guardrail: most of its judged points are)."""
    folder = load_run(run)
    segment = folder.point_segment
    if len(segment) != len(labels):
        raise SystemExit(f"{run}: {len(segment)} points, but the labels have {len(labels)}")
    inside = (segment >= 0) & labels.judged
    n = len(folder)
    rail = np.bincount(segment[inside], weights=labels.guardrail[inside], minlength=n)
    return 2 * rail > np.bincount(segment[inside], minlength=n)


def frame_figures(
    xy: np.ndarray, labels: FrameLabels, run, reviewed: np.ndarray
) -> tuple[float | None, float]:
    """Metres found within reach and the off-guardrail share, on the points of the segments not
    reviewed (and of no segment)."""
    segment = run.point_segment
    inside = segment >= 0
    found = np.zeros(len(segment), bool)
    found[inside] = run.segments["label"][segment[inside]]
    counted = np.ones(len(segment), bool)
    counted[inside] = ~reviewed[segment[inside]]
    share = found_within(rail_metres(xy, labels, found, counted))
    return share, off_guardrail_share(labels, found, counted)


def points_f1(truth: np.ndarray, predicted: np.ndarray, n_points: np.ndarray) -> float:
    """Guardrail F over points: each segment (S,) counts by its points, as the map's guardrails
    (and an operator's effort on them) do; tiny segments weigh almost nothing."""
    n = np.asarray(n_points, np.float64)
    tp = n[truth & predicted].sum()
    wrong = n[truth != predicted].sum()
    return float(2 * tp / (2 * tp + wrong)) if tp + wrong else 1.0


def learning_curve(
    run_dir: Path,
    truth: np.ndarray,
    labels: list[int],
    order: str,
    seed: int,
    reviewed_weight: float | None = None,
    leave_out_contradicted: bool = True,
    train_seed: int = 0,
    model: GuardrailClassifier | None = None,
    frame: tuple[np.ndarray, FrameLabels] | None = None,
) -> dict:
    """Label, fine-tune and measure ``run_dir`` (modified in place) at each count of ``labels``.

    ``model`` made the run: every fine-tuning starts from it, with every label given so far,
    as the app's Train does; None: every one from fresh draws. ``frame``: the points (N, 2) of
    a real frame's drive and their hand labels, to measure metres found and the off-guardrail
    share on the rest of the frame too.
    """
    rng = np.random.default_rng(seed)
    run = load_run(run_dir)
    random_order = rng.permutation(len(run))
    reviewed = np.zeros(len(run), bool)
    point_labels = np.full(len(run.point_segment), -1, np.int8)
    curve: dict[str, list] = {
        "labels": [],
        "guardrail_f1": [],
        "guardrail_f1_points": [],
        "seconds": [],
    }
    if frame is not None:
        curve["metres_found"], curve["off_guardrail"] = [], []
    for count in labels:
        clock = time.perf_counter()
        need = count - int(reviewed.sum())
        if need > 0:
            seg = run.segments
            if order == "queue":
                score = segment_queue_scores(seg, reviewed)
                ranked = queue_order(score, reviewed, n_points=seg["n_points"])
            else:
                ranked = random_order[~reviewed[random_order]]
            batch = ranked[:need]
            reviewed[batch] = True
            in_batch = np.isin(run.point_segment, batch)
            point_labels[in_batch] = truth[run.point_segment[in_batch]]
            trained = train_from_run(
                run,
                point_labels,
                params=ClassifierParams(mode="fast", seed=train_seed),
                reviewed_weight=reviewed_weight,
                leave_out_contradicted=leave_out_contradicted,
                start_from=model,
            )
            write_predictions(run_dir, predict_run(run, trained.model), trained.model)
            run = load_run(run_dir)
        rest = ~reviewed
        f1 = detection_metrics(truth[rest], run.segments["label"][rest]).guardrail.f1
        points = points_f1(truth[rest], run.segments["label"][rest], run.segments["n_points"][rest])
        curve["labels"].append(int(reviewed.sum()))
        curve["guardrail_f1"].append(round(float(f1), 4))
        curve["guardrail_f1_points"].append(round(points, 4))
        curve["seconds"].append(round(time.perf_counter() - clock, 1))
        if frame is not None:
            share, off = frame_figures(*frame, run, reviewed)
            curve["metres_found"].append(None if share is None else round(share, 4))
            curve["off_guardrail"].append(round(off, 4))
    reached = [
        n for n, f in zip(curve["labels"], curve["guardrail_f1"], strict=True) if f >= GOAL_F
    ]
    curve["labels_to_goal"] = reached[0] if reached else None
    return curve


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "drive", type=Path, help="a simulated drive (with truth), or a real frame's drive"
    )
    parser.add_argument(
        "--frame-labels",
        type=Path,
        help="the hand labels of a real frame (tests/data/real_frames/*.npz) DRIVE was imported "
        "from: the oracle's truth, and metres found and the off-guardrail share are measured too",
    )
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL_DIR)
    parser.add_argument("--run", type=Path, help="an existing run of DRIVE (else processed here)")
    parser.add_argument("--labels", default="0,25,50,100,200")
    parser.add_argument("--order", choices=("queue", "random", "both"), default="both")
    parser.add_argument("--seed", type=int, default=0, help="the random order's seed")
    parser.add_argument(
        "--train-seed",
        type=int,
        default=0,
        help="the fine-tuning's seed (the app's is 0); one street's curve moves by a few "
        "hundredths with it, so compare figures over several",
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--reviewed-weight",
        type=float,
        help="how many times an operator's label counts against the model's own in training "
        "(default: the app's, the reviewed segments together as much as the others)",
    )
    parser.add_argument(
        "--keep-contradicted",
        action="store_true",
        help="train on the model's labels an operator contradicted on their component too "
        "(as before 2026-11-28; see contradicted_labels in "
        "guardrail_core/review/training_labels.py)",
    )
    parser.add_argument(
        "--fresh-head",
        action="store_true",
        help="train each segment head from fresh draws instead of fine-tuning the run's model's "
        "(as before 2026-11-29)",
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    labels = sorted({int(x) for x in args.labels.split(",")})
    if labels[0] < 0:
        raise SystemExit("--labels: counts of 0 or more")
    orders = ["queue", "random"] if args.order == "both" else [args.order]
    out: dict = {"drive": str(args.drive), "model": str(args.model)}
    with tempfile.TemporaryDirectory(prefix="review-loop-") as tmp:
        run = args.run
        if run is None:
            run = Path(tmp) / "run"
            print(f"processing {args.drive} ...", file=sys.stderr, flush=True)
            process_drive_folder(
                args.drive, args.model, run, cluster=ClusterSpec(workers=args.workers)
            )
        frame = None
        if args.frame_labels is not None:
            labels_of_frame = load_frame_labels(args.frame_labels)
            truth = labelled_segments(labels_of_frame, run)
            source = open_drive(args.drive, with_truth=False)
            xyz = source.read_tiles(range(len(source.tiles)))[0].xyz
            frame = (xyz[:, :2], labels_of_frame)
        else:
            truth = true_segments(args.drive, run)
        out["segments"] = len(truth)
        out["guardrail_segments"] = int(truth.sum())
        for order in orders:
            copy = Path(tmp) / f"run_{order}"
            shutil.copytree(run, copy)
            print(f"labelling in {order} order ...", file=sys.stderr, flush=True)
            out[order] = learning_curve(
                copy,
                truth,
                labels,
                order,
                args.seed,
                args.reviewed_weight,
                leave_out_contradicted=not args.keep_contradicted,
                train_seed=args.train_seed,
                model=None if args.fresh_head else load_model(args.model),
                frame=frame,
            )
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print(f"{args.drive}: {out['segments']} segments ({out['guardrail_segments']} guardrail)")
        print(f"{'labels':>8s}" + "".join(f"{o + ' F':>14s}{o + ' F points':>18s}" for o in orders))
        for i, n in enumerate(labels):
            print(
                f"{n:>8d}"
                + "".join(
                    f"{out[o]['guardrail_f1'][i]:>14.4f}{out[o]['guardrail_f1_points'][i]:>18.4f}"
                    for o in orders
                )
            )
        for o in orders:
            print(f"{o}: F >= {GOAL_F} after {out[o]['labels_to_goal']} labels")
            if frame is not None:
                for n, share, off in zip(
                    labels, out[o]["metres_found"], out[o]["off_guardrail"], strict=True
                ):
                    print(f"{o}, {n} labels: {share:.1%} of the metres found, {off:.1%} off")
    return 0


if __name__ == "__main__":
    sys.exit(main())
