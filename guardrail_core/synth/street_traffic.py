"""What real scans of multi-lane roads hold and plain random streets lacked: medians of two
beams back to back with a hedge between, and cars in the lanes beside the mapping vehicle.

Each is added to a random street's spec
(:func:`~guardrail_core.synth.random_scene.random_scene_spec`) from a random stream of its own, so
a street without them is the street of the same seed.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.synth.designs import load_design

#: Metres between a median's two rails (post line to post line): German and British motorway
#: medians hold a hedge or a planted strip of one to two metres between them.
MEDIAN_GAP_M = (1.2, 2.2)
#: Metres between cars in a lane of traffic (bumper to bumper), when there is traffic.
CAR_GAP_M = (6.0, 40.0)


def add_medians(
    guardrails: list[dict], objects: list[dict], share: float, rng: np.random.Generator
) -> None:
    """Make ``share`` (0-1) of the left side's beam runs a median: a second run of the same
    design, ``facing: away`` (its beam on the far side of its posts, toward the opposite
    carriageway), 1.2-2.2 m farther out, and, two times in three, a clipped hedge between them.

    ``guardrails`` and ``objects`` are the spec's lists, extended in place (the new runs after
    every other run).
    """
    for run in [g for g in guardrails if g["side"] == "left"]:
        if load_design(run["design"]).type != "beam" or rng.random() >= share:
            continue
        gap = float(rng.uniform(*MEDIAN_GAP_M))
        guardrails.append({**run, "offset": round(run["offset"] + gap, 3), "facing": "away"})
        if rng.random() < 2 / 3:
            depth = max(0.4, gap - 0.7)
            objects.append(
                {
                    "kind": "hedge",
                    "side": "left",
                    "offset": round(run["offset"] + gap / 2, 3),
                    "at": run["start"],
                    "length": run["length"],
                    "depth": round(depth, 2),
                    "height": round(float(rng.uniform(0.5, 1.3)), 2),
                }
            )


def add_traffic(
    objects: list[dict],
    road: dict,
    vehicle_lane: int,
    span: tuple[float, float],
    share: float,
    rng: np.random.Generator,
) -> None:
    """Cars in the lanes next to the vehicle's, along ``span`` (metres along the road): in each
    such lane, a car every 6-40 m, each one kept with probability ``share`` (0-1). They stand
    still: a frame of a spinning LiDAR catches a moving car as it catches a standing one, 2-4 m
    beside the scanner, the height of a guardrail's rail at its sills.

    ``road`` is the spec's road (lanes, lane width); ``objects`` is extended in place.
    """
    lanes, width = int(road["lanes"]), float(road["lane_width"])
    half = lanes * width / 2
    for lane in (vehicle_lane - 1, vehicle_lane + 1):
        if not 0 <= lane < lanes:
            continue
        # Lane 0's centre is at -half + width / 2 (synth.vehicle); left is positive.
        lateral = -half + (lane + 0.5) * width
        side = "left" if lateral >= 0 else "right"
        offset = abs(lateral) - half
        at = span[0] + float(rng.uniform(0, CAR_GAP_M[1]))
        while at < span[1]:
            if rng.random() < share:
                objects.append(
                    {
                        "kind": "parked_car",
                        "side": side,
                        "offset": round(offset, 3),
                        "at": round(at, 3),
                    }
                )
            at += float(rng.uniform(*CAR_GAP_M)) + 4.5
