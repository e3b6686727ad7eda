"""The evaluation's results as typed values, each with ``to_json()`` (``guardrail evaluate --json``).

Detection (the paper's Tables 1 and 2): :class:`EvaluationResult`, made of
:class:`DetectionMetrics` per class. Reconstruction against the truth:
:class:`ReconstructionEvaluation`, made of :class:`ReconstructionFigures` and one
:class:`GuardrailFinding` per true guardrail. The units sweep of §5.2: :class:`UnitsSweep`.

Lengths and errors are in millimetres (``_mm``); shares are 0..1; NaN marks a share of nothing
(no true or no predicted segment of a class), None a figure nothing was measured for.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class ClassMetrics:
    """Recall, precision and F-measure of one class (Table 2), with the true and predicted counts."""

    recall: float
    precision: float
    f1: float
    n_true: int
    n_predicted: int

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class DetectionMetrics:
    """:class:`ClassMetrics` of both classes."""

    guardrail: ClassMetrics
    other: ClassMetrics

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class ClassCounts:
    """Segments by true class (true class: the majority of a segment's points)."""

    guardrail: int
    other: int

    def to_json(self) -> dict[str, int]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class PointMetrics:
    """Guardrail points: recall and precision of the labels after correction, and the true count."""

    recall: float
    precision: float
    n_true: int

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class PipeFinding:
    """One pipe of a true design, and whether the unit model reconstructs it.

    Attributes
    ----------
    kind : the true pipe's kind (horizontal, vertical, diagonal, curved)
    radius_mm : its true radius
    found : found in at least ``unit_share`` of the measured units
    found_in_units : measured units it was found in
    radius_err_mm, axis_dev_mm : medians over those units; None where it never was found
    """

    kind: str
    radius_mm: float
    found: bool
    found_in_units: int
    radius_err_mm: float | None
    axis_dev_mm: float | None


@dataclass(frozen=True)
class ReconstructionFigures:
    """The reconstruction's figures over a set of true guardrails (all, or one design's).

    ``pipes_in_view`` counts the pipes of guardrails with a unit whose two poles were scanned;
    radius: median error, axis: mean deviation, beam: median section Hausdorff, pole position and
    unit length: median errors (all of found pipes, measured units, matched poles).
    """

    pipes_found: int
    pipes_total: int
    pipes_in_view: int
    guardrails_total: int
    guardrails_in_view: int
    radius_err_mm_median: float | None
    axis_dev_mm_mean: float | None
    beam_section_hausdorff_mm: float | None
    beams_reconstructed: int
    beams_total: int
    poles_found: int
    poles_total: int
    pole_pos_err_mm_median: float | None
    unit_length_err_mm_median: float | None

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class GuardrailFinding:
    """One true guardrail and what its reconstruction got right.

    Attributes
    ----------
    truth_id, design, type : the true guardrail (``truth/objects.json``)
    run_id : the reconstructed run measured against it, None where no run matched
    poles_total, poles_found : its poles, and those a detected pole matched
    pipes : one finding per pipe of its design (pipe designs with measured units)
    pipes_total, pipes_found : the design's pipes per unit, and those found
    beam_section_hausdorff_mm : the section's error (beam designs), None where not measured
    units_in_view : its units with both poles scanned, None where not known
    units_measured : units whose two poles matched consecutive true poles
    """

    truth_id: int
    design: str
    type: str
    run_id: int | None
    poles_total: int
    pipes: tuple[PipeFinding, ...]
    pipes_total: int
    beam_section_hausdorff_mm: float | None
    units_in_view: int | None
    poles_found: int
    units_measured: int
    pipes_found: int

    def to_json(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["pipes"] = list(out["pipes"])
        return out


@dataclass(frozen=True)
class ReconstructionEvaluation:
    """:func:`guardrail_core.evaluate.reconstruction.evaluate_reconstruction`'s result."""

    overall: ReconstructionFigures
    designs: dict[str, ReconstructionFigures]
    runs: tuple[GuardrailFinding, ...]

    def to_json(self) -> dict[str, Any]:
        return {
            "overall": self.overall.to_json(),
            "designs": {name: figures.to_json() for name, figures in self.designs.items()},
            "runs": [run.to_json() for run in self.runs],
        }


@dataclass(frozen=True)
class EvaluationResult:
    """:func:`guardrail_core.evaluate.detection.evaluate_run`'s result.

    Attributes
    ----------
    segments : Table 1's segments by true class, and their total
    crops : by crop status name (ok, no_image, too_small), the segments by true class
    detection, detection_raw : Table 2 after and before label correction
    points : guardrail points after correction
    reconstruction : the reconstruction against the truth, where the run has one
    """

    segments: ClassCounts
    n_segments: int
    crops: dict[str, ClassCounts]
    detection: DetectionMetrics
    detection_raw: DetectionMetrics
    points: PointMetrics
    reconstruction: ReconstructionEvaluation | None = None

    def to_json(self) -> dict[str, Any]:
        """The members and keys ``guardrail evaluate --json`` has always printed."""
        out: dict[str, Any] = {
            "segments": {**self.segments.to_json(), "total": self.n_segments},
            "crops": {name: counts.to_json() for name, counts in self.crops.items()},
            "detection": self.detection.to_json(),
            "detection_raw": self.detection_raw.to_json(),
            "points": {"guardrail": self.points.to_json()},
        }
        if self.reconstruction is not None:
            out["reconstruction"] = self.reconstruction.to_json()
        return out


@dataclass(frozen=True)
class DesignSweep:
    """One design in the units sweep: per number of units, what was found of how many.

    Attributes
    ----------
    type : "pipe" or "beam"
    found, total : per k, pipes found and pipes in total (beam designs: runs whose section is
        within the tolerance, and runs)
    worst_section_hausdorff_mm : beam designs: per k the largest section Hausdorff of the
        design's runs (None where none was measured); None for pipe designs
    complete_from : the smallest k with everything found, None if never
    """

    type: str
    found: tuple[int, ...]
    total: tuple[int, ...]
    worst_section_hausdorff_mm: tuple[float | None, ...] | None
    complete_from: int | None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"type": self.type, "found": list(self.found)}
        out["total"] = list(self.total)
        if self.worst_section_hausdorff_mm is not None:
            out["worst_section_hausdorff_mm"] = list(self.worst_section_hausdorff_mm)
        out["complete_from"] = self.complete_from
        return out


@dataclass(frozen=True)
class UnitsSweep:
    """:func:`guardrail_core.evaluate.units_sweep.units_sweep`'s result: the numbers of units
    tried, in order, and per design (sorted by name) what was found."""

    units: tuple[int, ...]
    designs: dict[str, DesignSweep]

    def to_json(self) -> dict[str, Any]:
        return {
            "units": list(self.units),
            "designs": {name: design.to_json() for name, design in self.designs.items()},
        }
