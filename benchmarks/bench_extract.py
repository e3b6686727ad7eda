"""Benchmark extraction: the geometric stages, lattice components against Open3D DBSCAN, and
classifier inference.

Usage::

    .venv/bin/python benchmarks/bench_extract.py [--drive demo_output/sample_drive]
        [--repeats 5] [--json]

1. Geometric stages (track coordinates, lattice, road removal, wireframe components, 0.5 m
   slices) on every point of the drive, timed ``--repeats`` times; the figure is the median of
   input points per second. Target: >= 1,000,000 points/s on 2 cores (3x the 300,000 points/s a
   RIEGL VQ-250 acquires).
2. The wireframe's connected components against Open3D's DBSCAN (``eps`` = the link distance,
   ``min_points`` = 1) on the same non-road points in the same run: seconds of each, their
   ratio, and whether the segments agree (adjusted Rand index of the two partitions, and the
   share of points whose component is exactly one DBSCAN cluster).
3. Classifier inference: crops per second of the frozen EfficientNet-Lite0 backbone plus the
   fast head, on the drive's own crops (CPU).

The drive defaults to the demo's sample drive (``make demo`` makes it).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from guardrail_core.extract.classify.crop_classifier_params import ClassifierParams  # noqa: E402
from guardrail_core.extract.classify.crop_classifier_training import train_classifier  # noqa: E402
from guardrail_core.extract.crops import CROP_OK  # noqa: E402
from guardrail_core.extract.lattice import build_lattice  # noqa: E402
from guardrail_core.extract.pipeline import extract, segment_crops, slice_drive  # noqa: E402
from guardrail_core.extract.road import remove_road  # noqa: E402
from guardrail_core.extract.segments import SegmentParams, wireframe_components  # noqa: E402
from guardrail_core.formats.drive import load_drive  # noqa: E402
from guardrail_core.sensors.track import track_coordinates  # noqa: E402
from guardrail_core.timing import StageTimer  # noqa: E402

TARGET_POINTS_PER_S = 1_000_000
GEOMETRIC_STAGES = ("track", "lattice", "road_removal", "components", "slices")


def adjusted_rand_index(a: np.ndarray, b: np.ndarray) -> float:
    """Adjusted Rand index of two labelings (N,) of the same points (1: identical partitions)."""
    _, a = np.unique(a, return_inverse=True)
    _, b = np.unique(b, return_inverse=True)
    pairs = a.astype(np.int64) * (int(b.max()) + 1) + b
    _, joint = np.unique(pairs, return_counts=True)

    def comb2(x: np.ndarray) -> float:
        x = x.astype(np.float64)
        return float((x * (x - 1) / 2).sum())

    sum_joint = comb2(joint)
    sum_a, sum_b = comb2(np.bincount(a)), comb2(np.bincount(b))
    total = len(a) * (len(a) - 1) / 2
    expected = sum_a * sum_b / total
    maximum = (sum_a + sum_b) / 2
    return 1.0 if maximum == expected else (sum_joint - expected) / (maximum - expected)


def bench_geometry(drive, repeats: int) -> dict:
    runs = []
    for _ in range(repeats):
        timer = StageTimer(len(drive.points))
        slice_drive(drive, timer=timer)
        seconds = timer.seconds(*GEOMETRIC_STAGES)
        runs.append({"seconds": round(seconds, 3), "stages": timer.stages})
    median_s = statistics.median(r["seconds"] for r in runs)
    return {
        "points": len(drive.points),
        "median_seconds": median_s,
        "median_points_per_s": round(len(drive.points) / median_s),
        "target_points_per_s": TARGET_POINTS_PER_S,
        "runs": runs,
    }


def bench_dbscan(drive) -> dict:
    import open3d as o3d

    points = drive.points
    params = SegmentParams()
    track = track_coordinates(points.xyz, points.gps_time, drive.trajectory)
    lattice = build_lattice(points.rotation, points.phase, drive.scanner.points_per_rotation)
    kept = remove_road(points.xyz, track, lattice) == 0
    clock = time.perf_counter()
    component = wireframe_components(points.xyz, kept, lattice, params)[kept]
    lattice_s = time.perf_counter() - clock

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.xyz[kept]))
    clock = time.perf_counter()
    cluster = np.asarray(
        cloud.cluster_dbscan(eps=params.link_distance_m, min_points=1, print_progress=False)
    )
    dbscan_s = time.perf_counter() - clock

    # A component "matches" when all its points share one cluster that holds nothing else.
    key = component.astype(np.int64) * (int(cluster.max()) + 1) + cluster
    pairs, pair_count = np.unique(key, return_counts=True)
    comp_of_pair, cluster_of_pair = (
        pairs // (int(cluster.max()) + 1),
        pairs % (int(cluster.max()) + 1),
    )
    comp_size = np.bincount(component)
    cluster_size = np.bincount(cluster)
    exact = (pair_count == comp_size[comp_of_pair]) & (pair_count == cluster_size[cluster_of_pair])
    matched_points = int(pair_count[exact].sum())
    return {
        "points": int(kept.sum()),
        "lattice_seconds": round(lattice_s, 3),
        "dbscan_seconds": round(dbscan_s, 3),
        "speedup": round(dbscan_s / lattice_s, 1),
        "lattice_components": int(component.max()) + 1,
        "dbscan_clusters": int(cluster.max()) + 1,
        "adjusted_rand_index": round(adjusted_rand_index(component, cluster), 4),
        "points_in_identical_components": round(matched_points / len(component), 4),
    }


def bench_inference(drive) -> dict:
    result = extract(drive)
    ok = np.flatnonzero(result.choice.status == CROP_OK)
    crops = segment_crops(drive, result.choice, ok, ClassifierParams().input_size_px)
    rng = np.random.default_rng(0)
    labels = rng.random(len(crops)) < 0.5  # the head's weights do not change its speed
    model = train_classifier(
        None, labels, embeddings=rng.normal(size=(len(crops), 1280)).astype(np.float32)
    )
    model.predict_proba(crops[:16])  # warm-up
    clock = time.perf_counter()
    model.predict_proba(crops)
    seconds = time.perf_counter() - clock
    return {
        "crops": len(crops),
        "seconds": round(seconds, 2),
        "crops_per_s": round(len(crops) / seconds, 1),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--drive", type=Path, default=Path("demo_output/sample_drive"))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    drive = load_drive(args.drive, with_truth=False)
    result = {
        "benchmark": "extract",
        "drive": str(args.drive),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.python_version()}",
        "geometry": bench_geometry(drive, args.repeats),
        "components_vs_dbscan": bench_dbscan(drive),
        "inference": bench_inference(drive),
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    g, c, i = result["geometry"], result["components_vs_dbscan"], result["inference"]
    verdict = "met" if g["median_points_per_s"] >= TARGET_POINTS_PER_S else "MISSED"
    print(f"drive {args.drive}: {g['points']} points; {result['machine']}")
    print(
        f"geometric stages (road removal to slices): median {g['median_seconds']:.2f} s over "
        f"{args.repeats} runs = {g['median_points_per_s'] / 1e6:.2f} M points/s "
        f"(target >= {TARGET_POINTS_PER_S / 1e6:.1f} M: {verdict})"
    )
    stages = {
        s: statistics.median(r["stages"][s]["seconds"] for r in g["runs"])
        for s in (*GEOMETRIC_STAGES, "features")
    }
    print("  per stage (median s): " + ", ".join(f"{k} {v:.3f}" for k, v in stages.items()))
    print(
        f"components on {c['points']} non-road points: lattice {c['lattice_seconds']:.3f} s, "
        f"Open3D DBSCAN {c['dbscan_seconds']:.3f} s ({c['speedup']}x); "
        f"{c['lattice_components']} components vs {c['dbscan_clusters']} clusters, "
        f"adjusted Rand index {c['adjusted_rand_index']}, "
        f"{100 * c['points_in_identical_components']:.1f}% of points in identical groups"
    )
    print(f"classifier inference: {i['crops_per_s']} crops/s on the CPU ({i['crops']} crops)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
