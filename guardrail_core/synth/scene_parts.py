"""A scene as parts built one at a time: stretches of road, guardrail runs, street objects.

The mesh of a long drive's scene does not fit in memory at once, so the simulator builds only
the parts within the scanner's reach of the stretch it scans (:mod:`.scene_window`). A part's
faces are the same whichever other parts are built with it: it draws its random shapes and
paint from its own stream, the scene seed's child named by its object id
(:func:`~guardrail_core.synth.random_streams.child_rng`), and a stretch of road is a range of
the whole road's mesh rows.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from guardrail_core.errors import SceneSpecError
from guardrail_core.synth.confounders import CONFOUNDER_KINDS, build_confounder
from guardrail_core.synth.damage import Damage, parse_damage
from guardrail_core.synth.designs import Design, load_design, scaled_height
from guardrail_core.synth.guardrail import build_guardrail_run
from guardrail_core.synth.mesh import MeshBuilder, SceneMesh
from guardrail_core.synth.random_streams import child_rng
from guardrail_core.synth.road import SIDES, Road
from guardrail_core.synth.spec_values import spec_paint, spec_side, spec_value
from guardrail_core.synth.vegetation import (
    EXTENDED_VEGETATION,
    SIZES,
    VEGETATION_KINDS,
    build_vegetation,
    vegetation_sizes,
)

#: Which way a run's beams face: the road beside it, or away (a median's far rail).
FACINGS = ("road", "away")
#: Mesh rows of road per part: 25 m at the road mesh's 0.5 m rows.
ROAD_ROWS_PER_PART = 50


@dataclass(frozen=True)
class ScenePart:
    """One piece of a scene that is built as a unit.

    Attributes
    ----------
    name : str, where it comes from (``road rows 0..50``, ``guardrails[3]``, ``objects[5][2]``)
    build : adds the part's faces to a :class:`MeshBuilder` and returns its truth record
        (``truth/objects.json``), or None for the road
    """

    name: str
    build: Callable[[MeshBuilder], dict | None]

    def mesh(self) -> tuple[SceneMesh, dict | None]:
        """The part alone as a mesh, and its truth record."""
        builder = MeshBuilder()
        record = self.build(builder)
        return builder.build(), record


def part_rng(seed: int, object_id: int) -> np.random.Generator:
    """The random stream of the object ``object_id`` of a scene built from ``seed``."""
    return child_rng(np.random.SeedSequence(seed), object_id)


def road_parts(road: Road) -> list[ScenePart]:
    """The road's mesh in stretches of :data:`ROAD_ROWS_PER_PART` rows (neighbours share a row)."""
    last = len(road.mesh_rows()) - 1
    return [
        ScenePart(
            f"road rows {first}..{min(first + ROAD_ROWS_PER_PART, last)}",
            _RoadStretch(road, (first, min(first + ROAD_ROWS_PER_PART, last))),
        )
        for first in range(0, max(last, 1), ROAD_ROWS_PER_PART)
    ]


def guardrail_parts(items: list, road: Road, seed: int, first_id: int) -> list[ScenePart]:
    """One part per guardrail run of the spec's ``guardrails`` (checked here), with object ids
    from ``first_id`` on."""
    parts = []
    for i, item in enumerate(items):
        where = f"guardrails[{i}]"
        if not isinstance(item, dict):
            raise SceneSpecError(f"{where}: expected a mapping")
        design = load_design(spec_value(item, "design", str, where))
        height_scale = spec_value(item, "height_scale", float, where, 1.0)
        try:
            design = scaled_height(design, height_scale)
        except SceneSpecError as exc:
            raise SceneSpecError(f"{where}.{exc}") from None
        run = _GuardrailRun(
            road=road,
            seed=seed,
            object_id=first_id + i,
            item=item,
            where=where,
            design=design,
            height_scale=height_scale,
            side=spec_side(item, where),
            offset=spec_value(item, "offset", float, where, 0.35),
            start=spec_value(item, "start", float, where),
            length=spec_value(item, "length", float, where),
            spacing=spec_value(item, "pole_spacing", float, where, design.unit_length),
            facing=spec_value(item, "facing", str, where, "road"),
        )
        if run.facing not in FACINGS:
            raise SceneSpecError(
                f"{where}.facing: {run.facing!r}; expected one of {', '.join(FACINGS)}"
            )
        if run.spacing <= 0.3 or run.length < run.spacing:
            raise SceneSpecError(
                f"{where}: length {run.length} m must hold at least one pole spacing "
                f"{run.spacing} m"
            )
        if run.start < 0 or run.start + run.length > road.length:
            raise SceneSpecError(
                f"{where}: {run.start}..{run.start + run.length} m runs off the road "
                f"(0..{road.length:.1f} m)"
            )
        spec_paint(item, where, part_rng(seed, run.object_id))  # an unknown paint fails now
        if "damage" in item:
            units = int(np.floor(run.length / run.spacing + 1e-9))
            damage = parse_damage(item["damage"], where, design, units, run.spacing)
            run = replace(run, damage=damage)
        parts.append(ScenePart(where, run))
    return parts


