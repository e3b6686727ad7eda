"""Make the README figures of the reconstruction (§4): every design's unit beside the truth.

Usage::

    .venv/bin/guardrail simulate /tmp/sweep --scene units_sweep --image-every 20 \\
        --image-size 640x480
    .venv/bin/guardrail process /tmp/sweep --model demo_output/model --out /tmp/sweep_run
    .venv/bin/python docs/make_reconstruction_figures.py --drive /tmp/sweep --run /tmp/sweep_run

Writes into ``--out`` (default docs/images):

``reconstruction_units.png``
    one panel per run of the units-sweep street, in unit coordinates (x along the unit from its
    first pole, y above the ground; for beams the section, z toward the road against y): the
    superimposed points of all its units (grey), the true pipes or section (thick, light red)
    and the reconstruction (blue), with the pipes found.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from guardrail_core.errors import RunFolderError  # noqa: E402
from guardrail_core.evaluate.reconstruction import (  # noqa: E402
    ReconstructionMatch,
    evaluate_reconstruction,
    match_poles,
    measured_units,
    truth_guardrails,
)
from guardrail_core.formats.drive import load_drive  # noqa: E402
from guardrail_core.reconstruct.run_models import load_run_models  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drive", type=Path, required=True)
    parser.add_argument("--run", type=Path, required=True)
    parser.add_argument("--out", type=Path, default=Path("docs/images"))
    args = parser.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    drive = load_drive(args.drive)
    models = load_run_models(args.run)
    runs = list(models.runs)
    truths = truth_guardrails(drive.truth.objects)
    matched, _ = match_poles(runs, truths, ReconstructionMatch())
    result = evaluate_reconstruction(runs, drive.truth.objects)
    found = {r.run_id: r for r in result.runs if r.run_id is not None}

    panels = []
    for ri, run in enumerate(runs):
        ti, units = measured_units(ri, run, matched, truths)
        if ti is None or run.model is None or not units or run.run_id not in found:
            continue  # the figure shows the run each true guardrail was measured on
        panels.append((run, truths[ti], units))
    panels.sort(key=lambda p: (p[1]["type"], p[1]["design"]))
    cols = 5
    rows = int(np.ceil(len(panels) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.9 * rows), dpi=110)
    for ax in np.ravel(axes)[len(panels) :]:
        ax.axis("off")
    for ax, (run, truth, units) in zip(np.ravel(axes), panels, strict=False):
        try:
            points = models.superimposed_points(run.run_id)
        except RunFolderError:  # a run without superimposed points
            points = np.zeros((0, 3))
        model = run.model
        _, frame, true_unit = units[0]
        if model.type == "beam":
            ax.scatter(points[:, 2], points[:, 1], s=0.2, c="0.6", rasterized=True)
            true_section = np.asarray(truth["beams"][0]["section"])
            ax.plot(*true_section.T, color="#f4a3a3", lw=5, solid_capstyle="round")
            if model.section is not None:
                ax.plot(*model.section.T, color="#1f4e9c", lw=1.3)
            ax.set_xlabel("z toward the road (m)")
            figure = found[run.run_id].beam_section_hausdorff_mm
            caption = f"section within {figure:.1f} mm" if figure is not None else "no section"
            ax.set_aspect("equal")
        else:
            ax.scatter(points[:, 0], points[:, 1], s=0.2, c="0.6", rasterized=True)
            for pipe in truth["pipes"]:
                if pipe["unit"] == true_unit:
                    axis = frame.to_unit(np.asarray(pipe["axis"]))
                    ax.plot(axis[:, 0], axis[:, 1], color="#f4a3a3", lw=5, solid_capstyle="round")
            scale = frame.length / model.length
            for pipe in model.pipes:
                ax.plot(pipe.axis[:, 0] * scale, pipe.axis[:, 1], color="#1f4e9c", lw=1.3)
            record = found[run.run_id]
            caption = f"{record.pipes_found}/{record.pipes_total} pipes found"
            ax.set_xlim(-0.1, frame.length + 0.1)
            ax.set_xlabel("x along the unit (m)")
        ax.set_ylim(-0.05, 1.2)
        ax.set_title(f"{truth['design']}: {model.n_units} units\n{caption}", fontsize=9)
        ax.tick_params(labelsize=7)
        ax.set_ylabel("y above ground (m)", fontsize=8)
    fig.suptitle(
        "Reconstructed unit shapes (blue) on the truth (red), superimposed points in grey",
        fontsize=11,
    )
    fig.tight_layout()
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "reconstruction_units.png"
    fig.savefig(path)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
