"""Accuracy where users meet it: the default model on random streets nothing was tuned on.

Usage::

    .venv/bin/python benchmarks/accuracy.py [--streets 10] [--workers 2]
        [--data benchmarks/data/accuracy] [--set STAGE.NAME=VALUE ...] [--model DIR] [--json]

**The rule.** Seeds 10001-19999 belong to this benchmark alone: no training drive, test, example,
figure or tuning uses them (``tests/benchmarks/test_accuracy_seeds.py`` fails if another file of the
repository names one). The benchmark's streets are the random 300 m streets of seeds 10001,
10002, ... (``guardrail simulate DRIVE --length 300 --seed S``: every design and confounder, one
to three lanes, far-side guardrails, parked cars, curves), simulated once into ``--data`` and
reused. Looking at a street's figures and then changing the method for that street breaks the
rule as much as training on it: change the method for a *cause* in the breakdown, then measure
again here.

Each street is processed like a user's drive (``guardrail process``: the default model, 100 m
tiles on an embedded Dask cluster) and evaluated against its truth. Reported, pooled over the
streets:

- detection (segments, after label correction): recall, precision and F per class, with a 95 %
  bootstrap interval over streets (streets resampled with replacement: a street's segments are
  not independent of each other, so resampling segments would understate the spread);
- poles found of those in view (scanned: ten of the guardrail's points within 0.1 m of the axis)
  and of all true poles, pipes found of those in view (a guardrail with one unit whose two poles
  were scanned), and the misses of each by cause (:mod:`guardrail_core.evaluate.misses`:
  beyond the drive's ends, far side, occluded, short run, unit partly seen, design, ...); the
  false poles (detected poles no true pole took: a hedge's stems called guardrail, say), since a
  pole within 0.3 m of a true one counts as found, and a row of false ones would pass for it;
- errors of what was found: pole position (median), pipe radius (median), pipe axis deviation
  (mean), beam section Hausdorff (median), all in mm;
- per design: poles and pipes found.

Beside them, ``--multibeam-streets`` (default 3) random 300 m streets of seeds 15001, 15002, ...
scanned by a spinning multi-beam LiDAR, one frame every 30 m and no camera, as KITTI-like
deliveries are: long runs (``--long-runs 0.35``), motorway medians (``--medians 0.5``) and cars
in the lanes beside the car (``--traffic 0.5``), the sensor taking turns through the HDL-64E, the
Pandar64 and the OS1-128. Their detection is reported apart (no camera: the segment head
alone decides), with the same targets.

Targets (issue 21): guardrail F >= 0.98, other F >= 0.99; >= 95 % of pipes in view and of poles
found; radius <= 2 mm, axis <= 5 mm, beam section <= 10 mm, pole position <= 20 mm.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from guardrail_core.classes import GUARDRAIL_CLASSES, TruthClass  # noqa: E402
from guardrail_core.cli.common import process_params  # noqa: E402
from guardrail_core.distributed import ClusterSpec  # noqa: E402
from guardrail_core.evaluate.misses import (  # noqa: E402
    MissBreakdown,
    explain_detection_misses,
    explain_misses,
)
from guardrail_core.evaluate.reconstruction import PolePointCounter  # noqa: E402
from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR  # noqa: E402
from guardrail_core.formats.drive import open_drive  # noqa: E402
from guardrail_core.formats.run_folder_paths import RunFolder  # noqa: E402
from guardrail_core.process import process_drive_folder  # noqa: E402
from guardrail_core.reconstruct.run_models import load_run_models  # noqa: E402
from guardrail_core.synth.random_scene import random_scene_spec  # noqa: E402
from guardrail_core.synth.simulate import (  # noqa: E402
    SIMULATOR_VERSION,
    SimulationOptions,
    simulate_drive,
)

#: The benchmark's own seeds (see the rule above); street k (1, 2, ...) has seed FIRST_SEED + k - 1.
FIRST_SEED = 10001
LAST_SEED = 14999
#: The multi-beam streets' seeds: the rest of the benchmark's range.
MULTIBEAM_FIRST_SEED = 15001
MULTIBEAM_LAST_SEED = 19999
MULTIBEAM_SENSORS = ("hdl64e", "pandar64", "os1-128")
LENGTH_M = 300.0
BOOTSTRAP = 2000
TARGETS = {
    "guardrail_f": 0.98,
    "other_f": 0.99,
    "poles_found": 0.95,
    "pipes_found": 0.95,
    "radius_mm": 2.0,
    "axis_mm": 5.0,
    "beam_mm": 10.0,
    "pole_mm": 20.0,
}


def street_seeds(count: int) -> list[int]:
    """The seeds of the first ``count`` benchmark streets."""
    if not 1 <= count <= LAST_SEED - FIRST_SEED + 1:
        raise SystemExit(f"--streets: 1 to {LAST_SEED - FIRST_SEED + 1}, got {count}")
    return list(range(FIRST_SEED, FIRST_SEED + count))


def multibeam_seeds(count: int) -> list[int]:
    """The seeds of the first ``count`` multi-beam streets."""
    if not 0 <= count <= MULTIBEAM_LAST_SEED - MULTIBEAM_FIRST_SEED + 1:
        raise SystemExit(
            f"--multibeam-streets: 0 to {MULTIBEAM_LAST_SEED - MULTIBEAM_FIRST_SEED + 1}"
        )
    return list(range(MULTIBEAM_FIRST_SEED, MULTIBEAM_FIRST_SEED + count))


def street_spec(seed: int) -> dict:
    """The scene of benchmark street ``seed``: a profile-scanner street, or (a multi-beam seed)
    a multi-beam one with medians and traffic, its sensor by turns."""
    if seed < MULTIBEAM_FIRST_SEED:
        return random_scene_spec(seed, LENGTH_M)
    spec = random_scene_spec(seed, LENGTH_M, long_runs=0.35, medians=0.5, traffic=0.5)
    sensor = MULTIBEAM_SENSORS[(seed - MULTIBEAM_FIRST_SEED) % len(MULTIBEAM_SENSORS)]
    spec["scanner"] = {"kind": "multibeam", "frame_every_m": 30.0, "sensor": sensor}
    return spec


def ensure_street(data: Path, seed: int) -> Path:
    """The street of ``seed`` under ``data``: simulated the first time, and again when the
    simulator's street for that seed has changed since (its ``truth/scene.yaml`` differs) or
    the simulator itself has (``drive.json``'s ``source.simulator`` is not
    :data:`~guardrail_core.synth.simulate.SIMULATOR_VERSION`)."""
    out = data / f"street_{seed}"
    spec = street_spec(seed)
    scene = out / "truth" / "scene.yaml"
    header = out / "drive.json"
    stale = scene.is_file() and (
        yaml.safe_load(scene.read_text()) != spec
        or not header.is_file()
        or json.loads(header.read_text()).get("source", {}).get("simulator") != SIMULATOR_VERSION
    )
    if stale or not header.is_file():
        why = "again: the simulator or its street changed" if stale else f"({LENGTH_M:g} m)"
        print(f"simulating {out.name} {why} ...", file=sys.stderr, flush=True)
        multibeam = seed >= MULTIBEAM_FIRST_SEED  # no camera, as KITTI-like deliveries
        options = SimulationOptions(image_every_m=1e4) if multibeam else SimulationOptions()
        simulate_drive(spec, out, seed=seed, options=options, progress=False, overwrite=True)
    return out


def measure_street(
    drive: Path,
    run: Path,
    workers: int,
    reuse: bool = False,
    settings: Sequence[str] = (),
    model: Path = DEFAULT_MODEL_DIR,
) -> dict:
    """Process one street with ``model`` (``reuse``: keep a run already there; ``settings``:
    ``guardrail process --set`` values) and compare the run with its truth."""
    seconds = None  # a run reused
    if not (reuse and (run / "run.json").is_file()):
        if run.exists():
            shutil.rmtree(run)
        clock = time.perf_counter()
        extraction, reconstruction = process_params(list(settings))
        process_drive_folder(
            drive,
            model,
            run,
            params=extraction,
            reconstruction=reconstruction,
            cluster=ClusterSpec(workers=workers),
        )
        seconds = round(time.perf_counter() - clock, 1)
    # One pass over the drive's tiles: the truth of every segment (as ``guardrail evaluate``
    # takes it: most of its points) and the points around every true pole.
    source = open_drive(drive)
    folder = RunFolder.open(run)
    segments = folder.segments()
    pole_points = PolePointCounter(source.objects)
    guardrail_points = np.zeros(len(segments["n_points"]))
    label = np.asarray(segments["label"], bool)
    # Points of vegetation (hedges, shrubs, tall grass) and how many end up labelled guardrail.
    vegetation = {"points": 0, "labelled_guardrail": 0, "guardrail_labelled_points": 0}
    for t in range(len(source.tiles)):
        points, truth = source.read_tiles([t])
        assert truth is not None  # simulated
        pole_points.add(points.xyz, truth.point_object)
        segment = folder.point_segment_tile(t)
        inside = segment >= 0
        guardrail = np.isin(truth.point_class[inside], list(GUARDRAIL_CLASSES))
        guardrail_points += np.bincount(
            segment[inside], weights=guardrail, minlength=len(guardrail_points)
        )
        green = truth.point_class == TruthClass.VEGETATION
        labelled = np.zeros(len(segment), bool)
        labelled[inside] = label[segment[inside]]
        vegetation["points"] += int(green.sum())
        vegetation["labelled_guardrail"] += int((green & labelled).sum())
        vegetation["guardrail_labelled_points"] += int(labelled.sum())
    segment_truth = 2 * guardrail_points > segments["n_points"]
    counts = {
        name: {
            "tp": int((truth_class & predicted).sum()),
            "n_true": int(truth_class.sum()),
            "n_predicted": int(predicted.sum()),
        }
        for name, truth_class, predicted in (
            ("guardrail", segment_truth, label),
            ("other", ~segment_truth, ~label),
        )
    }
    misses = explain_misses(
        list(load_run_models(run).runs), source.objects, pole_points, source.trajectory
    )
    return {
        "drive": drive.name,
        "seconds": seconds,
        "detection": counts,
        "detection_misses": explain_detection_misses(segment_truth, label, segments),
        "misses": misses,
        "vegetation": vegetation,
    }


def f_measure(tp: np.ndarray, n_true: np.ndarray, n_predicted: np.ndarray) -> np.ndarray:
    """F = 2 TP / (true + predicted), elementwise (1 where both are 0)."""
    total = n_true + n_predicted
    return np.where(total > 0, 2 * tp / np.maximum(total, 1), 1.0)


def pooled_detection(streets: list[dict], rng: np.random.Generator) -> dict:
    """Per class: pooled recall, precision, F and the F's 95 % bootstrap interval over streets."""
    out = {}
    for name in ("guardrail", "other"):
        c = np.array(
            [[s["detection"][name][k] for k in ("tp", "n_true", "n_predicted")] for s in streets],
            np.float64,
        )
        tp, n_true, n_predicted = c.sum(axis=0)
        draws = rng.integers(0, len(streets), (BOOTSTRAP, len(streets)))
        resampled = c[draws].sum(axis=1)
        f = f_measure(resampled[:, 0], resampled[:, 1], resampled[:, 2])
        out[name] = {
            "recall": tp / max(n_true, 1),
            "precision": tp / max(n_predicted, 1),
            "f": float(f_measure(np.array(tp), np.array(n_true), np.array(n_predicted))),
            "f_95": [float(np.percentile(f, 2.5)), float(np.percentile(f, 97.5))],
            "n_true": int(n_true),
        }
    return out