def object_parts(items: list, road: Road, seed: int, first_id: int) -> list[ScenePart]:
    """One part per street object of the spec's ``objects`` (an item ``at`` several positions
    gives one per position), checked here, with object ids from ``first_id`` on."""
    parts: list[ScenePart] = []
    for i, item in enumerate(items):
        where = f"objects[{i}]"
        if not isinstance(item, dict):
            raise SceneSpecError(f"{where}: expected a mapping")
        kind = spec_value(item, "kind", str, where)
        if kind not in CONFOUNDER_KINDS and kind not in VEGETATION_KINDS:
            raise SceneSpecError(
                f"{where}.kind: unknown kind {kind!r} "
                f"(known: {', '.join(CONFOUNDER_KINDS + VEGETATION_KINDS)})"
            )
        side = spec_side(item, where)
        offset = spec_value(item, "offset", float, where, 1.0)
        if kind in VEGETATION_KINDS:
            _check_vegetation(item, kind, where)
        at = item.get("at")
        positions = at if isinstance(at, list) else [at]
        for j, s in enumerate(positions):
            if isinstance(s, bool) or not isinstance(s, int | float) or not 0 <= s <= road.length:
                raise SceneSpecError(
                    f"{where}.at: {s!r} is not a position on the road (0..{road.length:.1f} m)"
                )
            if kind in EXTENDED_VEGETATION and road.length - s <= 0.1:
                raise SceneSpecError(
                    f"{where}.at: a {kind} at {s} m has no road left to grow along "
                    f"(the road ends at {road.length:.1f} m)"
                )
            make = _Vegetation if kind in VEGETATION_KINDS else _StreetObject
            thing = make(
                road=road,
                seed=seed,
                object_id=first_id + len(parts),
                item=item,
                where=where,
                kind=kind,
                side=side,
                offset=offset,
                at=float(s),
                index=j,
            )
            spec_paint(item, where, part_rng(seed, thing.object_id))  # an unknown paint fails now
            parts.append(ScenePart(f"{where}[{j}]", thing))
    return parts


def _check_vegetation(item: dict, kind: str, where: str) -> None:
    """A vegetation item's sizes (positive metres) and, for a hedge or grass, its length."""
    for key in SIZES[kind]:
        if key in item and not 0.05 <= spec_value(item, key, float, where) <= 10:
            raise SceneSpecError(f"{where}.{key}: {item[key]} m is not a size in 0.05..10 m")
    if kind in EXTENDED_VEGETATION and not spec_value(item, "length", float, where) > 0.1:
        raise SceneSpecError(f"{where}.length: {kind} needs a length over 0.1 m")


@dataclass(frozen=True)
class _RoadStretch:
    """The road's mesh rows ``rows`` (first, last), inclusive."""

    road: Road
    rows: tuple[int, int]

    def __call__(self, builder: MeshBuilder) -> None:
        self.road.build_mesh(builder, rows=self.rows)


