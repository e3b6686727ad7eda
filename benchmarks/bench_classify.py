"""Benchmark classification: the crop CNN (§3.3) on one CPU thread, per runtime and batch size.

Usage::

    .venv/bin/python benchmarks/bench_classify.py [--drive DRIVE | --crops NPZ] [--limit 512]
        [--repeats 5] [--batch-sizes 1,8,16,64] [--save-crops NPZ] [--json]

The crops are a drive's own (default: the demo's ``demo_output/sample_drive``), cut by the
extraction pipeline at the default model's input size; ``--save-crops`` keeps them in an .npz
that ``--crops`` reads back (cutting a 300 m drive's crops takes a minute or two). Each process
of ``guardrail process`` runs torch on one thread, so everything here does too.

1. Crops per second of the frozen backbone (EfficientNet-Lite0, 128 px) for each runtime and
   batch size, the median of ``--repeats`` passes over the crops, in CPU time (the process's own
   seconds: the machine is shared) and wall time; and the largest difference from torch's
   embeddings and from the default model's probabilities. Runtimes: ``torch`` (eager, the
   reference), ``torch-channels-last``, ``torch-jit`` (traced, frozen, optimised for inference),
   ``onnxruntime`` (what the product uses when installed) and ``openvino`` (when installed).
2. Where a crop's time goes on torch: the normalisation, the backbone, the fast head; and the
   segment head per segment; and the one-off cost of exporting to ONNX Runtime.
3. With ``--stage``: the whole classify stage of ``guardrail process`` on all the source's crops
   and segments (embed, fast head, segment head), once each: as before this benchmark (torch,
   batches of 64), on torch and on ONNX Runtime at the default batch, and on ONNX Runtime asked
   only about the crops whose segment's shape does not decide
   (:meth:`~guardrail_core.extract.classify.crop_classifier.GuardrailClassifier.shape_decides`),
   with the number of segments whose label differs from the reference's.
"""

from __future__ import annotations

import argparse
import copy
import functools
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from guardrail_core.extract.classify.backbone import (  # noqa: E402
    CropEmbedder,
    load_backbone,
    normalise,
    pooled_features,
)
from guardrail_core.extract.classify.cnn_runtime import (  # noqa: E402
    BATCH_SIZE,
    CropNetwork,
    export_onnx,
    onnx_runtime_installed,
)
from guardrail_core.extract.classify.crop_classifier import GuardrailClassifier  # noqa: E402
from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR, load_model  # noqa: E402

Embed = Callable[[np.ndarray], np.ndarray]  # (B, S, S, 3) uint8 -> (B, 1280) float32


