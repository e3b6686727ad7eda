"""Benchmark the simulator: a 100 m random drive at the full scanner rate, timed per stage.

Usage::

    .venv/bin/python benchmarks/bench_simulate.py [--repeats 3] [--length 100] [--seed 0] [--json]

Each repeat simulates the same drive (``random_scene_spec(seed, length)`` with the default
:class:`~guardrail_core.synth.simulate.SimulationOptions`: 300,000 measurements/s, three
1024x768 cameras every 5 m) into its own folder in a temporary directory, and reports the seconds
of every stage (scene, scanner, cameras, write) that ``simulate_drive`` returns. The target is a
median total of at most 60 s on a 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from guardrail_core.synth.scene import random_scene_spec  # noqa: E402
from guardrail_core.synth.simulate import SimulationOptions, simulate_drive  # noqa: E402

TARGET_S = 60.0
STAGES = ("scene", "scanner", "cameras", "write")


def run(repeats: int, length: float, seed: int) -> dict:
    """Simulate the drive ``repeats`` times; return the measurements as a JSON-able dict."""
    options = SimulationOptions()
    runs = []
    with tempfile.TemporaryDirectory(prefix="bench_simulate-") as tmp:
        for i in range(repeats):
            spec = random_scene_spec(seed, length)
            clock = time.perf_counter()
            out = Path(tmp) / f"run{i + 1}"
            summary = simulate_drive(spec, out, seed=seed, options=options, progress=False)
            wall = time.perf_counter() - clock
            runs.append(
                {
                    "run": i + 1,
                    "seconds": {k: round(float(v), 3) for k, v in summary.seconds.items()},
                    "total_s": round(float(sum(summary.seconds.values())), 3),
                    "wall_s": round(wall, 3),
                    "points": summary.n_points,
                    "images": summary.n_images,
                    "length_m": round(summary.length_m, 2),
                }
            )
    median = statistics.median(r["total_s"] for r in runs)
    return {
        "benchmark": "simulate",
        "length_m": length,
        "seed": seed,
        "repeats": repeats,
        "measurements_per_s": options.scanner.measurement_rate_hz,
        "image_size": list(options.image_size),
        "image_every_m": options.image_every_m,
        "runs": runs,
        "median_total_s": round(median, 3),
        "target_s": TARGET_S,
        "target_cores": 2,
        "pass": median <= TARGET_S,
        "machine": {
            "cpu_count": os.cpu_count(),
            "platform": platform.platform(),
            "python": platform.python_version(),
            "processor": platform.processor() or platform.machine(),
        },
    }


def format_table(result: dict) -> str:
    """The measurements as a plain-text table."""
    header = ["run", *STAGES, "total", "points", "images"]
    rows = []
    for r in result["runs"]:
        secs = [f"{r['seconds'].get(s, 0.0):.1f}" for s in STAGES]
        rows.append(
            [str(r["run"]), *secs, f"{r['total_s']:.1f}", f"{r['points']:,}", str(r["images"])]
        )
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(header)]
    lines = [
        f"simulate: {result['length_m']:g} m random drive (seed {result['seed']}), "
        f"{result['measurements_per_s']:,.0f} measurements/s, "
        f"{result['image_size'][0]}x{result['image_size'][1]} cameras every "
        f"{result['image_every_m']:g} m; {result['repeats']} run(s), seconds per stage",
        "  ".join(h.rjust(w) for h, w in zip(header, widths, strict=True)),
        "  ".join("-" * w for w in widths),
    ]
    lines += ["  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in rows]
    verdict = "PASS" if result["pass"] else "FAIL"
    machine = result["machine"]
    lines += [
        "",
        f"median total {result['median_total_s']:.1f} s; target <= {result['target_s']:.0f} s "
        f"on {result['target_cores']} cores: {verdict}",
        f"machine: {machine['cpu_count']} CPUs, {machine['platform']}, Python {machine['python']}",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=3, help="number of runs (default 3)")
    parser.add_argument("--length", type=float, default=100.0, help="drive length, m (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random drive (default 0)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    result = run(args.repeats, args.length, args.seed)
    print(json.dumps(result, indent=2) if args.json else format_table(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
