"""Cropped images of sliced segments (§3.2).

Candidate images are those taken within a time window of the segment's points (by GPS time). The
segment's points are projected into each with the camera's calibration (pinhole and Brown-Conrady
distortion, OpenCV conventions); the rectangle around them is the crop. Among the images that
contain all the points, the one with the largest rectangle is chosen.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from guardrail_core.extract.segments import Segments, SegmentSummary
from guardrail_core.formats.drive import ImageRecord
from guardrail_core.formats.run_folder import (  # the codes the run folder stores
    CROP_NO_IMAGE,
    CROP_OK,
    CROP_TOO_SMALL,
)
from guardrail_core.params import StageParams, param
from guardrail_core.sensors.camera import Camera


@dataclass(frozen=True)
class CropParams(StageParams):
    """How images are chosen and cropped."""

    time_window_s: float = param(
        3.0,
        unit="s",
        ge=0,
        le=3600,
        doc="images taken within this long of a segment's first or last point are candidates",
    )
    max_range_m: float = param(
        40.0,
        unit="m",
        gt=0,
        le=1000,
        doc="cameras farther than this from a segment's centre are not candidates (too small a "
        "view)",
    )
    min_depth_m: float = param(
        0.1,
        unit="m",
        ge=0,
        le=100,
        doc="a segment's centre must lie at least this far in front of a candidate camera",
    )
    min_points: int = param(
        3, ge=1, le=1_000_000, doc="segments with fewer points get no crop (status too_small)"
    )
    margin: float = param(
        0.15,
        ge=0,
        le=10,
        doc="the crop extends the points' rectangle by this share of its size on every side",
    )
    min_size_px: int = param(
        32,
        unit="px",
        ge=1,
        le=10_000,
        doc="smallest crop side in image pixels, so a far or tiny segment still shows its context",
    )

    def check_relations(self) -> None:
        if self.min_depth_m >= self.max_range_m:
            self.fail(
                f"min_depth_m ({self.min_depth_m} m) must lie below max_range_m "
                f"({self.max_range_m} m)"
            )


@dataclass(frozen=True)
class CropChoice:
    """The image and rectangle chosen for every segment.

    Attributes
    ----------
    image : (S,) int64, index into the drive's images, -1 where there is no crop
    rect : (S, 4) int32, x0, y0, x1, y1 pixel rectangle (inclusive) around the projected points
    status : (S,) uint8, :data:`CROP_OK`, :data:`CROP_NO_IMAGE` or :data:`CROP_TOO_SMALL`
    """

    image: np.ndarray
    rect: np.ndarray
    status: np.ndarray


def choose_images(
    xyz: np.ndarray,
    segments: Segments,
    summary: SegmentSummary,
    images: Sequence[ImageRecord],
    cameras: dict[str, Camera],
    params: CropParams = CropParams(),
    *,
    progress: Callable[[int], None] | None = None,
) -> CropChoice:
    """Choose every segment's image: all points inside, largest rectangle (§3.2).

    Parameters
    ----------
    xyz : (N, 3) float64, metres, local frame
    segments : the sliced segments of these points
    summary : their centroids and time ranges
    images : the drive's image records (poses ``T_world_camera`` in the local frame)
    cameras : calibrations by name
    params : time window, range, margin
    progress : called with 1 after each image is examined

    Returns
    -------
    CropChoice for the S segments.

    References
    ----------
    Matsumoto et al. 2019, §3.2 (images by GPS time; the image that contains all projected points
    and has the largest rectangle is selected).
    """
    n_segments = len(segments)
    image = np.full(n_segments, -1, np.int64)
    rect = np.zeros((n_segments, 4), np.int32)
    status = np.full(n_segments, CROP_NO_IMAGE, np.uint8)
    status[segments.n_points < params.min_points] = CROP_TOO_SMALL
    if n_segments == 0 or len(images) == 0:
        return CropChoice(image, rect, status)

    sorted_xyz = np.asarray(xyz, np.float64)[segments.order]
    t_first, t_last = summary.time[:, 0], summary.time[:, 1]
    centroid = summary.centroid

    # Candidate (segment, image) pairs by GPS time.
    image_time = np.array([record.gps_time for record in images])
    by_time = np.argsort(image_time, kind="stable")
    lo = np.searchsorted(image_time[by_time], t_first - params.time_window_s, side="left")
    hi = np.searchsorted(image_time[by_time], t_last + params.time_window_s, side="right")
    candidate = np.flatnonzero((status != CROP_TOO_SMALL) & (hi > lo))
    counts = (hi - lo)[candidate]
    pair_segment = np.repeat(candidate, counts)
    pair_image = by_time[_concatenated_ranges(lo[candidate], counts)]

    # Cheap filter: the segment's centre in front of the camera, within range.
    T_world_camera = np.stack([record.T_world_camera for record in images])
    rotation = T_world_camera[pair_image, :3, :3]
    position = T_world_camera[pair_image, :3, 3]
    in_camera = np.einsum("pji,pj->pi", rotation, centroid[pair_segment] - position)
    near = (in_camera[:, 2] > params.min_depth_m) & (
        np.linalg.norm(in_camera, axis=1) < params.max_range_m
    )
    pair_segment, pair_image = pair_segment[near], pair_image[near]

    best_area = np.zeros(n_segments, np.int64)
    order = np.lexsort((pair_segment, pair_image))
    pair_segment, pair_image = pair_segment[order], pair_image[order]
    boundaries = np.flatnonzero(np.diff(pair_image)) + 1
    for group in np.split(np.arange(len(pair_image)), boundaries):
        if len(group) == 0:
            continue
        index = int(pair_image[group[0]])
        record = images[index]
        camera = cameras[record.camera]
        segs = pair_segment[group]
        sizes = segments.n_points[segs]
        members = _concatenated_ranges(segments.starts[segs], sizes)
        uv, valid = camera.project(sorted_xyz[members], record.T_world_camera)
        ok = valid & camera.inside(uv)
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        all_inside = np.logical_and.reduceat(ok, starts)
        uv = np.where(ok[:, None], uv, 0.0)
        u0 = np.floor(np.minimum.reduceat(uv[:, 0], starts) + 0.5)
        v0 = np.floor(np.minimum.reduceat(uv[:, 1], starts) + 0.5)
        u1 = np.floor(np.maximum.reduceat(uv[:, 0], starts) + 0.5)
        v1 = np.floor(np.maximum.reduceat(uv[:, 1], starts) + 0.5)
        area = ((u1 - u0 + 1) * (v1 - v0 + 1)).astype(np.int64)
        better = all_inside & (area > best_area[segs])
        chosen = segs[better]
        best_area[chosen] = area[better]
        image[chosen] = index
        rect[chosen] = np.stack([u0, v0, u1, v1], axis=1)[better].astype(np.int32)
        status[chosen] = CROP_OK
        if progress is not None:
            progress(1)
    return CropChoice(image, rect, status)


def _concatenated_ranges(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """``concatenate([arange(s, s + n) for s, n in zip(starts, lengths)])``, vectorised."""
    lengths = np.asarray(lengths, np.int64)
    total = int(lengths.sum())
    offsets = np.arange(total) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    return np.repeat(np.asarray(starts, np.int64), lengths) + offsets


def crop_window(
    rect: np.ndarray, params: CropParams = CropParams()
) -> tuple[np.ndarray, np.ndarray]:
    """Square windows around point rectangles, with margin: top-left (M, 2) and side (M,) pixels.

    A square keeps the image's proportions when resized to the classifier's input.
    """
    rect = np.asarray(rect, np.float64).reshape(-1, 4)
    width = rect[:, 2] - rect[:, 0] + 1
    height = rect[:, 3] - rect[:, 1] + 1
    side = np.maximum(np.maximum(width, height) * (1 + 2 * params.margin), params.min_size_px)
    side = np.ceil(side).astype(np.int64)
    centre = (rect[:, :2] + rect[:, 2:]) / 2
    top_left = np.floor(centre - (side[:, None] - 1) / 2).astype(np.int64)
    return top_left, side


def cut_crop(image: np.ndarray, top_left: np.ndarray, side: int, size: int) -> np.ndarray:
    """The square window of ``image`` (H, W, 3) at ``top_left`` (x, y), resized to (size, size, 3).

    Parts of the window beyond the image are black.
    """
    h, w = image.shape[:2]
    x0, y0 = int(top_left[0]), int(top_left[1])
    window = np.zeros((side, side, 3), np.uint8)
    sx0, sy0 = max(x0, 0), max(y0, 0)
    sx1, sy1 = min(x0 + side, w), min(y0 + side, h)
    if sx1 > sx0 and sy1 > sy0:
        window[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0] = image[sy0:sy1, sx0:sx1]
    interpolation = cv2.INTER_AREA if side > size else cv2.INTER_LINEAR
    return cv2.resize(window, (size, size), interpolation=interpolation)


def cut_crops(
    read_image: Callable[[int], np.ndarray],
    image: np.ndarray,
    rect: np.ndarray,
    size: int,
    params: CropParams = CropParams(),
    *,
    progress: Callable[[int], None] | None = None,
) -> np.ndarray:
    """Crops (K, size, size, 3) uint8 RGB of K chosen images and rectangles.

    Parameters
    ----------
    read_image : ``read_image(i)`` returns image ``i`` (H, W, 3) uint8 RGB; each image is read
        once
    image : (K,) int64, the chosen image of every crop (:attr:`CropChoice.image`)
    rect : (K, 4) int32, its rectangle around the projected points (:attr:`CropChoice.rect`)
    size : px, the crops' side
    params : margin and smallest window
    progress : called with the number of crops cut from each image
    """
    image = np.asarray(image, np.int64).reshape(-1)
    crops = np.empty((len(image), size, size, 3), np.uint8)
    if len(image) == 0:
        return crops
    if (image < 0).any():
        raise ValueError("cut_crops: a crop without an image (index -1) was asked for")
    top_left, side = crop_window(rect, params)
    for index in np.unique(image):
        rows = np.flatnonzero(image == index)
        picture = read_image(int(index))
        for row in rows:
            crops[row] = cut_crop(picture, top_left[row], int(side[row]), size)
        if progress is not None:
            progress(len(rows))
    return crops