def drive_crops(drive: Path, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A drive's crops (K, S, S, 3) uint8, which of its M segments have them (M,) bool, and the
    segments' features (M, F)."""
    from guardrail_core.extract.pipeline import extract, segment_crops
    from guardrail_core.formats.drive import load_drive
    from guardrail_core.formats.run_folder import CROP_OK

    loaded = load_drive(drive, with_truth=False)
    result = extract(loaded)
    has_crop = result.choice.status == CROP_OK
    crops = segment_crops(loaded, result.choice, np.flatnonzero(has_crop), size)
    return crops, has_crop, result.features


def torch_variants(size: int) -> dict[str, Embed]:
    """The torch ways tried: eager (the reference), channels-last, traced + frozen."""
    embedder = CropEmbedder(load_backbone()).eval()
    channels_last = copy.deepcopy(embedder).to(memory_format=torch.channels_last)
    example = torch.zeros((8, size, size, 3), dtype=torch.uint8)
    with torch.no_grad():
        jit = torch.jit.optimize_for_inference(
            torch.jit.freeze(torch.jit.trace(copy.deepcopy(embedder), example))
        )

    def run(module: torch.nn.Module) -> Embed:
        def embed(batch: np.ndarray) -> np.ndarray:
            with torch.inference_mode():
                return module(torch.from_numpy(batch)).numpy()

        return embed

    return {
        "torch": run(embedder),
        "torch-channels-last": run(channels_last),
        "torch-jit": run(jit),
    }


def onnx_variants(size: int) -> tuple[dict[str, Embed], dict[str, float]]:
    """ONNX Runtime (and OpenVINO on the same exported model, when installed), with the seconds
    of the export and of making each session."""
    out: dict[str, Embed] = {}
    setup: dict[str, float] = {}
    if not onnx_runtime_installed():
        return out, setup
    module = CropEmbedder(load_backbone()).eval()
    network = CropNetwork(module, size, (1280,), runtime="onnxruntime")
    start = time.process_time()
    network(np.zeros((1, size, size, 3), np.uint8))  # exports and makes the session
    setup["onnxruntime_export_and_session_cpu_s"] = time.process_time() - start
    out["onnxruntime"] = lambda batch: network(batch, batch_size=len(batch))
    try:
        import openvino
    except ImportError:
        return out, setup
    start = time.process_time()
    compiled = openvino.Core().compile_model(
        openvino.Core().read_model(model=export_onnx(module, size)),
        "CPU",
        {"INFERENCE_NUM_THREADS": 1, "NUM_STREAMS": 1, "INFERENCE_PRECISION_HINT": "f32"},
    )
    request = compiled.create_infer_request()
    setup["openvino_export_and_compile_cpu_s"] = time.process_time() - start
    out["openvino"] = lambda batch: np.array(request.infer({0: batch})[0])
    return out, setup


def timed(fn: Callable[[], object], repeats: int) -> tuple[float, float, object]:
    """Median CPU and wall seconds of ``repeats`` calls, and the last result."""
    cpu, wall, result = [], [], None
    for _ in range(repeats):
        c, w = time.process_time(), time.perf_counter()
        result = fn()
        cpu.append(time.process_time() - c)
        wall.append(time.perf_counter() - w)
    return statistics.median(cpu), statistics.median(wall), result


def in_batches(embed: Embed, crops: np.ndarray, batch_size: int) -> np.ndarray:
    return np.concatenate(
        [embed(crops[i : i + batch_size]) for i in range(0, len(crops), batch_size)]
    )


def breakdown(
    model: GuardrailClassifier, crops: np.ndarray, features: np.ndarray, repeats: int
) -> dict[str, float]:
    """Milliseconds per crop (per segment for the segment head) of each part, on torch."""
    net = load_backbone()
    batch = torch.from_numpy(np.ascontiguousarray(crops[:16]))
    with torch.inference_mode():
        x = normalise(batch)
        pre, _, _ = timed(lambda: normalise(batch), repeats * 10)
        cnn, _, _ = timed(lambda: pooled_features(net, x), repeats)
        embeddings = pooled_features(net, x).numpy()
    head, _, _ = timed(lambda: model.predict_proba(embeddings=embeddings), repeats * 10)
    crop_proba = np.full(len(features), 0.5)
    segment, _, _ = timed(lambda: model.segment_proba(features, crop_proba), repeats * 10)
    n = len(batch)
    return {
        "normalise_ms_per_crop": 1000 * pre / n,
        "backbone_ms_per_crop": 1000 * cnn / n,
        "fast_head_ms_per_crop": 1000 * head / n,
        "segment_head_ms_per_segment": 1000 * segment / max(len(features), 1),
    }


def classify_stage(
    model: GuardrailClassifier,
    crops: np.ndarray,
    has_crop: np.ndarray,
    features: np.ndarray,
    runtime: str,
    *,
    batch_size: int = BATCH_SIZE,
    gate: bool = False,
) -> tuple[float, float, np.ndarray, int]:
    """CPU and wall seconds of the classify stage, the segments' labels and the crops run.

    ``crops`` (K, S, S, 3) belong to the segments where ``has_crop`` (M,) is True; with ``gate``
    the CNN sees only those whose shape does not decide, and the rest get an undecided 0.5."""
    c, w = time.process_time(), time.perf_counter()
    crop_proba = np.full(len(features), np.nan)
    ask = has_crop.copy()
    if gate:
        decided = model.shape_decides(features)
        crop_proba[has_crop & decided] = 0.5
        ask &= ~decided
    asked = ask[has_crop]
    embeddings = model.embed(crops[asked], batch_size=batch_size, runtime=runtime)
    crop_proba[ask] = model.predict_proba(embeddings=embeddings)
    labels = model.segment_proba(features, crop_proba) >= model.threshold
    return time.process_time() - c, time.perf_counter() - w, labels, int(asked.sum())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drive", type=Path, default=Path("demo_output/sample_drive"))
    parser.add_argument("--crops", type=Path, help="an .npz of --save-crops (skips the drive)")
    parser.add_argument("--save-crops", type=Path, help="keep the drive's crops in this .npz")
    parser.add_argument("--limit", type=int, default=512, help="crops timed (the first ones)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--batch-sizes", default="1,8,16,64")
    parser.add_argument("--stage", action="store_true", help="also time the classify stage")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)

    model = load_model(DEFAULT_MODEL_DIR)
    size = model.input_size
    if args.crops:
        with np.load(args.crops) as saved:
            crops, has_crop, features = saved["crops"], saved["has_crop"], saved["features"]
    else:
        crops, has_crop, features = drive_crops(args.drive, size)
        if args.save_crops:
            np.savez(args.save_crops, crops=crops, has_crop=has_crop, features=features)
    stage = []
    if args.stage:
        cases = [("torch, batch 64 (before)", "torch", 64, False), ("torch", "torch", 16, False)]
        if onnx_runtime_installed():
            cases += [("onnxruntime", "onnxruntime", 16, False)]
            cases += [("onnxruntime, shape first", "onnxruntime", 16, True)]
        reference = None
        for name, runtime, batch_size, gate in cases:
            cpu, wall, labels, asked = classify_stage(
                model, crops, has_crop, features, runtime, batch_size=batch_size, gate=gate
            )
            reference = labels if reference is None else reference
            stage.append(
                {
                    "case": name,
                    "cpu_s": cpu,
                    "wall_s": wall,
                    "crops_run": asked,
                    "labels_differ": int((labels != reference).sum()),
                }
            )
    all_crops = len(crops)
    crops = np.ascontiguousarray(crops[: args.limit])
    sizes = [int(b) for b in args.batch_sizes.split(",")]

    variants = torch_variants(size)
    onnx, setup = onnx_variants(size)
    variants |= onnx
    reference = in_batches(variants["torch"], crops, 16)
    reference_proba = model.predict_proba(embeddings=reference)
    rows = []
    for name, embed in variants.items():
        for batch_size in sizes:
            run = functools.partial(in_batches, embed, crops, batch_size)
            cpu, wall, out = timed(run, args.repeats)
            embeddings = np.asarray(out)
            proba = model.predict_proba(embeddings=embeddings)
            rows.append(
                {
                    "runtime": name,
                    "batch_size": batch_size,
                    "crops_per_s_cpu": len(crops) / cpu,
                    "crops_per_s_wall": len(crops) / wall,
                    "ms_per_crop_cpu": 1000 * cpu / len(crops),
                    "max_embedding_diff": float(np.abs(embeddings - reference).max()),
                    "max_probability_diff": float(np.abs(proba - reference_proba).max()),
                    "labels_differ": int(
                        ((proba > model.threshold) != (reference_proba > model.threshold)).sum()
                    ),
                }
            )
    parts = breakdown(model, crops, features, args.repeats)
    best_torch = max(
        (r for r in rows if r["runtime"] == "torch"), key=lambda r: r["crops_per_s_cpu"]
    )
    best = max(rows, key=lambda r: r["crops_per_s_cpu"])
    result = {
        "source": str(args.crops or args.drive),
        "crops_in_source": all_crops,
        "segments_in_source": len(features),
        "crops_timed": len(crops),
        "input_size_px": size,
        "threads": torch.get_num_threads(),
        "repeats": args.repeats,
        "rows": rows,
        "torch_parts": parts,
        "classify_stage": stage,
        "setup": setup,
        "fastest": {
            "runtime": best["runtime"],
            "batch_size": best["batch_size"],
            "speedup_over_best_torch": best["crops_per_s_cpu"] / best_torch["crops_per_s_cpu"],
        },
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(
        f"{len(crops)} of the {all_crops} crops of {result['source']} ({size} px), one thread, "
        f"median of {args.repeats}"
    )
    print(
        f"{'runtime':<20} {'batch':>5} {'crops/s cpu':>11} {'wall':>7} {'ms/crop':>8} "
        f"{'max |d emb|':>11} {'max |d P|':>9} {'labels':>6}"
    )
    for r in rows:
        print(
            f"{r['runtime']:<20} {r['batch_size']:>5} {r['crops_per_s_cpu']:>11.1f} "
            f"{r['crops_per_s_wall']:>7.1f} {r['ms_per_crop_cpu']:>8.2f} "
            f"{r['max_embedding_diff']:>11.1e} {r['max_probability_diff']:>9.1e} "
            f"{r['labels_differ']:>6}"
        )
    print(
        f"torch, ms per crop: normalise {parts['normalise_ms_per_crop']:.3f}, backbone "
        f"{parts['backbone_ms_per_crop']:.2f}, fast head {parts['fast_head_ms_per_crop']:.4f}; "
        f"segment head {parts['segment_head_ms_per_segment']:.5f} ms per segment"
    )
    if setup:
        print("one-off: " + ", ".join(f"{k} {v:.2f}" for k, v in setup.items()))
    if stage:
        print(f"classify stage, {all_crops} crops of {len(features)} segments:")
        for r in stage:
            print(
                f"  {r['case']:<26} {r['cpu_s']:7.1f} s cpu {r['wall_s']:7.1f} s wall, "
                f"{r['crops_run']} crops run, {r['labels_differ']} labels differ"
            )
    fastest = result["fastest"]
    print(
        f"fastest: {fastest['runtime']} at batch {fastest['batch_size']}, "
        f"{fastest['speedup_over_best_torch']:.2f}x torch at its best batch size"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
