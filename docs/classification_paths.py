"""Each classification path's figure on held-out synthetic drives: the crop CNN alone, the
geometry alone (the segment head with every crop withheld) and the two fused (the segment head
with the crops, as `guardrail process` runs it).

    .venv/bin/python docs/classification_paths.py --model MODEL_DIR DRIVE [DRIVE ...]

Prints a Markdown table of guardrail recall, precision and F per path and drive kind (profile
scanner with cameras, multi-beam scanner), before and after label correction, and writes the
figures as JSON with ``--json``. Segment truth is the majority class of a segment's points, as
`guardrail evaluate` counts it.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from guardrail_core.extract.classify.crop_classifier_training import classification_metrics
from guardrail_core.extract.classify.label_correction import correct_labels
from guardrail_core.extract.classify.model_folder import load_model
from guardrail_core.extract.crops import CROP_OK
from guardrail_core.extract.pipeline import ExtractionParams, extract, segment_crops
from guardrail_core.extract.segment_truth import segment_truth
from guardrail_core.formats.drive import load_drive

PATHS = ("crop CNN alone", "geometry alone", "fused")


def path_labels(drive_path: Path, model, params: ExtractionParams) -> tuple[str, dict]:
    """The drive's kind and, per path, (truth, raw label, corrected label) of every segment."""
    drive = load_drive(drive_path)
    result = extract(drive, params)
    truth = segment_truth(drive.truth.point_class, result.point_segment, len(result.segments))
    ok = np.flatnonzero(result.choice.status == CROP_OK)
    crop_proba = np.full(len(result.segments), np.nan)
    if len(ok):
        crops = segment_crops(drive, result.choice, ok, model.input_size, params.crops)
        crop_proba[ok] = model.predict_proba(crops)
    withheld = np.full(len(result.segments), np.nan)
    probability = {
        # Without a crop the CNN has no answer: the segment counts as not guardrail.
        "crop CNN alone": np.nan_to_num(crop_proba, nan=0.0),
        "geometry alone": model.segment_proba(result.features, withheld),
        "fused": model.segment_proba(result.features, crop_proba),
    }
    out = {}
    for name, p in probability.items():
        raw = p >= model.threshold
        out[name] = (truth, raw, correct_labels(raw, result.extents(), params.correction, p))
    kind = drive.scanner.kind if drive.images else f"{drive.scanner.kind}, no images"
    return kind, out


def _percent(value: float | None) -> str:
    """A share as a percentage; a dash where it is undefined (no guardrail called at all)."""
    return "-" if value is None else f"{100 * value:.1f}%"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("drives", type=Path, nargs="+")
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--json", type=Path, help="write the figures here too")
    args = parser.parse_args()
    model = load_model(args.model)
    pooled: dict[tuple[str, str, str], list[np.ndarray]] = defaultdict(list)
    for path in args.drives:
        kind, labels = path_labels(path, model, ExtractionParams())
        for name, (truth, raw, corrected) in labels.items():
            pooled[(kind, name, "truth")].append(truth)
            pooled[(kind, name, "raw")].append(raw)
            pooled[(kind, name, "corrected")].append(corrected)
    figures = {}
    print("| drives | path | segments | recall | precision | F (raw) | F (corrected) |")
    print("|---|---|---|---|---|---|---|")
    for kind in sorted({k for k, _, _ in pooled}):
        for name in PATHS:
            truth = np.concatenate(pooled[(kind, name, "truth")])
            raw = classification_metrics(truth, np.concatenate(pooled[(kind, name, "raw")]))
            fixed = classification_metrics(truth, np.concatenate(pooled[(kind, name, "corrected")]))
            figures[f"{kind} / {name}"] = {"raw": raw, "corrected": fixed}
            print(
                f"| {kind} | {name} | {len(truth)} | {_percent(fixed['guardrail']['recall'])} | "
                f"{_percent(fixed['guardrail']['precision'])} | {_percent(raw['guardrail']['f1'])} "
                f"| {_percent(fixed['guardrail']['f1'])} |"
            )
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2, default=float))


if __name__ == "__main__":
    main()
