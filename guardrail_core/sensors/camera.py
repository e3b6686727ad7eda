"""The pinhole camera with Brown-Conrady distortion, in OpenCV's conventions.

``dist = (k1, k2, p1, p2, k3)`` as in ``cv2.projectPoints``; pixel centres at integer
coordinates, (0, 0) the centre of the top-left pixel.

References
----------
Weng, Cohen & Herniou 1992 (the model the paper cites, Matsumoto et al. 2019, §3.2).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from guardrail_core.geom.frames import invert_transform, transform_points


@dataclass(frozen=True)
class Camera:
    """A calibrated camera mounted on the vehicle.

    Attributes
    ----------
    name : str
    width, height : int, pixels
    K : (3, 3) float64, intrinsic matrix (fx, fy, cx, cy in pixels)
    dist : (5,) float64, Brown-Conrady (k1, k2, p1, p2, k3), OpenCV order
    T_vehicle_camera : (4, 4) float64, camera frame (OpenCV: x right, y down, z forward) to vehicle
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    T_vehicle_camera: np.ndarray

    def _distort_normalised(self, xy: np.ndarray) -> np.ndarray:
        """Undistorted (N, 2) to distorted (N, 2) normalised coordinates."""
        k1, k2, p1, p2, k3 = self.dist
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([xd, yd], axis=1)

    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Normalised undistorted coordinates (N, 2) to pixel coordinates (N, 2)."""
        d = self._distort_normalised(np.asarray(xy, np.float64))
        u = self.K[0, 0] * d[:, 0] + self.K[0, 1] * d[:, 1] + self.K[0, 2]
        v = self.K[1, 1] * d[:, 1] + self.K[1, 2]
        return np.stack([u, v], axis=1)

    def undistort(self, uv: np.ndarray, *, iterations: int = 20) -> np.ndarray:
        """Pixel coordinates (N, 2) to normalised undistorted coordinates (N, 2).

        Newton's method on the distortion model, started at the distorted point; converges to
        1e-12 within a few steps wherever the model is monotonic (a sane calibration).
        """
        uv = np.asarray(uv, np.float64)
        yd = (uv[:, 1] - self.K[1, 2]) / self.K[1, 1]
        xd = (uv[:, 0] - self.K[0, 2] - self.K[0, 1] * yd) / self.K[0, 0]
        target = np.stack([xd, yd], axis=1)
        xy = target.copy()
        h = 1e-7
        for _ in range(iterations):
            f = self._distort_normalised(xy) - target
            if np.max(np.abs(f), initial=0.0) < 1e-13:
                break
            jx = (self._distort_normalised(xy + [h, 0.0]) - self._distort_normalised(xy)) / h
            jy = (self._distort_normalised(xy + [0.0, h]) - self._distort_normalised(xy)) / h
            det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
            dx = (jy[:, 1] * f[:, 0] - jy[:, 0] * f[:, 1]) / det
            dy = (-jx[:, 1] * f[:, 0] + jx[:, 0] * f[:, 1]) / det
            xy -= np.stack([dx, dy], axis=1)
        return xy

    def pixel_rays(self) -> np.ndarray:
        """Unit ray directions (H, W, 3) in the camera frame through every pixel centre."""
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        xy = self.undistort(np.stack([u.ravel(), v.ravel()], axis=1))
        d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d.reshape(self.height, self.width, 3)

    @cached_property
    def max_normalised_radius(self) -> float:
        """Largest undistorted normalised radius that reaches the sensor (its corners), +5%.

        The distortion polynomial folds back beyond the lens's field of view: without this
        bound, points far outside the view would project onto the image.
        """
        w, h = self.width - 0.5, self.height - 0.5
        corners = np.array([[-0.5, -0.5], [w, -0.5], [-0.5, h], [w, h]])
        return 1.05 * float(np.linalg.norm(self.undistort(corners), axis=1).max())

    def project(
        self, points_world: np.ndarray, T_world_camera: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Project world points (N, 3) into the image.

        Returns
        -------
        uv : (N, 2) float64, pixel coordinates (meaningless where ``valid`` is False)
        valid : (N,) bool, the point lies in front of the camera (z > 0.1 m) and within the
            lens's field of view; combine with :meth:`inside` for points on the sensor
        """
        pts_cam = transform_points(
            invert_transform(T_world_camera), np.asarray(points_world, np.float64)
        )
        z = pts_cam[:, 2]
        in_front = z > 0.1
        xy = pts_cam[:, :2] / np.where(in_front, z, 1.0)[:, None]
        valid = in_front & (np.linalg.norm(xy, axis=1) <= self.max_normalised_radius)
        return self.distort(xy), valid

    def inside(self, uv: np.ndarray) -> np.ndarray:
        """Whether pixel coordinates (N, 2) fall on the sensor (N,) bool."""
        return (
            (uv[:, 0] >= -0.5)
            & (uv[:, 0] < self.width - 0.5)
            & (uv[:, 1] >= -0.5)
            & (uv[:, 1] < self.height - 0.5)
        )