def summarise(streets: list[dict]) -> dict:
    misses: MissBreakdown = sum((s["misses"] for s in streets), MissBreakdown())
    detection = pooled_detection(streets, np.random.default_rng(0))

    def median(values: tuple[float, ...]) -> float | None:
        return float(np.median(values)) if values else None

    figures = {
        "guardrail_f": detection["guardrail"]["f"],
        "other_f": detection["other"]["f"],
        "poles_found": misses.poles_found_in_view / max(misses.poles_in_view, 1),
        "poles_found_of_all": misses.poles_found / max(misses.poles_total, 1),
        "pipes_found": misses.pipes_found / max(misses.pipes_in_view, 1),
        "radius_mm": median(misses.radius_errors_mm),
        "axis_mm": float(np.mean(misses.axis_deviations_mm)) if misses.axis_deviations_mm else None,
        "beam_mm": median(misses.beam_hausdorff_mm),
        "pole_mm": median(misses.pole_errors_mm),
        "false_poles": misses.false_poles / max(misses.poles_detected, 1),
    }
    met = {
        name: value is not None
        and (value >= TARGETS[name] if name.endswith(("_f", "_found")) else value <= TARGETS[name])
        for name, value in figures.items()
        if name in TARGETS
    }
    wrong: dict[str, dict[str, int]] = {}
    for street in streets:
        for kind, counts in street["detection_misses"].items():
            for cause, n in counts.items():
                wrong.setdefault(kind, {}).setdefault(cause, 0)
                wrong[kind][cause] += n
    vegetation = {
        key: sum(s["vegetation"][key] for s in streets) for key in streets[0]["vegetation"]
    }
    return {
        "detection": detection,
        "detection_misses": wrong,
        "vegetation": vegetation,
        "figures": figures,
        "met": met,
        "misses": misses,
    }


