"""Guardrails found on real frames whose guardrail points were labelled by hand: metres of rail
found in 1 m bins, and the share of the points called guardrail that lie off every guardrail.

A labels file (``.npz``, one per frame; ``benchmarks/label_real_frames.py`` writes the
project's own) holds, per point of the frame in the order of its source file:

- ``guardrail`` and ``judged``: packed bits (``numpy.packbits``); a point not judged (what could
  be a post as much as grass) is neither credited nor blamed;
- ``barrier``: uint8, 0 for no barrier, else which labelled barrier the rail point belongs to;
- ``names``: the barriers' names; ``n_points``; ``sha256`` of the source file.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from guardrail_core.errors import LabelsMismatchError
from guardrail_core.extract.road import RoadParams

#: Rail points a 1 m bin needs to count as seen.
MIN_POINTS_SEEN = 3
#: The share of a seen bin's rail points that must be called guardrail for the bin to be found.
FOUND_SHARE = 0.5


@dataclass(frozen=True)
class FrameLabels:
    """Hand labels of one real frame (arrays (N,) over its points, in the source file's order)."""

    guardrail: np.ndarray
    judged: np.ndarray
    barrier: np.ndarray
    names: list[str]
    sha256: str

    def __len__(self) -> int:
        return len(self.guardrail)


def load_frame_labels(path: str | Path, source: str | Path | None = None) -> FrameLabels:
    """Read a labels file; with ``source``, check that it labels that very file.

    Raises
    ------
    LabelsMismatchError
        ``source`` is not the file the labels were made on (another size or checksum).
    """
    with np.load(path, allow_pickle=False) as npz:
        n = int(npz["n_points"])
        labels = FrameLabels(
            guardrail=np.unpackbits(npz["guardrail"], count=n).astype(bool),
            judged=np.unpackbits(npz["judged"], count=n).astype(bool),
            barrier=npz["barrier"].astype(np.int64),
            names=[str(name) for name in npz["names"]],
            sha256=str(npz["sha256"]),
        )
    if source is not None:
        digest = hashlib.sha256(Path(source).read_bytes()).hexdigest()
        if digest != labels.sha256:
            raise LabelsMismatchError(f"{path}: labels another file than {source}")
    return labels


@dataclass(frozen=True)
class RailMetres:
    """Metres of one labelled barrier: seen by the scan and found by a model."""

    name: str
    seen_m: float
    found_m: float
    lateral_m: float

    @property
    def within(self) -> bool:
        """Whether the barrier lies within the extraction's reach (``road.max_lateral_m``):
        beyond it (a guardrail across the opposite carriageway) nothing is looked for."""
        return self.lateral_m <= RoadParams().max_lateral_m

    @property
    def found_share(self) -> float:
        return self.found_m / self.seen_m if self.seen_m else float("nan")


def rail_metres(
    xy: np.ndarray,
    labels: FrameLabels,
    found: np.ndarray,
    counted: np.ndarray | None = None,
    bin_m: float = 1.0,
) -> list[RailMetres]:
    """Metres of every labelled barrier seen and found, in ``bin_m`` bins along the rail.

    Parameters
    ----------
    xy : (N, 2) metres, the frame's points in the sensor's horizontal frame (x forward, y left)
    labels : the frame's hand labels
    found : (N,) bool, the points a model called guardrail
    counted : (N,) bool, the points to measure on (default all; the review loop leaves out the
        segments the operator labelled)

    A bin is seen when it holds :data:`MIN_POINTS_SEEN` counted rail points, and found when at
    least :data:`FOUND_SHARE` of them were called guardrail. The rail's direction is its points'
    principal axis (the labelled rails bend little within a frame); its ``lateral_m`` the
    median ``|y|`` of its points.
    """
    counted = np.ones(len(found), bool) if counted is None else counted
    result = []
    for number, name in enumerate(labels.names, start=1):
        rail = labels.barrier == number
        if rail.sum() < 2:
            result.append(RailMetres(name, 0.0, 0.0, float("inf")))
            continue
        points = xy[rail]
        centred = points - points.mean(axis=0)
        axis = np.linalg.svd(centred, full_matrices=False)[2][0]
        along = centred @ axis
        bins = np.floor((along - along.min()) / bin_m).astype(np.int64)
        keep = counted[rail]
        n_bins = int(bins.max()) + 1
        n_seen = np.bincount(bins[keep], minlength=n_bins)
        n_found = np.bincount(bins[keep], weights=found[rail][keep], minlength=n_bins)
        seen = n_seen >= MIN_POINTS_SEEN
        hit = seen & (n_found >= FOUND_SHARE * n_seen)
        lateral = float(np.median(np.abs(points[:, 1])))
        result.append(
            RailMetres(name, float(seen.sum() * bin_m), float(hit.sum() * bin_m), lateral)
        )
    return result


def off_guardrail_share(labels: FrameLabels, found: np.ndarray, counted=None) -> float:
    """The share of the judged points called guardrail that are not guardrail (0 when none is
    called guardrail)."""
    counted = np.ones(len(found), bool) if counted is None else counted
    called = found & labels.judged & counted
    n = int(called.sum())
    return float((called & ~labels.guardrail).sum() / n) if n else 0.0


def found_within(barriers: list[RailMetres]) -> float | None:
    """The share of the metres seen that were found, over the barriers within reach (None: no
    such barrier was seen)."""
    seen = sum(b.seen_m for b in barriers if b.within)
    return sum(b.found_m for b in barriers if b.within) / seen if seen else None
