"""Metrics against the truth: the paper's Table 1 (segments per class) and Table 2 (recall,
precision, F-measure per class), before and after label correction."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from guardrail_core.classes import GUARDRAIL_CLASSES
from guardrail_core.errors import MissingDriveFileError, RunFolderError
from guardrail_core.evaluate.reconstruction import PolePointCounter, evaluate_reconstruction
from guardrail_core.evaluate.results import (
    ClassCounts,
    ClassMetrics,
    DetectionMetrics,
    EvaluationResult,
    PointMetrics,
    ReconstructionEvaluation,
)
from guardrail_core.formats.drive import Drive, open_drive
from guardrail_core.formats.run_folder import CROP_STATUS_NAMES, Run
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.reconstruct.run_models import load_run_models


def detection_metrics(truth: np.ndarray, predicted: np.ndarray) -> DetectionMetrics:
    """Recall, precision and F-measure of both classes (Table 2), with the true counts.

    Parameters
    ----------
    truth, predicted : (S,) bool, True for guardrail
    """
    truth, predicted = np.asarray(truth, bool), np.asarray(predicted, bool)
    return DetectionMetrics(
        guardrail=_class_metrics(truth, predicted), other=_class_metrics(~truth, ~predicted)
    )


def _class_metrics(truth: np.ndarray, predicted: np.ndarray) -> ClassMetrics:
    tp = int((truth & predicted).sum())
    n_true, n_predicted = int(truth.sum()), int(predicted.sum())
    recall = tp / n_true if n_true else float("nan")
    precision = tp / n_predicted if n_predicted else float("nan")
    f1 = 2 * recall * precision / (recall + precision) if recall + precision > 0 else 0.0
    return ClassMetrics(recall, precision, f1, n_true, n_predicted)


def evaluate_run(drive: Drive, run: Run) -> EvaluationResult:
    """Compare a run's segment labels with the drive's truth (a drive held in memory; see
    :func:`evaluate_run_folder` for one read tile by tile).

    Returns
    -------
    Table 1's counts (segments, and by crop status), Table 2 after and before label correction,
    guardrail point recall and precision after correction, and the reconstruction against the
    truth (:func:`~guardrail_core.evaluate.reconstruction.evaluate_reconstruction`) when the run
    has one.

    Raises
    ------
    MissingDriveFileError
        The drive has no truth (only synthetic drives do).
    RunFolderError
        The run was made from a drive with another number of points, or its reconstruction
        cannot be read (another format version, damaged).
    """
    if drive.truth is None:
        raise MissingDriveFileError(
            f"{drive.root}: no truth/ folder, so there is nothing to evaluate against"
        )
    if len(run.point_segment) != len(drive.points):
        raise RunFolderError(
            f"{run.root}: made from a drive of {len(run.point_segment)} points, but "
            f"{drive.root} has {len(drive.points)}"
        )
    tally = _Tally(run.segments, drive.truth.objects)
    tally.add(
        drive.truth.point_class, drive.truth.point_object, drive.points.xyz, run.point_segment
    )
    return tally.result(run.folder)


def evaluate_run_folder(drive_root: str | Path, run_root: str | Path) -> EvaluationResult:
    """:func:`evaluate_run` reading the drive and the run tile by tile, so memory stays flat at
    any drive length.

    Raises
    ------
    MissingDriveFileError, RunFolderError
        As :func:`evaluate_run`; also a drive with other tiles than the run was made from.
    """
    source = open_drive(drive_root)
    folder = RunFolder.open(run_root)
    if not source.has_truth:
        raise MissingDriveFileError(
            f"{source.root}: no truth/ folder, so there is nothing to evaluate against"
        )
    info = folder.info()
    if info.drive.points != source.tiles.points or info.drive.tiles != len(source.tiles):
        raise RunFolderError(
            f"{folder.root}: made from a drive of {info.drive.points} points in "
            f"{info.drive.tiles} tiles, but {source.root} has {source.tiles.points} in "
            f"{len(source.tiles)}"
        )
    tally = _Tally(folder.segments(), source.objects)
    for t in range(len(source.tiles)):
        points, truth = source.read_tiles([t])
        assert truth is not None  # has_truth
        segment = folder.point_segment_tile(t)
        if len(segment) != len(points):
            raise RunFolderError(
                f"{folder.point_tile_path(t)}: {len(segment)} points, the drive's tile has "
                f"{len(points)}"
            )
        tally.add(truth.point_class, truth.point_object, points.xyz, segment)
    return tally.result(folder)


class _Tally:
    """Counts of a run against the truth, added up tile by tile."""

    def __init__(self, segments: dict[str, np.ndarray], objects: list[dict]) -> None:
        self.segments = segments
        self.objects = objects
        n = len(segments["n_points"])
        self.guardrail_in_segment = np.zeros(n, np.int64)
        self.points_in_segment = np.zeros(n, np.int64)
        self.true_points = self.predicted_points = self.true_positive = 0
        self.pole_points = PolePointCounter(objects)

    def add(
        self,
        point_class: np.ndarray,
        point_object: np.ndarray,
        xyz: np.ndarray,
        point_segment: np.ndarray,
    ) -> None:
        """Add (n,) classes, object ids, (n, 3) points and segments of a piece of the drive."""
        n = len(self.points_in_segment)
        point_guardrail = np.isin(point_class, list(GUARDRAIL_CLASSES))
        in_segment = point_segment >= 0
        segment = point_segment[in_segment]
        self.guardrail_in_segment += np.bincount(
            segment, weights=point_guardrail[in_segment], minlength=n
        ).astype(np.int64)
        self.points_in_segment += np.bincount(segment, minlength=n)
        point_label = np.zeros(len(point_guardrail), bool)
        point_label[in_segment] = self.segments["label"][segment]
        self.true_positive += int((point_guardrail & point_label).sum())
        self.true_points += int(point_guardrail.sum())
        self.predicted_points += int(point_label.sum())
        self.pole_points.add(xyz, point_object)

    def result(self, folder: RunFolder) -> EvaluationResult:
        # Table 1's true class: guardrail where most of a segment's points are.
        truth = 2 * self.guardrail_in_segment > self.points_in_segment
        raw, label = self.segments["raw_label"], self.segments["label"]
        status = self.segments["crop_status"]
        reconstruction = None
        if folder.reconstruction.exists():
            runs = load_run_models(folder).runs
            in_view = self.pole_points.units_in_view()
            reconstruction = evaluate_reconstruction(list(runs), self.objects, in_view=in_view)
        return EvaluationResult(
            segments=ClassCounts(guardrail=int(truth.sum()), other=int((~truth).sum())),
            n_segments=len(truth),
            crops={
                name: ClassCounts(
                    guardrail=int((truth & (status == code)).sum()),
                    other=int((~truth & (status == code)).sum()),
                )
                for code, name in CROP_STATUS_NAMES.items()
            },
            detection=detection_metrics(truth, label),
            detection_raw=detection_metrics(truth, raw),
            points=PointMetrics(
                recall=self.true_positive / max(self.true_points, 1),
                precision=self.true_positive / max(self.predicted_points, 1),
                n_true=self.true_points,
            ),
            reconstruction=reconstruction,
        )


def format_report(result: EvaluationResult) -> str:
    """The evaluation as the paper's two tables, plain text."""
    lines = [
        "Table 1. Sliced segments (true class = majority of points)",
        f"  {'':14s}{'segments':>10s}{'with crop':>11s}{'no image':>10s}{'too small':>11s}",
    ]
    crops = result.crops
    for name in ("guardrail", "other"):
        lines.append(
            f"  {name:14s}{getattr(result.segments, name):>10d}"
            f"{getattr(crops['ok'], name):>11d}{getattr(crops['no_image'], name):>10d}"
            f"{getattr(crops['too_small'], name):>11d}"
        )
    for title, metrics in (
        ("Table 2. Classification, after label correction", result.detection),
        ("Table 2 (raw). Classification, before label correction", result.detection_raw),
    ):
        lines += ["", title, f"  {'':14s}{'Recall':>9s}{'Precision':>11s}{'F-measure':>11s}"]
        for name in ("guardrail", "other"):
            m: ClassMetrics = getattr(metrics, name)
            lines.append(
                f"  {name:14s}{_pct(m.recall):>9s}{_pct(m.precision):>11s}{_pct(m.f1):>11s}"
            )
    pts = result.points
    lines += [
        "",
        f"Guardrail points: recall {_pct(pts.recall)}, precision {_pct(pts.precision)} "
        f"of {pts.n_true} true guardrail points",
    ]
    if result.reconstruction is not None:
        lines += ["", *format_reconstruction(result.reconstruction)]
    return "\n".join(lines)


