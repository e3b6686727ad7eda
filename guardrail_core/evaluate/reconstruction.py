"""Reconstruction against the truth of a synthetic drive: poles, units, pipes and beam sections.

The figures of ``guardrail evaluate`` under ``reconstruction.*`` and the paper's experiment of
§5.2 (pipes found against the number of superimposed units).

Matching rules
--------------
- A true pole is found when a detected pole's axis stands within ``pole_match_m`` of it
  (horizontal distance); its error is that distance.
- A reconstructed run belongs to the true guardrail that most of its matched poles belong to.
- A unit is measured when both its poles matched consecutive poles of the same true guardrail;
  its length error compares the horizontal distances between the poles.
- A true pipe of a unit is found when one reconstructed axis, copied into that unit, stays within
  max(2 r, 20 mm) of it along >= 80% of its length. A pipe of the design counts as found when it
  is found in at least half of the run's measured units (the model is one unit shape copied
  between the poles, so this counts the pipes of the unit shape, as §5.2 does).
- Radius error and axis deviation are taken over found pipes, in the unit frame, where the
  axis deviation is the mean distance of the true axis to the reconstructed one (mm).
- The beam section's error is the symmetric Hausdorff distance between the reconstructed and the
  true section curves (mm), in (across the post axis toward the road, up) coordinates.
- Given the drive's points, a true guardrail is in view when at least one of its units has both
  poles scanned (``pole_points`` of its own points within ``pole_reach_m`` of each axis): no
  unit shape can be made of a guardrail the scanner never saw two poles of (one on a side
  street, behind a wall). Its pipes still count in ``pipes_total``; ``pipes_in_view`` counts
  those of the guardrails in view.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.evaluate.results import (
    GuardrailFinding,
    PipeFinding,
    ReconstructionEvaluation,
    ReconstructionFigures,
)
from guardrail_core.reconstruct.model import RunModel, UnitModel
from guardrail_core.reconstruct.unit_frame import UnitFrame


@dataclass(frozen=True)
class ReconstructionMatch:
    """Tolerances of the comparison (metres and shares)."""

    pole_match_m: float = 0.3  # a detected pole this close (horizontally) to a true one matches
    pipe_tolerance_radii: float = 2.0  # a pipe's axis within this many radii ...
    pipe_tolerance_min_m: float = 0.02  # ... or this many metres, whichever is larger
    pipe_coverage: float = 0.8  # ... along at least this share of the true pipe's length
    unit_share: float = 0.5  # a design pipe is found when found in this share of the units
    sample_step_m: float = 0.005  # curves are compared at samples this far apart
    pole_reach_m: float = 0.1  # a pole is scanned when this close to its axis (horizontally)
    pole_points: int = 10  # ... lie at least this many of its guardrail's points


def densify(polyline: np.ndarray, step: float) -> np.ndarray:
    """Points (M, D) along a polyline (K, D) no farther apart than ``step``, ends included."""
    polyline = np.asarray(polyline, np.float64)
    if len(polyline) < 2:
        return polyline.copy()
    out = [polyline[:1]]
    for a, b in zip(polyline[:-1], polyline[1:], strict=True):
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        t = np.arange(1, n + 1)[:, None] / n
        out.append(a + t * (b - a))
    return np.concatenate(out)


def _distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance (N,) of points (N, D) to a polyline (K, D), exact (segment projections)."""
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    length2 = np.maximum((ab**2).sum(axis=1), 1e-18)
    rel = points[:, None, :] - a[None]
    t = np.clip((rel * ab[None]).sum(axis=2) / length2[None], 0.0, 1.0)
    nearest = a[None] + t[..., None] * ab[None]
    return np.sqrt(((points[:, None, :] - nearest) ** 2).sum(axis=2)).min(axis=1)


def hausdorff(a: np.ndarray, b: np.ndarray, step: float = 0.002) -> float:
    """Symmetric Hausdorff distance between two polylines (K, D), (L, D), same units."""
    pa, pb = densify(a, step), densify(b, step)
    return float(max(cKDTree(pb).query(pa)[0].max(), cKDTree(pa).query(pb)[0].max()))


