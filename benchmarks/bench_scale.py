"""Benchmark survey scale: memory and speed of ``guardrail process`` against the drive's length
and the number of Dask workers, and tiled results against whole-drive results.

Usage::

    .venv/bin/python benchmarks/bench_scale.py [--lengths 300,1000,3000] [--workers 1,2]
        [--repeats 3] [--drives benchmarks/drives] [--against COMMIT] [--json]

For every length a random street is simulated once (``guardrail simulate --length L --seed
S``, kept under ``--drives``), then processed by ``guardrail process`` as a subprocess with each
number of workers (an embedded Dask LocalCluster, 100 m tiles), ``--repeats`` times. While it
runs, the resident memory of its whole process tree (the command and its Dask workers) is
sampled every 0.1 s. Reported per length and worker count, medians over the repeats:

- ``peak_total_gb``: the largest sum of resident memory over the tree;
- ``peak_process_gb``: the largest resident memory of one process (a worker, or the command);
- ``seconds`` and ``realtime``: the drive's own duration divided by the wall time (how many
  times faster than the vehicle recorded it); ``speedup``: seconds with 1 worker over seconds
  with 2.

With ``--against COMMIT``, each drive is also processed by the code of an earlier commit (a
temporary git worktree, first on the ``PYTHONPATH`` of the command and its workers) and by this
checkout, one after the other, ``--repeats`` times, with the largest worker count: this
machine's speed drifts by 10-30 % over an hour, so a change is measured against its
predecessor in the same minutes (medians of each, and their ratio).

Then tiles against whole: the shortest drive processed with ``--tile-m 100`` and with
``--tile-m 0`` (one tile covering the drive): the share of points with the same final label,
the guardrail runs and the pole count of each.

Targets (issue 20): peak memory per process under 3 GB at every length, flat in the length;
real-time factor >= 2 with 2 workers; speed-up >= 1.8 from 1 to 2 workers; >= 99.9 % of points
with the same label, the same runs and the same poles, tiled against whole.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from guardrail_core.formats.drive import open_drive  # noqa: E402
from guardrail_core.formats.run_folder_paths import RunFolder  # noqa: E402

GUARDRAIL = [str(ROOT / ".venv" / "bin" / "guardrail")]
TARGET_PROCESS_GB = 3.0
TARGET_REALTIME = 2.0
TARGET_SPEEDUP = 1.8
TARGET_SAME_LABEL = 0.999


def simulate(drives: Path, length: float, seed: int, image_every: float | None) -> Path:
    """The drive of ``length`` metres (simulated once, then reused)."""
    cameras = "" if image_every is None else f"_img{image_every:g}"
    out = drives / f"street_{int(length)}m{cameras}_seed{seed}"
    if not (out / "drive.json").is_file():
        options = [] if image_every is None else ["--image-every", str(image_every)]
        subprocess.run(
            [*GUARDRAIL, "simulate", str(out), "--length", str(length), "--seed", str(seed)]
            + ["--tile-m", "25", "--quiet", "--overwrite", *options],
            check=True,
        )
    return out


def measure(command: list[str], code: Path | None = None) -> dict[str, float]:
    """Run ``command``; its wall seconds and peak resident memory (GB), the whole process tree
    together and the largest single process. ``code``: a checkout of guardrail to run instead
    of this one (put first on the workers' path too)."""
    env, cwd = None, None
    if code is not None:
        # From outside this checkout, so that neither the working directory nor the editable
        # install puts this checkout's package before ``code``'s.
        env = {**os.environ, "PYTHONPATH": str(code)}
        cwd = code.parent
    start = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, env=env, cwd=cwd)
    root = psutil.Process(process.pid)
    peak_total = peak_one = 0
    while process.poll() is None:
        try:
            tree = [root, *root.children(recursive=True)]
            rss = []
            for p in tree:
                try:
                    rss.append(p.memory_info().rss)
                except psutil.Error:
                    pass
            peak_total = max(peak_total, sum(rss))
            peak_one = max([peak_one, *rss])
        except psutil.Error:
            pass
        time.sleep(0.1)
    seconds = time.perf_counter() - start
    if process.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed with exit code {process.returncode}")
    return {
        "seconds": seconds,
        "peak_total_gb": peak_total / 1e9,
        "peak_process_gb": peak_one / 1e9,
    }


def process(
    drive: Path, run: Path, workers: int, tile_m: float, code: Path | None = None
) -> dict[str, float]:
    return measure(
        [*GUARDRAIL, "process", str(drive), "--out", str(run), "--overwrite", "--quiet"]
        + ["--workers", str(workers), "--tile-m", str(tile_m)],
        code,
    )


