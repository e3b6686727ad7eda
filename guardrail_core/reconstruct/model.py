"""What reconstruction produces: poles, pipes, beam sections, unit models and run models.

Unit-model geometry is in unit coordinates (:mod:`guardrail_core.reconstruct.unit_frame`):
x along the unit from its first pole, y above the ground line, z toward the road; metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from guardrail_core.reconstruct.unit_frame import UnitFrame

PIPE_KINDS = ("horizontal", "vertical", "diagonal", "curved")


@dataclass(frozen=True)
class Pole:
    """A detected pole (§4.1): a vertical cylinder.

    Attributes
    ----------
    position : (3,) float64, metres, world: the ground point of the axis
    radius : float, metres
    height : float, metres from the ground to the highest point
    n_points : int, points that voted for it
    """

    position: np.ndarray
    radius: float
    height: float
    n_points: int


@dataclass(frozen=True)
class Pipe:
    """A reconstructed pipe (§4.3).

    Attributes
    ----------
    axis : (K, 3) float64, unit coordinates, metres: the skeleton polyline, K >= 2
    radius : float, metres
    kind : one of :data:`PIPE_KINDS`
    n_points : int, superimposed points assigned to it
    """

    axis: np.ndarray
    radius: float
    kind: str
    n_points: int


@dataclass(frozen=True)
class UnitModel:
    """The shape of one unit, reconstructed from the superimposed points of a run's units.

    Attributes
    ----------
    type : "pipe" or "beam"
    length : float, metres: the unit length the model was built for (x in [0, length])
    pipes : the pipes (pipe type)
    section : (M, 2) float64 (z, y) metres, the beam's section curve (beam type), else None
    pole_radius, pole_height : float, metres: the median of the run's poles
    n_units : int, units superimposed
    notes : what could not be reconstructed, in words
    """

    type: str
    length: float
    pipes: tuple[Pipe, ...] = ()
    section: np.ndarray | None = None
    pole_radius: float = 0.0
    pole_height: float = 0.0
    n_units: int = 0
    notes: tuple[str, ...] = ()


@dataclass
class RunModel:
    """One reconstructed guardrail run.

    Attributes
    ----------
    run_id : int
    poles : the run's poles in order along it (the road on the right, seen from above)
    units : (P - 1) unit frames between consecutive poles
    model : the unit model, or None when the run could not be reconstructed
    registered : (P - 1,) bool, units ICP registered (False: left at the rough alignment)
    n_points : int, guardrail points of the run
    notes : what went wrong, in words (a run with one unit, missing poles ...)
    """

    run_id: int
    poles: list[Pole]
    units: list[UnitFrame]
    model: UnitModel | None
    registered: np.ndarray
    n_points: int
    notes: list[str] = field(default_factory=list)