def truth_guardrails(objects: list[dict]) -> list[dict]:
    """The guardrail records of ``truth/objects.json``."""
    return [o for o in objects if o.get("kind") == "guardrail"]


def match_poles(
    runs: list[RunModel], truths: list[dict], match: ReconstructionMatch
) -> tuple[dict[tuple[int, int], tuple[int, int, float]], int]:
    """Detected pole (run index, pole index) -> (truth index, truth pole index, error m)."""
    true_xy, owner = [], []
    for ti, t in enumerate(truths):
        for pi, p in enumerate(t["poles"]):
            true_xy.append(p["position"][:2])
            owner.append((ti, pi))
    matched: dict[tuple[int, int], tuple[int, int, float]] = {}
    if not true_xy:
        return matched, 0
    tree = cKDTree(np.asarray(true_xy))
    candidates = []
    for ri, run in enumerate(runs):
        for pi, pole in enumerate(run.poles):
            dist, k = tree.query(pole.position[:2])
            if dist <= match.pole_match_m:
                candidates.append((float(dist), ri, pi, int(k)))
    taken: set[int] = set()
    for dist, ri, pi, k in sorted(candidates):  # one detection per true pole, closest first
        if k not in taken:
            taken.add(k)
            matched[(ri, pi)] = (*owner[k], dist)
    return matched, len(true_xy)


def units_in_view(
    xyz: np.ndarray,
    point_object: np.ndarray,
    objects: list[dict],
    match: ReconstructionMatch = ReconstructionMatch(),
) -> dict[int, int]:
    """Per true guardrail id, how many of its units have both poles scanned.

    Parameters
    ----------
    xyz : (N, 3) float64, metres: the drive's points, local frame
    point_object : (N,) int: the truth object id of every point
    objects : ``truth/objects.json``
    """
    counter = PolePointCounter(objects, match)
    counter.add(xyz, point_object)
    return counter.units_in_view()


class PolePointCounter:
    """Points of each true guardrail within ``match.pole_reach_m`` of each of its poles,
    counted piece by piece (a drive read tile by tile); :meth:`units_in_view` as the function
    of that name."""

    def __init__(
        self, objects: list[dict], match: ReconstructionMatch = ReconstructionMatch()
    ) -> None:
        self.match = match
        self.guardrails = truth_guardrails(objects)
        self.poles = [
            np.array([p["position"][:2] for p in t["poles"]], np.float64).reshape(-1, 2)
            for t in self.guardrails
        ]
        self.counts = [np.zeros(len(p), np.int64) for p in self.poles]

    def add(self, xyz: np.ndarray, point_object: np.ndarray) -> None:
        """Count (n, 3) points with their (n,) object ids."""
        point_object = np.asarray(point_object)
        for t, poles, counts in zip(self.guardrails, self.poles, self.counts, strict=True):
            own = np.asarray(xyz)[point_object == t["id"], :2]
            if len(own) == 0 or len(poles) == 0:
                continue
            near = cKDTree(own).query_ball_point(poles, self.match.pole_reach_m)
            counts += np.array([len(c) for c in near], np.int64)

    def units_in_view(self) -> dict[int, int]:
        out: dict[int, int] = {}
        for t, counts in zip(self.guardrails, self.counts, strict=True):
            seen = counts >= self.match.pole_points
            out[t["id"]] = (
                int(sum(bool(seen[u["start_pole"]] and seen[u["end_pole"]]) for u in t["units"]))
                if len(seen)
                else 0
            )
        return out


def _truth_frame(truth: dict, unit: int, frame: UnitFrame) -> UnitFrame:
    """The true frame of a true unit, with the detected frame's direction along the run."""
    a = np.asarray(truth["poles"][unit]["position"], np.float64)
    b = np.asarray(truth["poles"][unit + 1]["position"], np.float64)
    if np.dot(b - a, frame.along) < 0:
        a, b = b, a
    return UnitFrame.between(a, b)


def pipes_in_unit(model: UnitModel, frame: UnitFrame) -> list[np.ndarray]:
    """Model pipe axes (K, 3) copied into a unit of ``frame.length`` (x stretched)."""
    scale = np.array([frame.length / model.length, 1.0, 1.0]) if model.length > 0 else 1.0
    return [p.axis * scale for p in model.pipes]


