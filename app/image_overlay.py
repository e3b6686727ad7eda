"""A camera image with the drive's points on it, coloured by label, and picking a segment there.

The points drawn are those any crop of the image may hold: scanned within the crops' time
window of the exposure (``params.crops.time_window_s``, §3.2) and within their range of the
camera (``max_range_m``). Of the points on a pixel the nearest is drawn, so a near point hides
the far ones behind it, as in the picture; a click picks the point nearest the camera within a
few pixels.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

from app.run_tiles import RunTiles
from app.scene.colours import GUARDRAIL, OFF_ROAD, OTHER, ROAD, SELECTED
from guardrail_core.extract.crops import CropParams
from guardrail_core.formats.drive import DriveSource

#: Projections kept (an operator looks at a few images in turn).
PROJECTIONS_KEPT = 4
#: px, the side of a drawn point.
DOT_PX = 2
#: px, how far from a click a point may lie and still be picked.
PICK_RADIUS_PX = 6


@dataclass(frozen=True)
class ImagePoints:
    """The points of the drive on one image.

    Attributes
    ----------
    pixel : (K, 2) int32, column and row of each point on the image
    depth : (K,) float32, metres in front of the camera
    segment : (K,) int32, the point's segment (negative: road -1, off the road -2, not processed -3)
    front : (F,) int64, ascending: the points nearest the camera at their pixel (one a pixel),
        which are the ones drawn
    """

    pixel: np.ndarray
    depth: np.ndarray
    segment: np.ndarray
    front: np.ndarray


class ImageOverlay:
    """The drive's images with its points projected on them.

    Parameters
    ----------
    drive : the drive (its images and cameras)
    tiles : its points and the run's segments, read from the tiles the images need
    crops : the run's crop parameters (which points an image may show)

    Thread-safe: the app's request threads share one.
    """

    def __init__(self, drive: DriveSource, tiles: RunTiles, crops: CropParams) -> None:
        self.drive = drive
        self.tiles = tiles
        self.params = crops
        self._kept: OrderedDict[int, ImagePoints] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self.drive.images)

    def size(self, image: int) -> tuple[int, int]:
        """(width, height) pixels of image ``image``."""
        camera = self.drive.cameras[self.drive.images[image].camera]
        return camera.width, camera.height

    def points(self, image: int) -> ImagePoints:
        """The points on image ``image`` (0 <= image < len(self))."""
        with self._lock:
            if image in self._kept:
                self._kept.move_to_end(image)
                return self._kept[image]
        found = self._project(image)
        with self._lock:
            self._kept[image] = found
            while len(self._kept) > PROJECTIONS_KEPT:
                self._kept.popitem(last=False)
        return found

    def render(
        self, image: int, segment_label: np.ndarray, outline: int | None = None
    ) -> np.ndarray:
        """(H, W, 3) uint8 RGB: the image with its points coloured by their segment's label
        (``segment_label`` (S,) bool, True guardrail), road and off-road points grey, and the
        segment ``outline`` (if any) drawn in magenta with its hull."""
        record = self.drive.images[image]
        picture = np.ascontiguousarray(self.drive.read_image(record))
        found = self.points(image)
        front = found.front  # one point a pixel: no pixel is written twice in one pass
        seg = found.segment[front]
        colour = np.empty((len(seg), 3), np.uint8)
        colour[:] = OFF_ROAD
        colour[seg == -1] = ROAD
        in_segment = seg >= 0
        labels = np.asarray(segment_label, bool)[seg[in_segment]]
        colour[in_segment] = np.where(labels[:, None], GUARDRAIL, OTHER)
        if outline is not None:
            colour[seg == outline] = SELECTED
        height, width = picture.shape[:2]
        pixel = found.pixel[front]
        for dy, dx in [(d // DOT_PX, d % DOT_PX) for d in range(DOT_PX**2)][::-1]:
            # The dots' other pixels first, each point's own pixel last: it keeps its colour.
            rows = np.minimum(pixel[:, 1] + dy, height - 1)
            cols = np.minimum(pixel[:, 0] + dx, width - 1)
            picture[rows, cols] = colour
        mine = np.zeros(0, bool) if outline is None else found.segment == outline
        if mine.sum() >= 3:
            hull = cv2.convexHull(found.pixel[mine].astype(np.int32))
            cv2.polylines(picture, [hull], True, tuple(int(c) for c in SELECTED), 2, cv2.LINE_AA)
        return picture

    def pick(self, image: int, x: float, y: float, radius: float = PICK_RADIUS_PX) -> int | None:
        """The segment of the point nearest the camera within ``radius`` pixels of pixel
        (``x``, ``y``) of image ``image``; None where no segment's point lies there."""
        found = self.points(image)
        offset = found.pixel.astype(np.float64) - np.array([x, y])
        near = np.flatnonzero(((offset**2).sum(axis=1) <= radius**2) & (found.segment >= 0))
        if len(near) == 0:
            return None
        return int(found.segment[near[np.argmin(found.depth[near])]])

    def _project(self, image: int) -> ImagePoints:
        record = self.drive.images[image]
        camera = self.drive.cameras[record.camera]
        window = self.params.time_window_s
        scanned = self.tiles.scanned_between(record.gps_time - window, record.gps_time + window)
        index, xyz = np.arange(len(scanned)), scanned.xyz
        # Keep what lies in front, within range and within the lens's field before the
        # distortion model runs (most of the window does not): depth first, it is one product.
        rotation = record.T_world_camera[:3, :3]
        relative = xyz - record.T_world_camera[:3, 3]
        z = relative @ rotation[:, 2]
        ahead = (z > 0.1) & (z < self.params.max_range_m)
        index, local = index[ahead], relative[ahead] @ rotation
        z = local[:, 2]
        reach = camera.max_normalised_radius * z
        keep = (
            (z > 0.1)
            & (np.abs(local[:, 0]) <= reach)
            & (np.abs(local[:, 1]) <= reach)
            & (np.einsum("ij,ij->i", local, local) < self.params.max_range_m**2)
        )
        index, local = index[keep], local[keep]
        xy = local[:, :2] / local[:, 2:3]
        lens = np.einsum("ij,ij->i", xy, xy) <= camera.max_normalised_radius**2
        uv = camera.distort(xy[lens])
        index, depth = index[lens], local[lens, 2]
        on = camera.inside(uv)
        index, uv, depth = index[on], uv[on], depth[on]
        pixel = np.floor(uv + 0.5).astype(np.int32)
        # The nearest point of each pixel: one sort by pixel, then depth in millimetres.
        flat = pixel[:, 1].astype(np.int64) * camera.width + pixel[:, 0]
        key = (flat << 24) + np.minimum(depth * 1000, 2**24 - 1).astype(np.int64)
        by_key = np.argsort(key)
        flat_sorted = flat[by_key]
        first = np.flatnonzero(np.r_[True, flat_sorted[1:] != flat_sorted[:-1]])
        return ImagePoints(
            pixel=pixel,
            depth=depth.astype(np.float32),
            segment=np.asarray(scanned.segment[index], np.int32),
            front=np.sort(by_key[first]),
        )


def encode_png(picture: np.ndarray) -> bytes:
    """PNG bytes of an (H, W, 3) uint8 RGB picture (fast compression: it is sent, not kept)."""
    ok, data = cv2.imencode(
        ".png", cv2.cvtColor(picture, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1]
    )
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
        raise ValueError("the picture could not be encoded as PNG")
    return bytes(data)