@contextmanager
def checkout(commit: str) -> Iterator[Path]:
    """A detached worktree of ``commit`` in a temporary folder (removed afterwards)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "guardrail"
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(path), commit],
            check=True,
        )
        try:
            yield path
        finally:
            subprocess.run(
                ["git", "-C", str(ROOT), "worktree", "remove", "--force", str(path)], check=True
            )


def against(drive: Path, runs_dir: Path, workers: int, repeats: int, commit: str) -> dict:
    """``process`` of this checkout and of ``commit``, interleaved ``repeats`` times (the
    machine's speed drifts over minutes): the median seconds of each and their ratio."""
    seconds: dict[str, list[float]] = {"before": [], "now": []}
    with checkout(commit) as code:
        for _ in range(repeats):
            for name, where in (("before", code), ("now", None)):
                run = runs_dir / f"{drive.name}_{name}"
                seconds[name].append(process(drive, run, workers, 100.0, where)["seconds"])
    before, now = (statistics.median(seconds[k]) for k in ("before", "now"))
    return {
        "commit": commit,
        "workers": workers,
        "seconds": seconds,
        "before": before,
        "now": now,
        "speedup": before / now,
    }


def final_labels(run: Path) -> np.ndarray:
    folder = RunFolder.open(run)
    segment, label = folder.point_segment(), folder.segments()["label"]
    out = np.where(segment < 0, segment, 0).astype(np.int8)
    out[segment >= 0] = label[segment[segment >= 0]]
    return out


def runs_and_poles(run: Path) -> tuple[int, int]:
    runs = json.loads((run / "reconstruction" / "models.json").read_text())["runs"]
    return len(runs), sum(len(r["poles"]) for r in runs)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--lengths", default="300,1000,3000")
    parser.add_argument("--workers", default="1,2")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=31)
    parser.add_argument("--drives", type=Path, default=ROOT / "benchmarks" / "drives")
    parser.add_argument(
        "--image-every",
        type=float,
        default=None,
        help="camera spacing of the simulated drives (default: the simulator's 5 m; cameras are "
        "most of a simulation's time)",
    )
    parser.add_argument(
        "--no-check", action="store_true", help="leave out the tiles-against-whole check"
    )
    parser.add_argument(
        "--against",
        metavar="COMMIT",
        help="also run the code of COMMIT (a git worktree) on each drive, interleaved with this "
        "checkout's runs, with the largest worker count: before and now in the same minutes",
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    lengths = [float(v) for v in args.lengths.split(",")]
    worker_counts = [int(v) for v in args.workers.split(",")]
    args.drives.mkdir(parents=True, exist_ok=True)
    runs_dir = args.drives / "runs"
    rows = []
    for length in lengths:
        drive = simulate(args.drives, length, args.seed, args.image_every)
        source = open_drive(drive, with_truth=False)
        duration = float(source.trajectory.time[-1] - source.trajectory.time[0])
        for workers in worker_counts:
            samples = [
                process(drive, runs_dir / f"{drive.name}_w{workers}", workers, 100.0)
                for _ in range(args.repeats)
            ]
            seconds = statistics.median(s["seconds"] for s in samples)
            rows.append(
                {
                    "length_m": length,
                    "points": source.tiles.points,
                    "tiles": len(source.tiles),
                    "drive_seconds": duration,
                    "workers": workers,
                    "seconds": seconds,
                    "realtime": duration / seconds,
                    "peak_total_gb": statistics.median(s["peak_total_gb"] for s in samples),
                    "peak_process_gb": statistics.median(s["peak_process_gb"] for s in samples),
                    "runs": samples,
                }
            )
    comparisons = []
    if args.against:
        for length in lengths:
            drive = simulate(args.drives, length, args.seed, args.image_every)
            comparisons.append(
                {"length_m": length}
                | against(drive, runs_dir, max(worker_counts), args.repeats, args.against)
            )
    speedups = {}
    for length in lengths:
        by_workers = {r["workers"]: r["seconds"] for r in rows if r["length_m"] == length}
        if 1 in by_workers and 2 in by_workers:
            speedups[length] = by_workers[1] / by_workers[2]

    check = None
    if not args.no_check:
        drive = simulate(args.drives, min(lengths), args.seed, args.image_every)
        tiled, whole = runs_dir / "tiled_100", runs_dir / "whole"
        process(drive, tiled, max(worker_counts), 100.0)
        process(drive, whole, max(worker_counts), 0.0)
        check = {
            "length_m": min(lengths),
            "same_label": float((final_labels(tiled) == final_labels(whole)).mean()),
            "runs_poles_tiled": runs_and_poles(tiled),
            "runs_poles_whole": runs_and_poles(whole),
        }
    machine = {"cpus": os.cpu_count(), "platform": platform.platform(), "python": sys.version}
    if args.json:
        print(
            json.dumps(
                {
                    "rows": rows,
                    "speedup": speedups,
                    "against": comparisons,
                    "tiles_vs_whole": check,
                    "machine": machine,
                },
                indent=2,
            )
        )
        return 0
    print(
        f"{'length':>8s} {'points':>11s} {'tiles':>5s} {'workers':>7s} {'seconds':>8s} "
        f"{'realtime':>8s} {'peak all':>9s} {'peak one':>9s}"
    )
    for r in rows:
        print(
            f"{r['length_m']:>7.0f}m {r['points']:>11,d} {r['tiles']:>5d} {r['workers']:>7d} "
            f"{r['seconds']:>8.1f} {r['realtime']:>7.2f}x {r['peak_total_gb']:>7.2f}GB "
            f"{r['peak_process_gb']:>7.2f}GB"
        )
    for length, speedup in speedups.items():
        print(
            f"speed-up 1 -> 2 workers at {length:.0f} m: {speedup:.2f}x (target {TARGET_SPEEDUP})"
        )
    for c in comparisons:
        print(
            f"{c['length_m']:.0f} m, {c['workers']} workers: {c['before']:.1f} s at {c['commit']}, "
            f"{c['now']:.1f} s now ({c['speedup']:.2f}x; medians of interleaved runs)"
        )
    if check is not None:
        print(
            f"tiles against whole ({check['length_m']:.0f} m): {100 * check['same_label']:.3f} % "
            f"of points with the same label (target {100 * TARGET_SAME_LABEL:.1f} %); runs, "
            f"poles tiled {check['runs_poles_tiled']}, whole {check['runs_poles_whole']}"
        )
    print(f"machine: {machine['cpus']} cores, {machine['platform']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