def evaluate_pipes(
    model: UnitModel,
    frames: list[UnitFrame],
    true_units: list[list[dict]],
    match: ReconstructionMatch = ReconstructionMatch(),
) -> list[PipeFinding]:
    """Which pipes of a design a unit model reconstructs.

    Parameters
    ----------
    model : the unit model (unit coordinates)
    frames : the detected frames of the measured units
    true_units : per measured unit, its true pipes (``objects.json`` records, world axes), in
        the same order in every unit (the design's order)

    Returns
    -------
    One finding per design pipe (the errors are medians over the units where it was found, None
    where it never was).
    """
    if not true_units:
        return []
    n_pipes = len(true_units[0])
    out = []
    for j in range(n_pipes):
        found_in, radius_err, axis_dev = 0, [], []
        for frame, pipes in zip(frames, true_units, strict=True):
            true_pipe = pipes[j]
            r = float(true_pipe["radius"])
            tol = max(match.pipe_tolerance_radii * r, match.pipe_tolerance_min_m)
            samples = densify(frame.to_unit(np.asarray(true_pipe["axis"])), match.sample_step_m)
            best = None
            for axis, pipe in zip(pipes_in_unit(model, frame), model.pipes, strict=True):
                if len(axis) < 2:
                    continue
                d = _distance_to_polyline(samples, axis)
                coverage = float((d <= tol).mean())
                if coverage >= match.pipe_coverage and (best is None or d.mean() < best[1]):
                    best = (pipe, float(d.mean()))
            if best is not None:
                found_in += 1
                radius_err.append(abs(best[0].radius - r) * 1000)
                axis_dev.append(best[1] * 1000)
        found = found_in >= match.unit_share * len(frames) and found_in > 0
        out.append(
            PipeFinding(
                kind=true_units[0][j]["kind"],
                radius_mm=round(float(true_units[0][j]["radius"]) * 1000, 2),
                found=bool(found),
                found_in_units=found_in,
                radius_err_mm=float(np.median(radius_err)) if radius_err else None,
                axis_dev_mm=float(np.median(axis_dev)) if axis_dev else None,
            )
        )
    return out


def measured_units(
    run_index: int, run: RunModel, matched: dict, truths: list[dict]
) -> tuple[int | None, list[tuple[int, UnitFrame, int]]]:
    """The true guardrail of a run and its measured units as (unit index, frame, true unit)."""
    owners = [
        matched[(run_index, p)][0] for p in range(len(run.poles)) if (run_index, p) in matched
    ]
    if not owners:
        return None, []
    truth_index = max(set(owners), key=owners.count)
    units = []
    for u, frame in enumerate(run.units):
        a, b = matched.get((run_index, u)), matched.get((run_index, u + 1))
        if a is None or b is None or a[0] != truth_index or b[0] != truth_index:
            continue
        if abs(a[1] - b[1]) == 1:
            units.append((u, frame, min(a[1], b[1])))
    return truth_index, units


