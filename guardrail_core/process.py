"""``guardrail process``: a drive through extraction (§3) and reconstruction (§4) into one run folder."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from guardrail_core.extract.classify import EMBEDDING_DIM, GuardrailClassifier
from guardrail_core.extract.correct import correct_labels
from guardrail_core.extract.pipeline import ExtractionParams, extract
from guardrail_core.formats.atomic import staged_folder
from guardrail_core.formats.drive import Drive, drive_parts
from guardrail_core.formats.run_folder import (
    CROP_OK,
    CROP_STATUS_NAMES,
    POINT_OFF_ROAD,
    POINT_ROAD,
    RUN_FORMAT_VERSION,
    write_run_files,
)
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.formats.run_info import CropCounts, DriveRef, ModelRef, RunCounts, RunInfo
from guardrail_core.reconstruct.pipeline import ReconstructionParams, reconstruct_into
from guardrail_core.timing import StageTimer


def process_drive(
    drive: Drive,
    model: GuardrailClassifier,
    out: Path,
    *,
    params: ExtractionParams = ExtractionParams(),
    reconstruction: ReconstructionParams | None = ReconstructionParams(),
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
    progress: bool = False,
) -> RunInfo:
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
    inputs : further inputs besides the drive's parts (the model folder), which ``out`` must
        not be, hold, or replace
    progress : show progress bars

    Returns
    -------
    The run's ``run.json`` content (counts, model, parameters), with ``reconstruction``: the
    summary of :func:`guardrail_core.reconstruct.pipeline.reconstruct_into` (when reconstructed;
    run.json itself does not hold it).

    Raises
    ------
    OutputExistsError
        ``out`` exists, is not empty and ``overwrite`` is False.
    InputInsideOutputError
        ``out`` is, holds or would replace a part of the drive or another input; raised before
        any work.

    References
    ----------
    Matsumoto et al. 2019, §3 (Fig. 3) and §4.
    """
    out = Path(out)
    started = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    sources = [*drive_parts(drive.root), *inputs]
    with staged_folder(out, overwrite=overwrite, inputs=sources) as staging:
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
            folder = RunFolder(staging)
            folder.crops_dir.mkdir()
            for s in ok:
                cv2.imwrite(
                    str(folder.crop_path(int(s))),
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
            image_files = [record.file for record in drive.images]
            info = RunInfo(
                format_version=RUN_FORMAT_VERSION,
                created=started,
                drive=DriveRef(path=str(Path(drive.root).resolve()), points=len(drive.points)),
                model=ModelRef(version=model.version, mode=model.mode, threshold=model.threshold),
                params=params.to_json(),
                counts=RunCounts(
                    points=len(drive.points),
                    road_points=int((result.point_segment == POINT_ROAD).sum()),
                    off_road_points=int((result.point_segment == POINT_OFF_ROAD).sum()),
                    segment_points=int(segments.n_points.sum()),
                    segments=len(segments),
                    crops=CropCounts(**status_counts),
                    guardrail_segments_raw=int(raw_label.sum()),
                    guardrail_segments=int(label.sum()),
                    guardrail_points=int(segments.n_points[label].sum()),
                ),
                images=tuple(image_files),
            )
            write_run_files(
                staging,
                info=info.to_json(),
                point_segment=result.point_segment,
                segments=table,
                timings=timer.as_json(),
                image_files=image_files,
                embeddings=embeddings,
            )
        if reconstruction is not None:
            with timer.stage("reconstruct", points=int(segments.n_points[label].sum())):
                reconstructed = reconstruct_into(
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
            info = dataclasses.replace(info, reconstruction=reconstructed)
        # The write stage's own time is known only now: rewrite timings.json with it.
        folder.timings_file.write_text(json.dumps(timer.as_json(), indent=2) + "\n")
    return info
