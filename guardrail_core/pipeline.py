"""Runs the extraction stages (§3) in order, records their timings, writes the run folder."""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from guardrail_core.drive import Drive, atomic_folder, commit_folder
from guardrail_core.errors import EmptyDriveError
from guardrail_core.extract.classify import EMBEDDING_DIM, GuardrailClassifier
from guardrail_core.extract.correct import CorrectionParams, SegmentExtents, correct_labels
from guardrail_core.extract.crops import (
    CROP_OK,
    CROP_STATUS_NAMES,
    CropChoice,
    CropParams,
    choose_images,
    cut_crops,
)
from guardrail_core.extract.lattice import build_lattice
from guardrail_core.extract.road import OFF_ROAD, ROAD, RoadParams, remove_road
from guardrail_core.extract.segments import (
    SegmentParams,
    Segments,
    SegmentSummary,
    absorb_fragments,
    slice_components,
    summarise_segments,
    wireframe_components,
)
from guardrail_core.extract.shape_features import segment_features
from guardrail_core.extract.track import track_coordinates
from guardrail_core.reconstruction import ReconstructionParams, reconstruct_into
from guardrail_core.run_folder import POINT_OFF_ROAD, POINT_ROAD, crop_name, write_run_files
from guardrail_core.timing import StageTimer


@dataclass(frozen=True)
class ExtractionParams:
    """The parameters of every extraction stage."""

    road: RoadParams = field(default_factory=RoadParams)
    segments: SegmentParams = field(default_factory=SegmentParams)
    crops: CropParams = field(default_factory=CropParams)
    correction: CorrectionParams = field(default_factory=CorrectionParams)

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class Extraction:
    """Sliced segments of a drive and their crops (everything before the classifier).

    Attributes
    ----------
    point_segment : (N,) int32, segment of every point, POINT_ROAD or POINT_OFF_ROAD
    segments : the sliced segments
    summary : their extents
    features : (S, SEGMENT_FEATURE_DIM) float32, shape and neighbour features
        (:mod:`guardrail_core.extract.shape_features`)
    choice : chosen image and rectangle per segment
    crops : (S, size, size, 3) uint8 RGB, black where there is no crop
    """

    point_segment: np.ndarray
    segments: Segments
    summary: SegmentSummary
    features: np.ndarray
    choice: CropChoice
    crops: np.ndarray

    def extents(self) -> SegmentExtents:
        return segment_extents(self.segments, self.summary)


def segment_extents(segments: Segments, summary: SegmentSummary) -> SegmentExtents:
    return SegmentExtents(segments.slice_index, summary.lateral, summary.height)


def slice_drive(
    drive: Drive, params: ExtractionParams = ExtractionParams(), *, timer: StageTimer | None = None
) -> tuple[np.ndarray, Segments, SegmentSummary, np.ndarray]:
    """The geometric stages of §3.1: road removal, wireframe components (fragments joined to
    their neighbours), 0.5 m slices, and the segments' shape features.

    Returns ``point_segment`` (N,) int32 (segment, POINT_ROAD or POINT_OFF_ROAD), the segments,
    their summary and their (S, SEGMENT_FEATURE_DIM) float32 features.

    Raises
    ------
    EmptyDriveError
        The drive has no points.
    """
    timer = timer or StageTimer(len(drive.points))
    points = drive.points
    n = len(points)
    if n == 0:
        raise EmptyDriveError(f"{drive.root}: the drive has no points")
    with timer.stage("track", points=n):
        track = track_coordinates(points.xyz, points.gps_time, drive.trajectory)
    with timer.stage("lattice", points=n):
        lattice = build_lattice(points.rotation, points.phase, drive.scanner.points_per_rotation)
    with timer.stage("road_removal", points=n):
        status = remove_road(points.xyz, track, lattice, params.road)
        kept = status == 0
    with timer.stage("components", points=int(kept.sum())):
        component = wireframe_components(points.xyz, kept, lattice, params.segments)
        component = absorb_fragments(points.xyz, component, params.segments)
    with timer.stage("slices", points=int(kept.sum())):
        segments = slice_components(component, track.station, params.segments, track.lateral)
        summary = summarise_segments(
            points.xyz, points.gps_time, track.lateral, track.height, segments
        )
    with timer.stage("features", points=int(kept.sum())):
        features = segment_features(
            track.station,
            track.lateral,
            track.height,
            points.intensity,
            segments,
            segment_extents(segments, summary),
            params.segments.slice_length_m,
            params.correction,
        )
    point_segment = segments.point_segment.copy()
    point_segment[status == ROAD] = POINT_ROAD
    point_segment[status == OFF_ROAD] = POINT_OFF_ROAD
    return point_segment, segments, summary, features


def extract(
    drive: Drive,
    crop_size: int,
    params: ExtractionParams = ExtractionParams(),
    *,
    timer: StageTimer | None = None,
    progress: bool = False,
) -> Extraction:
    """Slice a drive (§3.1) and crop every segment's image (§3.2) at ``crop_size`` pixels."""
    timer = timer or StageTimer(len(drive.points))
    point_segment, segments, summary, features = slice_drive(drive, params, timer=timer)
    with timer.stage("crops", points=int(segments.n_points.sum())):
        with tqdm(
            total=len(drive.images), desc="choosing images", unit="image", disable=not progress
        ) as bar:
            choice = choose_images(
                drive.points.xyz,
                segments,
                summary,
                drive.images,
                drive.cameras,
                params.crops,
                progress=bar.update,
            )
        n_ok = int((choice.status == CROP_OK).sum())
        with tqdm(total=n_ok, desc="cutting crops", unit="crop", disable=not progress) as bar:
            crops = cut_crops(
                lambda i: drive.read_image(drive.images[i]),
                choice,
                crop_size,
                params.crops,
                progress=bar.update,
            )
    return Extraction(point_segment, segments, summary, features, choice, crops)