def report(summary: dict, streets: list[dict]) -> str:
    d, f, m, met = summary["detection"], summary["figures"], summary["misses"], summary["met"]
    ok = {True: "met", False: "MISSED"}
    lines = [
        f"{len(streets)} streets of {LENGTH_M:g} m (seeds {streets[0]['seed']}-"
        f"{streets[-1]['seed']}), the model {summary['model']}, 100 m tiles",
        "",
        f"{'detection (segments)':24s}{'n_true':>8s}{'recall':>9s}{'precision':>11s}"
        f"{'F':>8s}{'F 95 % interval':>18s}",
    ]
    for name in ("guardrail", "other"):
        c = d[name]
        lines.append(
            f"{name:24s}{c['n_true']:>8d}{c['recall']:>9.3f}{c['precision']:>11.3f}"
            f"{c['f']:>8.3f}{c['f_95'][0]:>11.3f}-{c['f_95'][1]:.3f}   "
            f"target >= {TARGETS[name + '_f']} {ok[met[name + '_f']]}"
        )
    wrong = summary["detection_misses"]
    lines.append(
        "  guardrail segments missed, by cause (of all guardrail segments): "
        + ", ".join(f"{c} {wrong['missed'][c]} of {wrong['guardrail'][c]}" for c in wrong["missed"])
    )
    lines.append(
        "  false alarms by cause: "
        + ", ".join(f"{c} {n}" for c, n in wrong["false alarms"].items())
    )
    v = summary["vegetation"]
    lines.append(
        f"  vegetation points labelled guardrail: {v['labelled_guardrail']:,} of "
        f"{v['points']:,} ({100 * v['labelled_guardrail'] / max(v['points'], 1):.1f} %; "
        f"{100 * v['labelled_guardrail'] / max(v['guardrail_labelled_points'], 1):.1f} % of "
        "the points labelled guardrail)"
    )
    lines += [
        "",
        f"poles found      {m.poles_found_in_view} of {m.poles_in_view} in view "
        f"({100 * f['poles_found']:.1f} %)   target >= 95 % {ok[met['poles_found']]}",
        f"  of all true poles: {m.poles_found} of {m.poles_total} "
        f"({100 * f['poles_found_of_all']:.1f} %)",
        f"  missed by cause: {_causes(m.pole_misses)}",
        f"  false poles (detected where no true pole stands): {m.false_poles} of "
        f"{m.poles_detected} detected",
        f"pipes found      {m.pipes_found} of {m.pipes_in_view} in view "
        f"({100 * f['pipes_found']:.1f} %)   target >= 95 % {ok[met['pipes_found']]}",
        f"  missed by cause: {_causes(m.pipe_misses)}",
        f"  design misses: {_causes(m.design_misses)}",
        "",
    ]
    for key, label, target in (
        ("pole_mm", "pole position, median", 20),
        ("radius_mm", "pipe radius, median", 2),
        ("axis_mm", "pipe axis deviation, mean", 5),
        ("beam_mm", "beam section Hausdorff, median", 10),
    ):
        value = f[key]
        shown = "-" if value is None else f"{value:.1f} mm"
        lines.append(f"{label:32s}{shown:>10s}   target <= {target} mm {ok[met[key]]}")
    lines += ["", f"{'design':18s}{'poles':>14s}{'pipes in view':>16s}"]
    for name, c in m.designs.items():
        pipes = f"{c['pipes_found']}/{c['pipes_in_view']}" if c["pipes_in_view"] else "-"
        lines.append(f"{name:18s}{c['poles_found']:>7d}/{c['poles_total']:<6d}{pipes:>16s}")
    lines += ["", "per street (guardrail F, poles, pipes):"]
    for s in streets:
        g = s["detection"]["guardrail"]
        gf = f_measure(np.array(g["tp"]), np.array(g["n_true"]), np.array(g["n_predicted"]))
        sm = s["misses"]
        lines.append(
            f"  {s['drive']}: F {float(gf):.3f}, poles {sm.poles_found}/{sm.poles_total}, "
            f"pipes {sm.pipes_found}/{sm.pipes_in_view}, "
            + ("run reused" if s["seconds"] is None else f"processed in {s['seconds']} s")
        )
    if "multibeam" in summary:
        mb = summary["multibeam"]
        lines += [
            "",
            f"multi-beam streets (seeds {mb['seeds'][0]}-{mb['seeds'][-1]}; one frame every 30 m, "
            "no camera, medians and traffic):",
        ]
        for name in ("guardrail", "other"):
            c = mb["detection"][name]
            lines.append(
                f"  {name:22s}{c['n_true']:>8d}{c['recall']:>9.3f}{c['precision']:>11.3f}"
                f"{c['f']:>8.3f}{c['f_95'][0]:>11.3f}-{c['f_95'][1]:.3f}   "
                f"target >= {TARGETS[name + '_f']} "
                f"{ok[c['f'] >= TARGETS[name + '_f']]}"
            )
    return "\n".join(lines)


