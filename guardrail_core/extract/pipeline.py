"""The extraction stages (§3) in order: slicing a drive into segments and cropping their images."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from guardrail_core.errors import EmptyDriveError
from guardrail_core.extract.classify.label_correction_params import CorrectionParams
from guardrail_core.extract.classify.segment_extents import SegmentExtents
from guardrail_core.extract.classify.segment_scores import ClassifyParams
from guardrail_core.extract.classify.shape_features import segment_features
from guardrail_core.extract.crops import (
    CROP_NO_IMAGE,
    CROP_OK,
    CropChoice,
    CropParams,
    choose_images,
    cut_crops,
)
from guardrail_core.extract.curbs import separate_curbs
from guardrail_core.extract.lattice import build_lattice
from guardrail_core.extract.road import OFF_ROAD, ROAD, RoadParams, remove_road
from guardrail_core.extract.segments import (
    SegmentParams,
    Segments,
    SegmentSummary,
    absorb_fragments,
    summarise_segments,
    wireframe_components,
)
from guardrail_core.extract.slices import slice_components
from guardrail_core.formats.drive import Drive
from guardrail_core.formats.run_folder import POINT_OFF_ROAD, POINT_ROAD
from guardrail_core.params import ParameterError, StageParams, apply_settings
from guardrail_core.progress import progress_bar
from guardrail_core.sensors.track import TrackCoordinates, track_coordinates
from guardrail_core.timing import StageTimer


@dataclass(frozen=True)
class ExtractionParams(StageParams):
    """The parameters of every extraction stage, one :class:`StageParams` per stage."""

    road: RoadParams = field(default_factory=RoadParams)
    segments: SegmentParams = field(default_factory=SegmentParams)
    crops: CropParams = field(default_factory=CropParams)
    classify: ClassifyParams = field(default_factory=ClassifyParams)
    correction: CorrectionParams = field(default_factory=CorrectionParams)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ExtractionParams:
        """Parameters from :meth:`to_json` output (``run.json``'s ``params``); a stage missing
        keeps its defaults, and so does a field missing from a stage.

        Raises
        ------
        ParameterError
            An unknown stage or field, or a value the stage refuses.
        """
        if not isinstance(data, Mapping):
            raise ParameterError(f"ExtractionParams: expected an object of stages, got {data!r}")
        unknown = sorted(set(data) - set(_STAGES))
        if unknown:
            raise ParameterError(
                f"unknown extraction stage {', '.join(unknown)} (known: {', '.join(_STAGES)})"
            )
        stages: dict[str, Any] = {
            name: _STAGES[name].from_json(value) for name, value in data.items()
        }
        return cls(**stages)

    def with_settings(self, settings: Sequence[str]) -> ExtractionParams:
        """These parameters with ``STAGE.NAME=VALUE`` settings applied (``guardrail process
        --set``): see :func:`~guardrail_core.params.apply_settings`."""
        return apply_settings(self, _STAGES, settings, "extraction")


#: The stages of :class:`ExtractionParams` by field name.
_STAGES: dict[str, type[StageParams]] = {
    "road": RoadParams,
    "segments": SegmentParams,
    "crops": CropParams,
    "classify": ClassifyParams,
    "correction": CorrectionParams,
}


@dataclass(frozen=True)
class Extraction:
    """Sliced segments of a drive and the image each is cropped from (everything before the
    classifier; :func:`segment_crops` cuts the crops asked for).

    Attributes
    ----------
    point_segment : (N,) int32, segment of every point, POINT_ROAD or POINT_OFF_ROAD
    segments : the sliced segments
    summary : their extents
    features : (S, SEGMENT_FEATURE_DIM) float32, shape and neighbour features
        (:mod:`guardrail_core.extract.classify.shape_features`)
    choice : chosen image and rectangle per segment
    """

    point_segment: np.ndarray
    segments: Segments
    summary: SegmentSummary
    features: np.ndarray
    choice: CropChoice

    def extents(self) -> SegmentExtents:
        return segment_extents(self.segments, self.summary)


def segment_extents(segments: Segments, summary: SegmentSummary) -> SegmentExtents:
    return SegmentExtents(
        segments.slice_index,
        summary.lateral,
        summary.height,
        segments.component,
        segments.n_points,
    )


def slice_drive(
    drive: Drive,
    params: ExtractionParams = ExtractionParams(),
    *,
    timer: StageTimer | None = None,
    track: TrackCoordinates | None = None,
) -> tuple[np.ndarray, Segments, SegmentSummary, np.ndarray]:
    """The geometric stages of §3.1: road removal, wireframe components (fragments joined to
    their neighbours), 0.5 m slices, and the segments' shape features.

    ``track`` : the points' track coordinates where the caller has them already (a tile
    computes them to choose its points).

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
    if track is None:
        with timer.stage("track", points=n):
            track = track_coordinates(points.xyz, points.gps_time, drive.trajectory)
    with timer.stage("lattice", points=n):
        lattice = build_lattice(points.rotation, points.phase, drive.scanner.points_per_rotation)
    with timer.stage("road_removal", points=n):
        status = remove_road(points.xyz, track, lattice, params.road)
        kept = status == 0
    with timer.stage("components", points=int(kept.sum())):
        component = wireframe_components(points.xyz, kept, lattice, params.segments)
        component = separate_curbs(
            points.xyz,
            component,
            lattice,
            track.station,
            track.lateral,
            track.height,
            params.segments,
        )
        component = absorb_fragments(points.xyz, component, params.segments, track.height)
    with timer.stage("slices", points=int(kept.sum())):
        segments = slice_components(
            component, track.station, params.segments, track.lateral, track.height
        )
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
            params.segments,
            params.correction,
        )
    point_segment = segments.point_segment.copy()
    point_segment[status == ROAD] = POINT_ROAD
    point_segment[status == OFF_ROAD] = POINT_OFF_ROAD
    return point_segment, segments, summary, features


