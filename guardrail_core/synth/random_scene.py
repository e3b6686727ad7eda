"""Random streets: a scene spec (:mod:`guardrail_core.synth.scene`) written from a seed, with
the guardrail designs, roadsides, street objects, kerb planting and traffic drawn at random.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from guardrail_core.errors import SceneSpecError
from guardrail_core.synth.confounders import CONFOUNDER_KINDS
from guardrail_core.synth.designs import list_designs, load_design
from guardrail_core.synth.kerb_planting import add_kerb_planting
from guardrail_core.synth.materials import PAINTS
from guardrail_core.synth.random_damage import add_damage
from guardrail_core.synth.road import SIDES
from guardrail_core.synth.scene import DEFAULT_CRS, DEFAULT_ORIGIN
from guardrail_core.synth.street_traffic import add_medians, add_traffic

# ----------------------------------------------------------------------------- random scenes

#: Where along the cross-section each kind stands: (offset from the road edge, zone).
_PLACEMENT = {
    "bollard": "curb",
    "sign_pole": "curb",
    "utility_pole": "curb",
    "pedestrian": "walk",
    "bicycle_rack": "walk",
    "tree": "walk",
    "mesh_fence": "verge",
    "bar_fence": "verge",
    "low_wall": "verge",
    "facade": "far",
    "parked_car": "road",
}
_EXTENT = {
    "mesh_fence": (8, 20),
    "bar_fence": (6, 16),
    "low_wall": (6, 18),
    "facade": (10, 25),
    "bicycle_rack": (3, 6),
}


#: Length (m) of a random street's long guardrail runs (``long_runs``): roads keep a guardrail
#: along an embankment, a bridge approach or a whole stretch of motorway.
LONG_RUN_M = (40.0, 120.0)


def random_scene_spec(
    seed: int,
    length: float,
    designs: Sequence[str] | None = None,
    *,
    roadside: bool = True,
    long_runs: float = 0.0,
    curb_height: float | None = None,
    height_jitter: float = 0.0,
    medians: float = 0.0,
    traffic: float = 0.0,
    young_trees: float = 0.0,
    damage: float = 0.0,
) -> dict:
    """A random street ``length`` metres long (plus run-in and run-out) mixing every design and kind.

    Guardrail runs take turns through ``designs`` (default: all shipped designs); confounders take
    turns through all kinds, so a drive of ~150 m or more holds each of them at least once. A run
    is 3-12 units of a 2 m design or 3-6 of a 4 m one; ``long_runs`` (0-1) of the runs are
    40-120 m long instead (:data:`LONG_RUN_M`; drawn from a stream of their own, so with 0 the
    street is that of the seed before this option). ``curb_height`` (m): the curbs' height
    (default the road's 0.15 m; 0: no curb, the sidewalks and guardrails at road level, as on a
    rural road's or a motorway's shoulder). ``height_jitter`` (0-0.5): each run is built
    ``1 + U(-height_jitter, height_jitter)`` times as tall as its design (``height_scale``), as real
    guardrails of one design stand at different heights; drawn from a stream of its own, and with
    0 no run has a ``height_scale``.
    ``medians`` (0-1): that share of the left side's beam runs are a median's near rail, with a
    second rail back to back and a hedge between (:func:`~.street_traffic.add_medians`);
    ``traffic`` (0-1): cars in the lanes beside the vehicle's (:func:`~.street_traffic.add_traffic`);
    ``young_trees`` (0-1): young trees and low hedges close behind that share of the pipe runs
    (:func:`~.kerb_planting.add_kerb_planting`); ``damage`` (0-1): that share of the runs gets
    one to three damage items (:func:`~.random_damage.add_damage`); each from a stream of its own.
    ``roadside``: the verges get embankments, ditches, hedges, shrubs and tall grass
    (:func:`_green_roadside`), drawn from a stream of their own: the road, guardrails and other
    objects are those of the same seed without them.
    """
    if length < 20:
        raise SceneSpecError(f"--length: a drive needs at least 20 m, got {length} m")
    if not 0.0 <= long_runs <= 1.0:
        raise SceneSpecError(f"--long-runs: a share from 0 to 1, got {long_runs}")
    if not 0.0 <= height_jitter <= 0.5:
        raise SceneSpecError(f"--height-jitter: 0 to 0.5, got {height_jitter}")
    for name, share in (
        ("--medians", medians),
        ("--traffic", traffic),
        ("--young-trees", young_trees),
        ("--damage", damage),
    ):
        if not 0.0 <= share <= 1.0:
            raise SceneSpecError(f"{name}: a share from 0 to 1, got {share}")
    if curb_height is not None and not 0.0 <= curb_height <= 0.5:
        raise SceneSpecError(f"--curb-height: 0 to 0.5 m, got {curb_height}")
    shipped = list_designs()
    design_pool = shipped if designs is None else list(designs)
    unknown = sorted(set(design_pool) - set(shipped))
    if unknown or not design_pool:
        raise SceneSpecError(
            f"--designs: unknown design(s) {', '.join(unknown) or '(none given)'}; "
            f"shipped designs are {', '.join(shipped)}"
        )
    rng = np.random.default_rng(seed)
    margin = 25.0
    total = length + 2 * margin
    centreline: list[dict] = []
    done = 0.0
    while done < total:
        piece = float(min(rng.uniform(25, 70), total - done))
        if round(piece, 2) <= 0:  # an arc's rounding left less than a centimetre: done
            break
        if rng.random() < 0.45 and piece > 15:
            radius = float(rng.uniform(90, 400))
            angle = float(np.rad2deg(piece / radius) * rng.choice([-1, 1]))
            centreline.append({"arc": {"radius": round(radius, 1), "angle_deg": round(angle, 3)}})
            piece = abs(np.deg2rad(round(angle, 3))) * round(radius, 1)
        else:
            centreline.append({"straight": round(piece, 2)})
        done += piece
    lanes = int(rng.choice([1, 2, 2, 2, 3]))
    sidewalk = {
        "left": round(float(rng.uniform(2.0, 4.0)), 2),
        "right": round(float(rng.uniform(2.0, 4.0)), 2),
    }
    road = {
        "heading_deg": round(float(rng.uniform(-180, 180)), 2),
        "centreline": centreline,
        "lanes": lanes,
        "lane_width": round(float(rng.uniform(2.9, 3.5)), 2),
        "grade_percent": round(float(rng.uniform(-3, 3)), 2),
        "sidewalk": sidewalk,
        "verge": 6.0,
    }
    if curb_height is not None:
        road["curb"] = {"height": float(curb_height)}
    vehicle_lane = int(rng.integers(0, lanes))
    v_lo = float(rng.uniform(5.0, 10.0))
    vehicle = {
        "lane": vehicle_lane,
        "speed_mps": [round(v_lo, 2), round(min(15.0, v_lo + rng.uniform(1, 5)), 2)],
        "start": margin,
        "end": margin + length,
    }

    queue = [str(d) for d in rng.permutation(design_pool)]
    run_lengths = np.random.default_rng([seed, 22])  # a stream of its own, as the roadside's
    run_heights = np.random.default_rng([seed, 23])
    kinds = [str(k) for k in rng.permutation(CONFOUNDER_KINDS)]
    guardrails: list[dict] = []
    objects: list[dict] = []
    # Parked cars stand in the outer lane of a side the vehicle does not drive in.
    car_sides = (
        []
        if lanes == 1
        else [
            side
            for side in SIDES
            if not (side == "left" and vehicle_lane == 0)
            and not (side == "right" and vehicle_lane == lanes - 1)
        ]
    )
    for side in SIDES:
        walk = sidewalk[side]
        s = float(rng.uniform(0, 10))
        while s < total - 8:
            design = load_design(queue.pop(0) if queue else str(rng.choice(design_pool)))
            spacing = design.unit_length
            units = int(rng.integers(3, 13 if spacing < 3 else 7))
            if run_lengths.random() < long_runs:
                units = max(3, int(round(run_lengths.uniform(*LONG_RUN_M) / spacing)))
            run = units * spacing
            if s + run > total - 2:
                units = int((total - 2 - s) // spacing)
                run = units * spacing
            if units >= 2:
                guardrails.append(
                    {
                        "design": design.name,
                        "side": side,
                        "offset": round(float(rng.uniform(0.3, 0.5)), 3),
                        "start": round(s, 3),
                        "length": round(run, 3),
                        "pole_spacing": spacing,
                        "paint": str(rng.choice(list(PAINTS))),
                    }
                )
                if height_jitter > 0:
                    scale = 1.0 + run_heights.uniform(-height_jitter, height_jitter)
                    guardrails[-1]["height_scale"] = round(float(scale), 3)
            gap_start = s + run + 1.0
            gap = float(rng.uniform(6, 18))
            # Curb-side objects stand in the gaps between runs; others anywhere along the side.
            for zone_kind in ("curb", "road"):
                at = gap_start + rng.uniform(0.5, max(1.0, gap - 2.5))
                pool = [k for k in kinds if _PLACEMENT[k] == zone_kind] or [
                    k for k in CONFOUNDER_KINDS if _PLACEMENT[k] == zone_kind
                ]
                kind = pool[0]
                if kind in kinds:
                    kinds.remove(kind)
                if kind == "parked_car" and side not in car_sides:
                    continue
                if at < total - 3:
                    objects.append(_object(kind, side, at, walk, rng))
            s = gap_start + gap
        # Behind the curb line: walkers, trees and racks on the sidewalk, fences and walls on the
        # verge, facades at the back, each zone filled independently along the whole side.
        for zone in ("walk", "verge", "far"):
            at = float(rng.uniform(2, 12))
            while at < total - 5:
                pool = [k for k in kinds if _PLACEMENT[k] == zone] or [
                    k for k in CONFOUNDER_KINDS if _PLACEMENT[k] == zone
                ]
                kind = pool[0]
                if kind in kinds:
                    kinds.remove(kind)
                item = _object(kind, side, at, walk, rng)
                extent = float(item.get("length", 1.5))
                if at + extent < total - 1:
                    objects.append(item)
                at += extent + float(rng.uniform(3, 15 if zone != "far" else 6))
    if roadside:
        road["roadside"], green = _green_roadside(
            np.random.default_rng([seed, 21]), guardrails, sidewalk, total
        )
        objects.extend(green)
    # After the roadside: its stream draws per run of the plain street.
    if medians > 0:
        add_medians(guardrails, objects, medians, np.random.default_rng([seed, 24]))
    if traffic > 0:
        span = (margin, margin + length)
        add_traffic(objects, road, vehicle_lane, span, traffic, np.random.default_rng([seed, 25]))
    if young_trees > 0:
        add_kerb_planting(guardrails, objects, young_trees, np.random.default_rng([seed, 26]))
    if damage > 0:
        add_damage(guardrails, damage, np.random.default_rng([seed, 27]))
    return {
        "name": f"random-{seed}",
        "crs": DEFAULT_CRS,
        "origin": list(DEFAULT_ORIGIN),
        "road": road,
        "vehicle": vehicle,
        "guardrails": guardrails,
        "objects": objects,
    }


def _green_roadside(
    rng: np.random.Generator, guardrails: list[dict], sidewalk: dict, total: float
) -> tuple[dict, list[dict]]:
    """The lie of each verge and the vegetation along it: ``road.roadside`` and object items.

    Per side: a level verge (40 %), an embankment rising (30 %) or falling (30 %) at 15-50 %,
    with a ditch at its foot one time in three. Behind a guardrail run, one time in three, a
    clipped hedge (a planting strip) from just behind its rails, and one time in four a shrub
    pressed against them; shrubs every 5-25 m and patches of tall grass along the verge.
    """
    curb_width = 0.18
    profile: dict = {}
    items: list[dict] = []
    for side in SIDES:
        lie = rng.choice(["level", "up", "down"], p=[0.4, 0.3, 0.3])
        slope = {"level": 0.0, "up": 1.0, "down": -1.0}[str(lie)] * rng.uniform(15, 50)
        side_profile: dict = {"slope_percent": round(float(slope), 1)}
        if rng.random() < 1 / 3:
            side_profile["ditch"] = {
                "depth": round(float(rng.uniform(0.3, 0.8)), 2),
                "width": round(float(rng.uniform(0.8, 2.0)), 2),
            }
        profile[side] = side_profile
        for run in (g for g in guardrails if g["side"] == side):
            if rng.random() < 1 / 3:
                depth = float(rng.uniform(0.5, 1.0))
                start = run["start"] + float(rng.uniform(0, 0.3)) * run["length"]
                items.append(
                    {
                        "kind": "hedge",
                        "side": side,
                        "offset": round(run["offset"] + 0.1 + depth / 2 + rng.uniform(0, 0.3), 3),
                        "at": round(start, 3),
                        "length": round(
                            float(rng.uniform(0.5, 1.0)) * (run["start"] + run["length"] - start),
                            2,
                        ),
                        "depth": round(depth, 2),
                        "height": round(float(rng.uniform(0.6, 1.3)), 2),
                    }
                )
            if rng.random() < 1 / 4:
                width = float(rng.uniform(0.6, 1.6))
                items.append(
                    {
                        "kind": "shrub",
                        "side": side,
                        "offset": round(run["offset"] + 0.05 + width / 2, 3),
                        "at": round(run["start"] + float(rng.uniform(0, run["length"])), 3),
                        "width": round(width, 2),
                    }
                )
        verge = sidewalk[side] + curb_width
        at = float(rng.uniform(2, 15))
        while at < total - 5:
            items.append(
                {
                    "kind": "shrub",
                    "side": side,
                    "offset": round(verge + float(rng.uniform(0.5, 4.0)), 3),
                    "at": round(at, 3),
                }
            )
            at += float(rng.uniform(5, 25))
        at = float(rng.uniform(0, 10))
        while at < total - 6:
            patch = float(rng.uniform(5, 20))
            patch = min(patch, total - 1 - at)
            items.append(
                {
                    "kind": "tall_grass",
                    "side": side,
                    "offset": round(verge + float(rng.uniform(0.0, 1.0)), 3),
                    "at": round(at, 3),
                    "length": round(patch, 2),
                }
            )
            at += patch + float(rng.uniform(3, 15))
    return profile, items


def _object(kind: str, side: str, at: float, walk: float, rng: np.random.Generator) -> dict:
    zone = _PLACEMENT[kind]
    curb_width = 0.18
    offset = {
        "curb": float(rng.uniform(0.35, 0.6)),
        "road": -1.05,
        "walk": float(rng.uniform(curb_width + 0.9, max(curb_width + 1.0, walk - 0.6))),
        "verge": walk + curb_width + float(rng.uniform(0.3, 1.5)),
        "far": walk + curb_width + float(rng.uniform(3.0, 5.5)),
    }[zone]
    item: dict = {"kind": kind, "side": side, "offset": round(offset, 3), "at": round(float(at), 3)}
    if kind in _EXTENT:
        lo, hi = _EXTENT[kind]
        item["length"] = round(float(rng.uniform(lo, hi)), 2)
    if kind in {"mesh_fence", "bar_fence", "bicycle_rack", "bollard", "utility_pole", "sign_pole"}:
        item["paint"] = str(rng.choice(list(PAINTS)))
    return item
