"""Random damage on a random street's guardrail runs (``guardrail simulate --damage SHARE``).

Kinds and magnitudes are drawn in the ranges of the condition benchmark (issue 79): dents
10-100 mm deep and 0.3-1.5 m long, posts leaning 2-10 degrees, pipes bent 20-100 mm, runs
lowered 10-80 mm by repaving, and ends missing or bent 50-300 mm.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.synth.designs import load_design

DENT_DEPTH_M = (0.01, 0.1)
DENT_LENGTH_M = (0.3, 1.5)
LEAN_DEG = (2.0, 10.0)
BENT_M = (0.02, 0.1)
DROP_M = (0.01, 0.08)
END_BENT_M = (0.05, 0.3)


def add_damage(guardrails: list[dict], share: float, rng: np.random.Generator) -> None:
    """Give ``share`` (0-1) of ``guardrails`` (scene spec items, edited in place) a ``damage``
    list of one to three items of different kinds.

    Each run draws from ``rng`` the same count of numbers whether or not it is damaged, so
    which runs are damaged does not change how the others are. Runs of fewer than three units
    are left whole; targets keep off a run's end unit and end posts, so an ``end_missing``
    drawn with them takes nothing they name.
    """
    for run in guardrails:
        design = load_design(run["design"])
        units = int(np.floor(run["length"] / run["pole_spacing"] + 1e-9))
        draws = rng.random(16)  # a fixed count per run: a stream that does not drift
        if draws[0] >= share or units < 3:
            continue
        kinds = ["dent", "missing_post", "leaning_post", "lowered", "end_missing", "end_damaged"]
        if design.pipes:
            kinds += ["bent_pipe", "missing_pipe"]
        n = 1 + int(draws[1] * 3)
        picked = [kinds[int(k)] for k in np.argsort(draws[2 : 2 + len(kinds)])[:n]]
        if "end_missing" in picked and "end_damaged" in picked:
            picked.remove("end_damaged")
        u = draws[10:16]
        inner_unit = 1 + int(u[0] * (units - 2))  # 1..units-2
        inner_pole = 1 + int(u[1] * (units - 1))  # 1..units-1
        items = []
        for kind in picked:
            item: dict = {"kind": kind}
            if kind == "dent":
                length = _between(DENT_LENGTH_M, u[2])
                item.update(
                    at_m=round((inner_unit + 0.2 + 0.6 * u[3]) * run["pole_spacing"], 3),
                    depth_m=round(_between(DENT_DEPTH_M, u[4]), 4),
                    length_m=round(length, 3),
                )
            elif kind in ("bent_pipe", "missing_pipe"):
                pipe = int(u[5] * len(design.pipes))
                if kind == "missing_pipe" and "bent_pipe" in picked:
                    if len(design.pipes) == 1:
                        continue
                    pipe = (pipe + 1) % len(design.pipes)  # not the bent one
                item.update(unit=inner_unit, pipe=pipe)
                if kind == "bent_pipe":
                    item["offset_m"] = round(_between(BENT_M, u[4]), 4)
            elif kind == "missing_post":
                item["pole"] = inner_pole
            elif kind == "leaning_post":
                item.update(
                    pole=1 + (inner_pole % (units - 1)),  # not the missing one
                    lean_deg=round(_between(LEAN_DEG, u[3]), 2),
                    direction="away" if u[5] < 0.7 else "forward",
                )
            elif kind == "lowered":
                item["drop_m"] = round(_between(DROP_M, u[2]), 4)
            elif kind == "end_damaged":
                item["offset_m"] = round(_between(END_BENT_M, u[5]), 3)
            items.append(item)
        run["damage"] = items


def _between(bounds: tuple[float, float], u: float) -> float:
    return float(bounds[0] + (bounds[1] - bounds[0]) * u)