def format_reconstruction(rec: ReconstructionEvaluation) -> list[str]:
    """The reconstruction figures as a table: one row per design and one overall."""
    lines = [
        "Reconstruction (pipes of the unit shape; errors of found pipes; mm)",
        f"  {'design':16s}{'pipes':>8s}{'in view':>9s}{'radius':>8s}{'axis':>7s}{'beam':>7s}"
        f"{'poles':>10s}{'pole pos':>10s}{'unit len':>10s}",
    ]
    rows = [*rec.designs.items(), ("overall", rec.overall)]
    for name, f in rows:
        pipes = f"{f.pipes_found}/{f.pipes_total}" if f.pipes_total else "-"
        seen = str(f.pipes_in_view) if f.pipes_total else "-"
        lines.append(
            f"  {name:16s}{pipes:>8s}{seen:>9s}{_mm(f.radius_err_mm_median):>8s}"
            f"{_mm(f.axis_dev_mm_mean):>7s}{_mm(f.beam_section_hausdorff_mm):>7s}"
            f"{f.poles_found:>5d}/{f.poles_total:<4d}{_mm(f.pole_pos_err_mm_median):>10s}"
            f"{_mm(f.unit_length_err_mm_median):>10s}"
        )
    overall = rec.overall
    lines.append(
        "  in view: pipes of the guardrails with a unit whose two poles were scanned "
        f"({overall.guardrails_in_view} of {overall.guardrails_total} guardrails)"
    )
    lines.append(
        "  radius: median error; axis: mean deviation; beam: section Hausdorff; pole pos and "
        "unit len: median errors"
    )
    return lines


def _mm(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def _pct(value: float) -> str:
    return "n/a" if np.isnan(value) else f"{100 * value:.1f}%"
