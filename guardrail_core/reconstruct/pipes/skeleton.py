"""A pipe under construction: its skeleton in (x, y) and the points it was found from."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

#: The kinds of pipe (:data:`guardrail_core.reconstruct.model.PIPE_KINDS`).
PipeKind = Literal["horizontal", "vertical", "diagonal", "curved"]


@dataclass(frozen=True)
class Chain:
    """The slice centres a skeleton was shaped from (§4.3, Fig. 16 d), kept so that two pieces
    of one pipe can be shaped again as one.

    Attributes
    ----------
    centres : (K, 2) float64, unit (x, y), metres, in x order
    shared : (K,) bool, centres shared with another chain (a crossing): they do not shape it
    own : (M,) int64, indices (into the points between the poles) of its unshared components
    """

    centres: np.ndarray
    shared: np.ndarray
    own: np.ndarray


@dataclass
class Skeleton:
    """A pipe under construction; the later steps move its ends and change its kind.

    Attributes
    ----------
    xy : (K, 2) float64, unit (x, y), metres: the axis polyline, K >= 2
    kind : what the pipe is
    idx : (M,) int64, indices (into the points between the poles) of the points it came from
    chain : the slice centres it was shaped from (None for vertical pipes and straight ones)
    """

    xy: np.ndarray
    kind: PipeKind
    idx: np.ndarray
    chain: Chain | None = None
