"""The experiment of §5.2: pipes found against the number of superimposed units, per design.

Each run is reconstructed again from only its first k units (superimposed with ICP), for every k
asked, and its unit model is measured against the truth with
:func:`guardrail_core.evaluate.reconstruction.evaluate_reconstruction`. Beams count as found when
their section is within ``beam_tolerance_mm`` (Hausdorff) of the truth.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.errors import InvalidOptionError
from guardrail_core.evaluate.reconstruction import evaluate_reconstruction
from guardrail_core.evaluate.results import DesignSweep, GuardrailFinding, UnitsSweep
from guardrail_core.formats.drive import Drive
from guardrail_core.formats.run_folder import POINT_ROAD, Run
from guardrail_core.reconstruct.pipeline import (
    ReconstructionParams,
    guardrail_mask,
    reconstruct_guardrails,
)

#: A beam section within this Hausdorff distance (mm) of the truth counts as found.
BEAM_TOLERANCE_MM = 10.0


def parse_units(text: str) -> list[int]:
    """``"1,2,4"`` -> [1, 2, 4]; raises InvalidOptionError on anything but positive integers."""
    try:
        values = sorted({int(v) for v in text.split(",") if v.strip()})
    except ValueError as exc:
        raise InvalidOptionError(
            f"--units-sweep expects integers like 1,2,4,8, got {text!r}"
        ) from exc
    if not values or values[0] < 1:
        raise InvalidOptionError(f"--units-sweep expects positive integers, got {text!r}")
    return values


def units_sweep(
    drive: Drive,
    run: Run,
    units: list[int],
    *,
    params: ReconstructionParams = ReconstructionParams(),
    progress: bool = False,
) -> UnitsSweep:
    """Pipes found per design for every number of superimposed units.

    Returns
    -------
    The numbers of units and per design, for each of them, the pipes found of how many, and the
    smallest number with every pipe found. For beam designs ``found``/``total`` count beam runs
    whose section is within :data:`BEAM_TOLERANCE_MM`, and ``worst_section_hausdorff_mm`` holds
    the largest section Hausdorff (mm) of the design's runs for every k (None where no section
    was measured).
    """
    if drive.truth is None:
        raise InvalidOptionError(f"{drive.root}: the units sweep needs a drive with truth/")
    guardrail = guardrail_mask(run.point_segment, run.segments["label"])
    ground = run.point_segment == POINT_ROAD
    designs: dict[str, dict[str, Any]] = {}
    for k in units:
        rec = reconstruct_guardrails(
            drive.points.xyz,
            guardrail,
            ground,
            drive.trajectory.position,
            params=params,
            max_units=k,
            progress=progress,
        )
        result = evaluate_reconstruction(rec.runs, drive.truth.objects)
        by_design: dict[str, list[GuardrailFinding]] = {}
        for record in result.runs:
            by_design.setdefault(record.design, []).append(record)
        for design, records in sorted(by_design.items()):
            kind = records[0].type
            entry = designs.setdefault(design, {"type": kind, "found": [], "total": []})
            if kind == "beam":
                measured = [
                    r.beam_section_hausdorff_mm
                    for r in records
                    if r.beam_section_hausdorff_mm is not None
                ]
                found = sum(h <= BEAM_TOLERANCE_MM for h in measured)
                total = len(records)
                worst = entry.setdefault("worst_section_hausdorff_mm", [])
                worst.append(round(max(measured), 2) if measured else None)
            else:
                found = sum(r.pipes_found for r in records)
                total = sum(r.pipes_total for r in records)
            entry["found"].append(int(found))
            entry["total"].append(int(total))
    out: dict[str, DesignSweep] = {}
    for design, entry in designs.items():
        complete = [
            k for k, f, t in zip(units, entry["found"], entry["total"], strict=True) if t and f == t
        ]
        worst = entry.get("worst_section_hausdorff_mm")
        out[design] = DesignSweep(
            type=entry["type"],
            found=tuple(entry["found"]),
            total=tuple(entry["total"]),
            worst_section_hausdorff_mm=None if worst is None else tuple(worst),
            complete_from=complete[0] if complete else None,
        )
    return UnitsSweep(units=tuple(units), designs=out)


def format_units_sweep(result: UnitsSweep) -> str:
    """The sweep as a text table: one row per design, one column per number of units."""
    units = result.units
    width = max([len(d) for d in result.designs] + [6])
    head = f"{'design':<{width}}  " + "  ".join(f"{k:>6}" for k in units) + "  complete from"
    lines = ["pipes found against the number of superimposed units (§5.2)", head]
    for design, entry in result.designs.items():
        cells = "  ".join(f"{f:>3}/{t:<2}" for f, t in zip(entry.found, entry.total, strict=True))
        done = entry.complete_from
        lines.append(f"{design:<{width}}  {cells}  {done if done is not None else 'never'}")
        if entry.worst_section_hausdorff_mm is not None:
            mm = "  ".join(
                "     -" if h is None else f"{h:>6.1f}" for h in entry.worst_section_hausdorff_mm
            )
            lines.append(f"{'  section, mm':<{width}}  {mm}")
    if any(e.worst_section_hausdorff_mm is not None for e in result.designs.values()):
        lines.append(
            f"beams: found when the section is within {BEAM_TOLERANCE_MM:g} mm (Hausdorff);"
        )
        lines.append("section, mm: the largest Hausdorff of the design's runs")
    return "\n".join(lines)


def plot_units_sweep(result: UnitsSweep, path: str | Path) -> Path:
    """Write the sweep as a PNG line plot (share of pipes found against units, log2 axis)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    units = np.asarray(result.units)
    fig, ax = plt.subplots(figsize=(7.5, 4.5), dpi=120)
    for design, entry in result.designs.items():
        found, total = np.asarray(entry.found, float), np.asarray(entry.total, float)
        share = np.divide(found, total, out=np.zeros_like(found), where=total > 0)
        style = "--" if entry.type == "beam" else "-"
        ax.plot(units, 100 * share, style, marker="o", label=design)
    ax.set_xscale("log", base=2)
    ax.set_xticks(units, [str(k) for k in units])
    ax.set_xlabel("superimposed units")
    ax.set_ylabel("pipes found (%)  [beams: section within 10 mm]")
    ax.set_ylim(-3, 103)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="lower right", ncol=2)
    ax.set_title("Pipes found against superimposed units (Matsumoto et al. 2019, §5.2)")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
