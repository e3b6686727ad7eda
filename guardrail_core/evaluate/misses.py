"""Why true poles and pipes were missed: each miss put down to one cause, so a figure below its
target says what to fix (the accuracy benchmark, ``benchmarks/accuracy.py``).

Causes of a missed pole, the first that applies:

- ``beyond the drive's ends``: not scanned (fewer than ``pole_points`` of its guardrail's points
  within ``pole_reach_m`` of its axis) and standing before the drive's first position or after
  its last (a run that begins or ends out of sight);
- ``far side``: not scanned, more than :data:`FAR_SIDE_M` from the vehicle's path;
- ``occluded``: not scanned, nearer (a parked car, a bollard or another object stood between);
- ``short run``: scanned, in a guardrail of at most :data:`SHORT_RUN_UNITS` units;
- ``unit partly seen``: scanned, but a neighbouring pole of its guardrail was not;
- ``far side, scanned``: scanned, more than :data:`FAR_SIDE_M` from the path;
- ``in view``: scanned, near, in a long run with its neighbours seen: the method's own miss.

A guardrail segment the model labelled other (a miss), or another segment it labelled guardrail
(a false alarm), is put down to ``far side`` (its mean offset beyond :data:`FAR_SIDE_M`), ``no
crop`` (no image held it), ``few points`` (under :data:`FEW_POINTS`) or ``near, with a crop``, the
first that applies (:func:`explain_detection_misses`).

A pipe of a guardrail in view (one unit with both poles scanned) that was not found is put down
to ``design`` when its run was reconstructed and measured (the design's pipe, by kind, is then
named in :attr:`MissBreakdown.design_misses`), else to its guardrail: ``short run``, ``far
side`` (most poles beyond :data:`FAR_SIDE_M`) or ``not reconstructed``.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.evaluate.reconstruction import (
    PolePointCounter,
    ReconstructionMatch,
    evaluate_reconstruction,
    match_poles,
    truth_guardrails,
)
from guardrail_core.formats.drive_tiles import vehicle_station
from guardrail_core.formats.run_folder import CROP_OK
from guardrail_core.reconstruct.model import RunModel
from guardrail_core.sensors.track import track_coordinates
from guardrail_core.sensors.trajectory import Trajectory

#: Metres from the vehicle's path beyond which a pole stands on the far side of the road: beyond
#: the lane beside the vehicle (a near-side guardrail stands about 2 m from the path).
FAR_SIDE_M = 4.0
#: A guardrail of at most this many units is a short run.
SHORT_RUN_UNITS = 2
#: A segment of fewer points than this has little shape to judge.
FEW_POINTS = 20

POLE_CAUSES = (
    "beyond the drive's ends",
    "far side",
    "occluded",
    "short run",
    "unit partly seen",
    "far side, scanned",
    "in view",
)
PIPE_CAUSES = ("design", "short run", "far side", "not reconstructed")
SEGMENT_CAUSES = ("far side", "no crop", "few points", "near, with a crop")


def explain_detection_misses(
    truth: np.ndarray, label: np.ndarray, segments: dict[str, np.ndarray]
) -> dict[str, dict[str, int]]:
    """Segments the model got wrong, by cause (see the module's notes).

    Parameters
    ----------
    truth : (S,) bool, the true class (guardrail: most of the segment's points are)
    label : (S,) bool, the run's label after correction
    segments : the run's segment table (``lateral`` (S, 2) m, ``crop_status``, ``n_points``)

    Returns
    -------
    ``{"missed": {cause: n}, "false alarms": {cause: n}, "guardrail": {cause: n}}``, the last
    counting every true guardrail segment by the same causes (what each cause's misses are out of).
    """
    truth, label = np.asarray(truth, bool), np.asarray(label, bool)
    offset = np.abs(np.asarray(segments["lateral"], np.float64).mean(axis=1))
    tests = (
        offset > FAR_SIDE_M,
        np.asarray(segments["crop_status"]) != CROP_OK,
        np.asarray(segments["n_points"]) < FEW_POINTS,
    )
    cause = np.full(len(truth), len(tests))  # near, with a crop
    for code in range(len(tests) - 1, -1, -1):  # the first cause that applies wins
        cause[tests[code]] = code

    def count(mask: np.ndarray) -> dict[str, int]:
        n = np.bincount(cause[mask], minlength=len(SEGMENT_CAUSES))
        return {name: int(k) for name, k in zip(SEGMENT_CAUSES, n, strict=True)}

    return {
        "missed": count(truth & ~label),
        "false alarms": count(~truth & label),
        "guardrail": count(truth),
    }


@dataclass(frozen=True)
class MissBreakdown:
    """Poles and pipes found, and the misses by cause, of one drive (or summed over several).

    Attributes
    ----------
    poles_total, poles_found : true poles, and those a detected pole matched
    poles_in_view, poles_found_in_view : the true poles that were scanned (``pole_points`` of
        their guardrail's points within ``pole_reach_m`` of the axis), and those of them found
    poles_detected : the runs' poles (those inserted where one was missing included); those no
        true pole took (:attr:`false_poles`) stand where there is none, or twice at one
    pole_misses : cause (:data:`POLE_CAUSES`) -> missed poles
    pipes_in_view, pipes_found : pipes of the design per unit of the guardrails in view, and
        those found (the rules of :mod:`guardrail_core.evaluate.reconstruction`)
    pipe_misses : cause (:data:`PIPE_CAUSES`) -> missed pipes in view
    design_misses : ``"design/kind"`` -> pipes missed for the ``design`` cause
    designs : design -> {"poles_total", "poles_found", "pipes_in_view", "pipes_found"}
    pole_errors_mm : (found poles) horizontal distance to the true axis
    radius_errors_mm, axis_deviations_mm : (found pipes) medians over their units
    beam_hausdorff_mm : (measured beam runs) section error
    """

    poles_total: int = 0
    poles_found: int = 0
    poles_in_view: int = 0
    poles_found_in_view: int = 0
    poles_detected: int = 0
    pole_misses: dict[str, int] = field(default_factory=dict)
    pipes_in_view: int = 0
    pipes_found: int = 0
    pipe_misses: dict[str, int] = field(default_factory=dict)
    design_misses: dict[str, int] = field(default_factory=dict)
    designs: dict[str, dict[str, int]] = field(default_factory=dict)
    pole_errors_mm: tuple[float, ...] = ()
    radius_errors_mm: tuple[float, ...] = ()
    axis_deviations_mm: tuple[float, ...] = ()
    beam_hausdorff_mm: tuple[float, ...] = ()

    def __add__(self, other: MissBreakdown) -> MissBreakdown:
        designs: dict[str, dict[str, int]] = {}
        for source in (self.designs, other.designs):
            for name, counts in source.items():
                designs[name] = dict(Counter(designs.get(name, {})) + Counter(counts))
                for key in counts:  # Counter drops zeros; the table wants them
                    designs[name].setdefault(key, 0)
        return MissBreakdown(
            poles_total=self.poles_total + other.poles_total,
            poles_found=self.poles_found + other.poles_found,
            poles_in_view=self.poles_in_view + other.poles_in_view,
            poles_found_in_view=self.poles_found_in_view + other.poles_found_in_view,
            poles_detected=self.poles_detected + other.poles_detected,
            pole_misses=_add(self.pole_misses, other.pole_misses),
            pipes_in_view=self.pipes_in_view + other.pipes_in_view,
            pipes_found=self.pipes_found + other.pipes_found,
            pipe_misses=_add(self.pipe_misses, other.pipe_misses),
            design_misses=_add(self.design_misses, other.design_misses),
            designs=dict(sorted(designs.items())),
            pole_errors_mm=self.pole_errors_mm + other.pole_errors_mm,
            radius_errors_mm=self.radius_errors_mm + other.radius_errors_mm,
            axis_deviations_mm=self.axis_deviations_mm + other.axis_deviations_mm,
            beam_hausdorff_mm=self.beam_hausdorff_mm + other.beam_hausdorff_mm,
        )

    @property
    def false_poles(self) -> int:
        """Detected poles that matched no true pole (a pole is matched once)."""
        return self.poles_detected - self.poles_found

    def to_json(self) -> dict[str, Any]:
        return {
            "poles_total": self.poles_total,
            "poles_found": self.poles_found,
            "poles_in_view": self.poles_in_view,
            "poles_found_in_view": self.poles_found_in_view,
            "poles_detected": self.poles_detected,
            "false_poles": self.false_poles,
            "pole_misses": self.pole_misses,
            "pipes_in_view": self.pipes_in_view,
            "pipes_found": self.pipes_found,
            "pipe_misses": self.pipe_misses,
            "design_misses": self.design_misses,
            "designs": self.designs,
            "pole_errors_mm": list(self.pole_errors_mm),
            "radius_errors_mm": list(self.radius_errors_mm),
            "axis_deviations_mm": list(self.axis_deviations_mm),
            "beam_hausdorff_mm": list(self.beam_hausdorff_mm),
        }


def _add(a: dict[str, int], b: dict[str, int]) -> dict[str, int]:
    out = dict(a)
    for key, value in b.items():
        out[key] = out.get(key, 0) + value
    return out


def pole_track(poles_xyz: np.ndarray, trajectory: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Station and lateral offset (K,) of pole positions (K, 3) along the vehicle's path, m;
    stations outside [0, the path's length] lie beyond the drive's ends."""
    poles_xyz = np.asarray(poles_xyz, np.float64).reshape(-1, 3)
    if len(poles_xyz) == 0:
        return np.zeros(0), np.zeros(0)
    nearest = cKDTree(trajectory.position[:, :2]).query(poles_xyz[:, :2])[1]
    track = track_coordinates(poles_xyz, trajectory.time[nearest], trajectory)
    return track.station, track.lateral


def explain_misses(
    runs: list[RunModel],
    objects: list[dict],
    pole_points: PolePointCounter,
    trajectory: Trajectory,
    match: ReconstructionMatch = ReconstructionMatch(),
) -> MissBreakdown:
    """Poles and pipes found of a drive's true guardrails, and why the others were missed.

    Parameters
    ----------
    runs : the reconstructed runs
    objects : ``truth/objects.json``
    pole_points : the drive's points counted around every true pole (every tile added)
    trajectory : the drive's trajectory
    match : the matching tolerances (those of ``guardrail evaluate``)
    """
    truths = truth_guardrails(objects)
    matched, _ = match_poles(runs, truths, match)
    found = {(ti, pi): error for ti, pi, error in matched.values()}
    path_end = float(vehicle_station(trajectory, trajectory.time[-1:])[0])
    evaluation = evaluate_reconstruction(runs, objects, match, in_view=pole_points.units_in_view())
    pole_misses: Counter[str] = Counter()
    pipe_misses: Counter[str] = Counter()
    design_misses: Counter[str] = Counter()
    designs: dict[str, Counter[str]] = {}
    in_view = found_in_view = 0
    radius, axis, beams = [], [], []
    for ti, (truth, counts, finding) in enumerate(
        zip(truths, pole_points.counts, evaluation.runs, strict=True)
    ):
        poles = np.array([p["position"] for p in truth["poles"]], np.float64).reshape(-1, 3)
        station, lateral = pole_track(poles, trajectory)
        scanned = counts >= match.pole_points
        far = np.abs(lateral) > FAR_SIDE_M
        short = len(truth["units"]) <= SHORT_RUN_UNITS
        design = designs.setdefault(truth["design"], Counter())
        design["poles_total"] += len(poles)
        in_view += int(scanned.sum())
        found_in_view += sum(1 for pi in np.flatnonzero(scanned) if (ti, int(pi)) in found)
        for pi in range(len(poles)):
            if (ti, pi) in found:
                design["poles_found"] += 1
                continue
            neighbours = scanned[max(pi - 1, 0) : pi + 2]
            if not scanned[pi]:
                if station[pi] < 0 or station[pi] > path_end:
                    cause = "beyond the drive's ends"
                else:
                    cause = "far side" if far[pi] else "occluded"
            elif short:
                cause = "short run"
            elif not neighbours.all():
                cause = "unit partly seen"
            else:
                cause = "far side, scanned" if far[pi] else "in view"
            pole_misses[cause] += 1

        if finding.beam_section_hausdorff_mm is not None:
            beams.append(finding.beam_section_hausdorff_mm)
        if truth["type"] != "pipe" or not finding.units_in_view:
            continue
        design["pipes_in_view"] += finding.pipes_total
        design["pipes_found"] += finding.pipes_found
        missed = finding.pipes_total - finding.pipes_found
        measured = [p for p in finding.pipes if not p.found]
        for pipe in measured:
            design_misses[f"{truth['design']}/{pipe.kind}"] += 1
        pipe_misses["design"] += len(measured)
        rest = missed - len(measured)  # the run was not reconstructed, or not measured
        if rest:
            if short:
                pipe_misses["short run"] += rest
            elif far.mean() > 0.5:
                pipe_misses["far side"] += rest
            else:
                pipe_misses["not reconstructed"] += rest
        for pipe in finding.pipes:
            if pipe.found and pipe.radius_err_mm is not None and pipe.axis_dev_mm is not None:
                radius.append(pipe.radius_err_mm)
                axis.append(pipe.axis_dev_mm)
    for counter in designs.values():
        for key in ("poles_total", "poles_found", "pipes_in_view", "pipes_found"):
            counter.setdefault(key, 0)
    return MissBreakdown(
        poles_total=sum(len(t["poles"]) for t in truths),
        poles_found=len(found),
        poles_in_view=in_view,
        poles_found_in_view=found_in_view,
        poles_detected=sum(len(run.poles) for run in runs),
        pole_misses={c: pole_misses[c] for c in POLE_CAUSES if pole_misses[c]},
        pipes_in_view=evaluation.overall.pipes_in_view,
        pipes_found=evaluation.overall.pipes_found,
        pipe_misses={c: pipe_misses[c] for c in PIPE_CAUSES if pipe_misses[c]},
        design_misses=dict(sorted(design_misses.items())),
        designs={name: dict(c) for name, c in sorted(designs.items())},
        pole_errors_mm=tuple(1000 * e for e in found.values()),
        radius_errors_mm=tuple(radius),
        axis_deviations_mm=tuple(axis),
        beam_hausdorff_mm=tuple(beams),
    )
