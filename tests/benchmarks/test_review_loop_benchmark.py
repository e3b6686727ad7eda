"""``benchmarks/review_loop.py`` runs from the shipped default model, with no ``--model``: it
processes the drive with it and fine-tunes from it, as an operator's Train does."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from guardrail_core.evaluate.detection import detection_metrics
from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR
from guardrail_core.extract.segment_truth import segment_truth
from guardrail_core.formats.drive import Drive
from guardrail_core.formats.run_folder import load_run
from tests.kitti_data import KITTI_SEQ01, require_kitti

ROOT = Path(__file__).resolve().parents[2]


def test_the_learning_curve_from_the_shipped_model(
    drive_path: Path, drive: Drive, shipped_run_path: Path
) -> None:
    command = [
        sys.executable,
        str(ROOT / "benchmarks" / "review_loop.py"),
        str(drive_path),
        "--labels",
        "0,10,20",
        "--workers",
        "1",
        "--json",
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=1200, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout)
    assert Path(out["model"]) == DEFAULT_MODEL_DIR

    # The benchmark's run is the one `guardrail process` makes with the shipped model: with no
    # label yet, both orders measure its labels against the truth.
    run = load_run(shipped_run_path)
    assert drive.truth is not None
    truth = segment_truth(drive.truth.point_class, run.point_segment, len(run))
    assert out["segments"] == len(run) and out["guardrail_segments"] == int(truth.sum())
    shipped_f1 = detection_metrics(truth, run.segments["label"]).guardrail.f1
    for order in ("queue", "random"):
        curve = out[order]
        assert curve["labels"] == [0, 10, 20]
        assert curve["guardrail_f1"][0] == round(float(shipped_f1), 4)
        assert all(0.0 <= f <= 1.0 for f in curve["guardrail_f1"] + curve["guardrail_f1_points"])
        assert np.isfinite(curve["seconds"]).all()


def test_the_learning_curve_on_a_real_frame(tmp_path: Path) -> None:
    """The review loop on the KITTI motorway frame, truth from its hand labels: the frame has no
    image, so each fine-tuning keeps the crop classifier and trains the segment head."""
    require_kitti(KITTI_SEQ01)
    from guardrail_core.importers.kitti import import_kitti

    import_kitti(KITTI_SEQ01, tmp_path / "drive", frames=[280])
    command = [
        sys.executable,
        str(ROOT / "benchmarks" / "review_loop.py"),
        str(tmp_path / "drive"),
        "--frame-labels",
        str(ROOT / "tests" / "data" / "real_frames" / "kitti01_000280.npz"),
        "--labels",
        "0,10",
        "--order",
        "queue",
        "--workers",
        "1",
        "--json",
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=1200, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    curve = json.loads(done.stdout)["queue"]
    assert curve["labels"] == [0, 10]
    # With no label yet the whole frame is measured: what benchmarks/real_frames.py reports for
    # the shipped model (75.0 % of the metres, 3.8 % off on 2026-12-07).
    assert 0.7 <= curve["metres_found"][0] <= 0.8
    assert 0.0 < curve["off_guardrail"][0] <= 0.05
    assert all(0.0 <= f <= 1.0 for f in curve["metres_found"] + curve["off_guardrail"])