@dataclass(frozen=True)
class _GuardrailRun:
    """A guardrail run of the spec (``item`` at ``where``), read and checked."""

    road: Road
    seed: int
    object_id: int
    item: dict
    where: str
    design: Design  # already scaled by height_scale
    height_scale: float
    side: str
    offset: float
    start: float
    length: float
    spacing: float
    facing: str = "road"
    damage: tuple[Damage, ...] = ()

    def __call__(self, builder: MeshBuilder) -> dict:
        paint = spec_paint(self.item, self.where, part_rng(self.seed, self.object_id))
        poles, toward_road = _poles_along(
            self.road, self.side, self.offset, self.start, self.length, self.spacing
        )
        if self.facing == "away":  # a median's far rail: its beams face the other carriageway
            toward_road = -toward_road
        if self.damage and len(poles) != int(np.floor(self.length / self.spacing + 1e-9)) + 1:
            raise SceneSpecError(  # the road ended before the run's length: indices would shift
                f"{self.where}.damage: the run has {len(poles) - 1} units on the road, not the "
                f"{self.length / self.spacing:.0f} its length holds"
            )
        record = build_guardrail_run(
            self.design,
            poles,
            toward_road,
            paint=paint,
            object_id=self.object_id,
            builder=builder,
            damage=self.damage,
        )
        record.update(
            {
                "side": self.side,
                "offset": self.offset,
                "start": self.start,
                "pole_spacing": self.spacing,
            }
        )
        if self.facing != "road":
            record["facing"] = self.facing
        if self.height_scale != 1.0:  # only then: a drive of unscaled designs keeps its truth
            record["height_scale"] = self.height_scale
        return record


@dataclass(frozen=True)
class _StreetObject:
    """One street object of the spec (position ``index`` of ``item`` at ``where``), checked."""

    road: Road
    seed: int
    object_id: int
    item: dict
    where: str
    kind: str
    side: str
    offset: float
    at: float
    index: int

    def __call__(self, builder: MeshBuilder) -> dict:
        rng = part_rng(self.seed, self.object_id)
        paint = spec_paint(self.item, self.where, rng)
        road = self.road
        lateral = road.lateral_of(self.side, self.offset)
        base = road.point(np.array([self.at]), np.array([lateral]))[0]
        _, tangent, left = road.frame(np.array([self.at]))
        record = build_confounder(
            self.kind,
            base=base,
            along=tangent[0],
            toward_road=-SIDES[self.side] * left[0],
            length=float(self.item.get("length", 0.0)),
            paint=paint,
            object_id=self.object_id,
            builder=builder,
            rng=rng,
        )
        record.update(
            {"side": self.side, "offset": self.offset, "at": self.at, "index": self.index}
        )
        return record


@dataclass(frozen=True)
class _Vegetation(_StreetObject):
    """A hedge, shrub or patch of tall grass of the spec: laid on the ground, not a rigid object."""

    def __call__(self, builder: MeshBuilder) -> dict:
        rng = part_rng(self.seed, self.object_id)
        record = build_vegetation(
            self.kind,
            road=self.road,
            side=self.side,
            offset=self.offset,
            at=self.at,
            length=float(self.item.get("length", 0.0)),
            sizes=vegetation_sizes(self.kind, self.item, rng),
            object_id=self.object_id,
            builder=builder,
            rng=rng,
        )
        record.update(
            {"side": self.side, "offset": self.offset, "at": self.at, "index": self.index}
        )
        return record


def _poles_along(
    road: Road, side: str, offset: float, start: float, length: float, spacing: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pole ground points (P, 3) every ``spacing`` metres along the offset line, and toward-road units."""
    lateral = road.lateral_of(side, offset)
    s = np.arange(start, min(start + length * 1.3 + 1.0, road.length), 0.02)
    line = road.point(s, np.full_like(s, lateral))
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(line[:, :2], axis=0), axis=1))])
    n_units = int(np.floor(min(length, arc[-1]) / spacing + 1e-9))
    at = np.arange(n_units + 1) * spacing
    s_poles = np.interp(at, arc, s)
    poles = road.point(s_poles, np.full_like(s_poles, lateral))
    _, _, left = road.frame(s_poles)
    return poles, -SIDES[side] * left