def _causes(counts: dict[str, int]) -> str:
    ranked = sorted(counts.items(), key=lambda kv: -kv[1])
    return ", ".join(f"{name} {n}" for name, n in ranked) or "none"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--streets", type=int, default=10, help="how many streets (default 10)")
    parser.add_argument(
        "--multibeam-streets",
        type=int,
        default=3,
        help="how many multi-beam streets beside them (default 3; 0: none)",
    )
    parser.add_argument("--workers", type=int, default=2, help="Dask workers (default 2)")
    parser.add_argument("--data", type=Path, default=ROOT / "benchmarks" / "data" / "accuracy")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead")
    parser.add_argument("--save", type=Path, help="also write the JSON object to this file")
    parser.add_argument(
        "--reuse-runs",
        action="store_true",
        help="evaluate the runs a previous call left in DATA/runs instead of processing again "
        "(only after a change to the evaluation, never to the method)",
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="STAGE.NAME=VALUE",
        help="a parameter as `guardrail process --set` takes it (repeatable), to measure a "
        "change against the defaults on the same streets (its runs go to DATA/runs_set)",
    )
    parser.add_argument(
        "--model",
        type=Path,
        help="another model folder to measure on the same streets (its runs go to DATA/runs_set)",
    )
    args = parser.parse_args()
    args.data.mkdir(parents=True, exist_ok=True)
    streets, multibeam = [], []
    for seed in street_seeds(args.streets) + multibeam_seeds(args.multibeam_streets):
        drive = ensure_street(args.data, seed)
        print(f"processing {drive.name} ...", file=sys.stderr, flush=True)
        result = measure_street(
            drive,
            args.data / ("runs_set" if args.set or args.model else "runs") / drive.name,
            args.workers,
            reuse=args.reuse_runs,
            settings=args.set,
            model=args.model or DEFAULT_MODEL_DIR,
        )
        (streets if seed < MULTIBEAM_FIRST_SEED else multibeam).append({"seed": seed, **result})
    summary = {**summarise(streets), "model": str(args.model or "default")}
    if multibeam:
        summary["multibeam"] = {
            "seeds": [s["seed"] for s in multibeam],
            "detection": pooled_detection(multibeam, np.random.default_rng(0)),
        }
    document = {
        **{k: v for k, v in summary.items() if k != "misses"},
        "misses": summary["misses"].to_json(),
        "streets": [{**s, "misses": s["misses"].to_json()} for s in streets + multibeam],
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
    }
    if args.save:
        args.save.write_text(json.dumps(document, indent=1) + "\n")
    print(json.dumps(document, indent=1) if args.json else report(summary, streets))
    return 0


if __name__ == "__main__":
    sys.exit(main())