def process_drive(
    drive: Drive,
    model: GuardrailClassifier,
    out: Path,
    *,
    params: ExtractionParams = ExtractionParams(),
    reconstruction: ReconstructionParams | None = ReconstructionParams(),
    overwrite: bool = False,
    progress: bool = False,
) -> dict[str, Any]:
    """Extract guardrail segments from a drive with a trained model, reconstruct the guardrails
    and write the run folder.

    Parameters
    ----------
    drive : the drive
    model : the trained classifier
    out : the run folder to write; written whole or not at all
    params : extraction parameters
    reconstruction : reconstruction parameters (§4); None leaves the reconstruction out
    overwrite : replace an existing run folder
    progress : show progress bars

    Returns
    -------
    The run's ``run.json`` content (counts, model, parameters), with ``reconstruction``: the
    summary of :func:`guardrail_core.reconstruction.reconstruct_into` (when reconstructed).

    References
    ----------
    Matsumoto et al. 2019, §3 (Fig. 3) and §4.
    """
    out = Path(out)
    started = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    with atomic_folder(out, overwrite=overwrite) as staging_name:
        staging = Path(staging_name)
        timer = StageTimer(len(drive.points))
        result = extract(drive, model.input_size, params, timer=timer, progress=progress)
        segments, choice = result.segments, result.choice
        ok = np.flatnonzero(choice.status == CROP_OK)

        with timer.stage("classify", points=len(segments)):
            crop_probability = np.full(len(segments), np.nan, np.float64)
            embeddings = None
            if len(ok):
                if model.mode == "fast":
                    embeddings = np.zeros((len(segments), EMBEDDING_DIM), np.float32)
                    embeddings[ok] = model.embed(result.crops[ok], progress=progress)
                    crop_probability[ok] = model.predict_proba(embeddings=embeddings[ok])
                else:
                    crop_probability[ok] = model.predict_proba(result.crops[ok], progress=progress)
            probability = model.segment_proba(result.features, crop_probability)
            raw_label = np.nan_to_num(probability, nan=0.0) >= model.threshold

        with timer.stage("correction", points=len(segments)):
            label = correct_labels(raw_label, result.extents(), params.correction)

        with timer.stage("write", points=len(segments)):
            (staging / "crops").mkdir()
            for s in ok:
                cv2.imwrite(
                    str(staging / crop_name(int(s))),
                    np.ascontiguousarray(result.crops[s][:, :, ::-1]),
                    [cv2.IMWRITE_JPEG_QUALITY, 92],
                )
            summary = result.summary
            table = {
                "component": segments.component,
                "slice_index": segments.slice_index,
                "n_points": segments.n_points,
                "centroid": summary.centroid,
                "bbox_min": summary.bbox_min,
                "bbox_max": summary.bbox_max,
                "lateral": summary.lateral,
                "height": summary.height,
                "time": summary.time,
                "image": choice.image,
                "rect": choice.rect,
                "crop_status": choice.status,
                "crop_probability": crop_probability.astype(np.float32),
                "probability": probability.astype(np.float32),
                "features": result.features,
                "raw_label": raw_label,
                "label": label,
            }
            status_counts = {
                name: int((choice.status == code).sum()) for code, name in CROP_STATUS_NAMES.items()
            }
            info = {
                "created": started,
                "drive": {"path": str(Path(drive.root).resolve()), "points": len(drive.points)},
                "model": {
                    "version": model.version,
                    "mode": model.mode,
                    "threshold": model.threshold,
                },
                "params": params.to_json(),
                "counts": {
                    "points": len(drive.points),
                    "road_points": int((result.point_segment == POINT_ROAD).sum()),
                    "off_road_points": int((result.point_segment == POINT_OFF_ROAD).sum()),
                    "segment_points": int(segments.n_points.sum()),
                    "segments": len(segments),
                    "crops": status_counts,
                    "guardrail_segments_raw": int(raw_label.sum()),
                    "guardrail_segments": int(label.sum()),
                    "guardrail_points": int(segments.n_points[label].sum()),
                },
            }
            write_run_files(
                staging,
                info=info,
                point_segment=result.point_segment,
                segments=table,
                timings=timer.as_json(),
                image_files=[record.file for record in drive.images],
                embeddings=embeddings,
            )
        if reconstruction is not None:
            with timer.stage("reconstruct", points=int(segments.n_points[label].sum())):
                info["reconstruction"] = reconstruct_into(
                    staging,
                    drive.points.xyz,
                    result.point_segment,
                    label,
                    drive.trajectory.position,
                    origin=drive.origin,
                    crs=drive.crs,
                    params=reconstruction,
                    progress=progress,
                )
        # The write stage's own time is known only now: rewrite timings.json with it.
        (staging / "timings.json").write_text(json.dumps(timer.as_json(), indent=2) + "\n")
        commit_folder(staging, out)
    return info