def extract(
    drive: Drive,
    params: ExtractionParams = ExtractionParams(),
    *,
    timer: StageTimer | None = None,
    progress: bool = False,
    track: TrackCoordinates | None = None,
    crop_range_m: tuple[float, float] | None = None,
) -> Extraction:
    """Slice a drive (§3.1) and choose every segment's image and rectangle (§3.2)
    (``track``: see :func:`slice_drive`); :func:`segment_crops` cuts the crops.

    ``crop_range_m``: [first, last) metres along the trajectory; only segments whose slice
    starts there get an image, the others get :data:`CROP_NO_IMAGE` (a processing tile's margin
    beyond what its own labels depend on). None: every segment."""
    timer = timer or StageTimer(len(drive.points))
    point_segment, segments, summary, features = slice_drive(
        drive, params, timer=timer, track=track
    )
    with timer.stage("crops", points=int(segments.n_points.sum())):
        with progress_bar(
            total=len(drive.images), desc="choosing images", unit="image", enabled=progress
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
        if crop_range_m is not None:
            start = segments.slice_index * params.segments.slice_length_m
            away = (start < crop_range_m[0]) | (start >= crop_range_m[1])
            choice = CropChoice(
                np.where(away, -1, choice.image),
                choice.rect,
                np.where(away & (choice.status == CROP_OK), CROP_NO_IMAGE, choice.status).astype(
                    choice.status.dtype
                ),
            )
    return Extraction(point_segment, segments, summary, features, choice)


def segment_crops(
    drive: Drive,
    choice: CropChoice,
    rows: np.ndarray,
    size: int,
    params: CropParams = CropParams(),
    *,
    progress: bool = False,
) -> np.ndarray:
    """(K, size, size, 3) uint8 RGB crops of the segments ``rows`` (K,), each of which must have
    one (status ok), cut from the drive's images; an image is decoded only when a crop asked
    for lies in it.

    Raises
    ------
    ValueError
        A segment of ``rows`` has no crop.
    """
    rows = np.asarray(rows, np.int64).reshape(-1)
    if (choice.status[rows] != CROP_OK).any():
        raise ValueError("segment_crops: a segment without a crop was asked for")
    with progress_bar(total=len(rows), desc="cutting crops", unit="crop", enabled=progress) as bar:
        return cut_crops(
            lambda i: drive.read_image(drive.images[i]),
            choice.image[rows],
            choice.rect[rows],
            size,
            params,
            progress=bar.update,
        )
