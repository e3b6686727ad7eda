"""The unit frame (Matsumoto et al. 2019, §4.2, Fig. 13): coordinates of one unit shape.

A unit is the stretch of a guardrail run between two consecutive poles. Its coordinates:

- x, metres: horizontal distance along the unit from the first pole's axis (the second pole's
  axis stands at x = ``length``);
- y, metres: height above the ground line joining the two poles' ground points (the poles'
  direction, straight up);
- z, metres: horizontal offset from the vertical plane through the two pole axes, positive toward
  the road, i.e. toward the scanner: the visible face of a pipe is on its +z side.

These are the coordinates designs are written in, so a reconstructed unit model compares with a
design directly. On a grade the map from unit to world is a small shear (y stays vertical while
x follows the slope), volume-preserving and exact for guardrails that follow the ground.

The paper puts the origin at the centre of the rectangle the points project to; anchoring it at a
detected pole makes the rough alignment of §4.2 exact up to the pole's error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class UnitFrame:
    """Where one unit sits in the world.

    Attributes
    ----------
    origin : (3,) float64, metres: ground point of the first pole's axis, world frame
    along : (3,) float64: horizontal unit vector from the first pole to the second, world frame
    length : float, metres: horizontal distance between the two pole axes
    slope : float: rise of the ground line per metre of x
    """

    origin: np.ndarray
    along: np.ndarray
    length: float
    slope: float

    @classmethod
    def between(cls, pole_a: np.ndarray, pole_b: np.ndarray) -> UnitFrame:
        """The frame of the unit from ground point ``pole_a`` (3,) to ``pole_b`` (3,), world.

        Order the poles so that the road lies on the right of a -> b seen from above (then
        z = x × up points toward the road); :func:`guardrail_core.reconstruct.units` does.
        """
        a, b = np.asarray(pole_a, np.float64), np.asarray(pole_b, np.float64)
        horizontal = (b - a) * np.array([1.0, 1.0, 0.0])
        length = float(np.linalg.norm(horizontal))
        if length <= 0:
            raise ValueError("the two poles of a unit stand at the same place")
        return cls(a, horizontal / length, length, float((b[2] - a[2]) / length))

    @property
    def normal(self) -> np.ndarray:
        """(3,) the unit's z axis in the world: horizontal, toward the road."""
        return np.cross(self.along, UP)

    @property
    def T_world_unit(self) -> np.ndarray:
        """(4, 4) affine map from unit coordinates to the world (a shear on a grade)."""
        t = np.eye(4)
        t[:3, 0] = self.along + self.slope * UP
        t[:3, 1] = UP
        t[:3, 2] = self.normal
        t[:3, 3] = self.origin
        return t

    def to_unit(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> unit coordinates (N, 3)."""
        d = np.asarray(points, np.float64).reshape(-1, 3) - self.origin
        x = d @ self.along
        return np.stack([x, d[:, 2] - self.slope * x, d @ self.normal], axis=1)

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """Unit coordinates (N, 3) -> world points (N, 3)."""
        p = np.asarray(points, np.float64).reshape(-1, 3)
        return p @ self.T_world_unit[:3, :3].T + self.origin
