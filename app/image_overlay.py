"""A camera image with the drive's points on it, coloured by label, and picking a segment there.

The points drawn are those any crop of the image may hold: scanned within the crops' time
window of the exposure (``params.crops.time_window_s``, §3.2) and within their range of the
camera (``max_range_m``). They are drawn far to near, so a near point hides the far ones behind
it, as in the picture; a click picks the nearest-to-the-camera point within a few pixels.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

from app.scene.colours import GUARDRAIL, OFF_ROAD, OTHER, ROAD, SELECTED
from guardrail_core.extract.crops import CropParams
from guardrail_core.formats.drive import Drive

#: Projections kept (an operator looks at a few images in turn).
PROJECTIONS_KEPT = 4
#: px, the side of a drawn point.
DOT_PX = 2
#: px, how far from a click a point may lie and still be picked.
PICK_RADIUS_PX = 6


@dataclass(frozen=True)
class ImagePoints:
    """The points drawn on one image, far to near.

    Attributes
    ----------
    pixel : (K, 2) int32, column and row of each point on the image
    depth : (K,) float32, metres in front of the camera
    segment : (K,) int32, the point's segment (negative: road -1, off the road -2, not processed -3)
    """

    pixel: np.ndarray
    depth: np.ndarray
    segment: np.ndarray


class ImageOverlay:
    """The drive's images with its points projected on them.

    Parameters
    ----------
    drive : the drive, its points in memory
    point_segment : (N,) int32, the run's segment of every drive point
    crops : the run's crop parameters (which points an image may show)

    Thread-safe: the app's request threads share one.
    """

    def __init__(self, drive: Drive, point_segment: np.ndarray, crops: CropParams) -> None:
        self.drive = drive
        self.point_segment = point_segment
        self.params = crops
        gps_time = drive.points.gps_time
        # Mobile-mapping points come in time order; sort only where they do not.
        self._by_time = None if np.all(np.diff(gps_time) >= 0) else np.argsort(gps_time)
        self._sorted_time = gps_time if self._by_time is None else gps_time[self._by_time]
        self._kept: OrderedDict[int, ImagePoints] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self.drive.images)

    def size(self, image: int) -> tuple[int, int]:
        """(width, height) pixels of image ``image``."""
        camera = self.drive.cameras[self.drive.images[image].camera]
        return camera.width, camera.height

    def points(self, image: int) -> ImagePoints:
        """The points drawn on image ``image`` (0 <= image < len(self)), far to near."""
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
        seg = found.segment
        colour = np.empty((len(seg), 3), np.uint8)
        colour[:] = OFF_ROAD
        colour[seg == -1] = ROAD
        in_segment = seg >= 0
        labels = np.asarray(segment_label, bool)[seg[in_segment]]
        colour[in_segment] = np.where(labels[:, None], GUARDRAIL, OTHER)
        mine = np.zeros(len(seg), bool) if outline is None else seg == outline
        colour[mine] = SELECTED
        height, width = picture.shape[:2]
        for dy in range(DOT_PX):
            for dx in range(DOT_PX):
                rows = np.minimum(found.pixel[:, 1] + dy, height - 1)
                cols = np.minimum(found.pixel[:, 0] + dx, width - 1)
                # Where points share a pixel the nearest is drawn (they come far to near).
                flat = (rows * width + cols)[::-1]
                _, first = np.unique(flat, return_index=True)
                nearest = len(flat) - 1 - first
                picture[rows[nearest], cols[nearest]] = colour[nearest]
        if mine.sum() >= 3:
            hull = cv2.convexHull(found.pixel[mine].astype(np.int32))
            cv2.polylines(picture, [hull], True, tuple(int(c) for c in SELECTED), 2, cv2.LINE_AA)
        return picture

    def pick(self, image: int, x: float, y: float) -> int | None:
        """The segment of the point nearest the camera within :data:`PICK_RADIUS_PX` of pixel
        (``x``, ``y``) of image ``image``; None where no segment's point lies there."""
        found = self.points(image)
        offset = found.pixel.astype(np.float64) - np.array([x, y])
        near = np.flatnonzero(((offset**2).sum(axis=1) <= PICK_RADIUS_PX**2) & (found.segment >= 0))
        if len(near) == 0:
            return None
        return int(found.segment[near[np.argmin(found.depth[near])]])

    def _project(self, image: int) -> ImagePoints:
        record = self.drive.images[image]
        camera = self.drive.cameras[record.camera]
        window = self.params.time_window_s
        lo, hi = np.searchsorted(
            self._sorted_time, [record.gps_time - window, record.gps_time + window]
        )
        index = np.arange(lo, hi) if self._by_time is None else self._by_time[lo:hi]
        xyz = self.drive.points.xyz[index]
        position = record.T_world_camera[:3, 3]
        near = ((xyz - position) ** 2).sum(axis=1) < self.params.max_range_m**2
        index, xyz = index[near], xyz[near]
        uv, valid = camera.project(xyz, record.T_world_camera)
        keep = valid & camera.inside(uv)
        index, uv = index[keep], uv[keep]
        depth = (xyz[keep] - position) @ record.T_world_camera[:3, 2]
        order = np.argsort(-depth, kind="stable")
        return ImagePoints(
            pixel=np.floor(uv[order] + 0.5).astype(np.int32),
            depth=depth[order].astype(np.float32),
            segment=np.asarray(self.point_segment[index[order]], np.int32),
        )


def encode_png(picture: np.ndarray) -> bytes:
    """PNG bytes of an (H, W, 3) uint8 RGB picture (fast compression: it is sent, not kept)."""
    ok, data = cv2.imencode(
        ".png", cv2.cvtColor(picture, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1]
    )
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
        raise ValueError("the picture could not be encoded as PNG")
    return bytes(data)