def evaluate_reconstruction(
    runs: list[RunModel],
    objects: list[dict],
    match: ReconstructionMatch = ReconstructionMatch(),
    in_view: dict[int, int] | None = None,
) -> ReconstructionEvaluation:
    """Compare reconstructed runs with the truth guardrails of ``objects.json``.

    ``in_view`` (from :func:`units_in_view`) gives each true guardrail's units with both poles
    scanned; without it every guardrail counts as in view.

    Returns
    -------
    The figures over all true guardrails (``overall``) and per design (``designs``, sorted by
    name), and one finding per true guardrail (``runs``, in ``objects.json``'s order); None
    where nothing was measured.
    """
    truths = truth_guardrails(objects)
    matched, _ = match_poles(runs, truths, match)
    per_truth: dict[int, dict[str, Any]] = {}
    for ti, t in enumerate(truths):
        per_truth[ti] = {
            "truth_id": t["id"],
            "design": t["design"],
            "type": t["type"],
            "run_id": None,
            "poles_total": len(t["poles"]),
            "pole_errors_mm": [],
            "unit_length_errors_mm": [],
            "pipes": [],
            "pipes_total": len(t["pipes"]) // max(len(t["units"]), 1) if t["type"] == "pipe" else 0,
            "beam_section_hausdorff_mm": None,
            "units_in_view": None if in_view is None else in_view.get(t["id"], 0),
        }
    for owner, _, dist in matched.values():
        per_truth[owner]["pole_errors_mm"].append(dist * 1000)

    for ri, run in enumerate(runs):
        truth_index, units = measured_units(ri, run, matched, truths)
        if truth_index is None:
            continue
        record, truth = per_truth[truth_index], truths[truth_index]
        if record["run_id"] is not None and len(record["unit_length_errors_mm"]) >= len(units):
            continue  # another, longer reconstruction of the same guardrail is measured
        record["run_id"] = run.run_id
        record["unit_length_errors_mm"] = []
        for _, frame, true_unit in units:
            true_frame = _truth_frame(truth, true_unit, frame)
            record["unit_length_errors_mm"].append(abs(frame.length - true_frame.length) * 1000)
        model = run.model
        if model is None or not units:
            continue
        if truth["type"] == "pipe" and model.type == "pipe":
            by_unit = defaultdict(list)
            for p in truth["pipes"]:
                by_unit[p["unit"]].append(p)
            record["pipes"] = evaluate_pipes(
                model, [f for _, f, _ in units], [by_unit[tu] for _, _, tu in units], match
            )
        elif truth["type"] == "beam" and model.type == "beam" and model.section is not None:
            true_section = np.asarray(truth["beams"][0]["section"], np.float64)
            record["beam_section_hausdorff_mm"] = hausdorff(model.section, true_section) * 1000

    designs: dict[str, list[dict]] = defaultdict(list)
    for record in per_truth.values():
        designs[record["design"]].append(record)
    return ReconstructionEvaluation(
        overall=_figures(list(per_truth.values())),
        designs={name: _figures(records) for name, records in sorted(designs.items())},
        runs=tuple(_finding(r) for r in per_truth.values()),
    )


def _figures(records: list[dict]) -> ReconstructionFigures:
    pipes: list[PipeFinding] = [p for r in records for p in r["pipes"]]
    found = [p for p in pipes if p.found]
    radius = [p.radius_err_mm for p in found if p.radius_err_mm is not None]
    axis = [p.axis_dev_mm for p in found if p.axis_dev_mm is not None]
    poles = [e for r in records for e in r["pole_errors_mm"]]
    units = [e for r in records for e in r["unit_length_errors_mm"]]
    beams = [r["beam_section_hausdorff_mm"] for r in records if r["type"] == "beam"]
    beams_measured = [b for b in beams if b is not None]
    seen = [r for r in records if r["units_in_view"] is None or r["units_in_view"] > 0]
    return ReconstructionFigures(
        pipes_found=len(found),
        pipes_total=sum(r["pipes_total"] for r in records),
        pipes_in_view=sum(r["pipes_total"] for r in seen),
        guardrails_total=len(records),
        guardrails_in_view=len(seen),
        radius_err_mm_median=_median(radius),
        axis_dev_mm_mean=float(np.mean(axis)) if axis else None,
        beam_section_hausdorff_mm=_median(beams_measured),
        beams_reconstructed=len(beams_measured),
        beams_total=len(beams),
        poles_found=len(poles),
        poles_total=sum(r["poles_total"] for r in records),
        pole_pos_err_mm_median=_median(poles),
        unit_length_err_mm_median=_median(units),
    )


def _finding(record: dict) -> GuardrailFinding:
    """A true guardrail's working record (see :func:`evaluate_reconstruction`) as its finding."""
    return GuardrailFinding(
        truth_id=record["truth_id"],
        design=record["design"],
        type=record["type"],
        run_id=record["run_id"],
        poles_total=record["poles_total"],
        pipes=tuple(record["pipes"]),
        pipes_total=record["pipes_total"],
        beam_section_hausdorff_mm=record["beam_section_hausdorff_mm"],
        units_in_view=record["units_in_view"],
        poles_found=len(record["pole_errors_mm"]),
        units_measured=len(record["unit_length_errors_mm"]),
        pipes_found=sum(p.found for p in record["pipes"]),
    )


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None
