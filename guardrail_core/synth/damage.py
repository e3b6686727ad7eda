"""Damage to a guardrail run: dents, bent and missing pipes, missing and leaning posts, a rail
lowered by repaving, a missing or bent run end.

A run's ``damage`` (scene spec) is a list of items ``{kind: ..., ...}`` read here into
:class:`Damage` records; :mod:`.guardrail` builds the run with them and this module gives the
geometry they share: the horizontal displacement of the rails away from the road
(:func:`rail_push`), the lean of a post (:func:`lean_rotation`) and the truth record of an item
(:func:`damage_record`). Positions along a run are metres of horizontal chord from its first
pole; heights are metres above the ground at the poles.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from guardrail_core.errors import SceneSpecError
from guardrail_core.synth.designs import Design
from guardrail_core.synth.spec_values import spec_value

DAMAGE_KINDS = (
    "dent",
    "bent_pipe",
    "missing_pipe",
    "missing_post",
    "leaning_post",
    "lowered",
    "end_missing",
    "end_damaged",
)
#: Which way a leaning post's top goes: from the road, toward it, forward along the run, back.
LEAN_DIRECTIONS = ("away", "toward", "forward", "back")
#: Which way a bent pipe bows.
BEND_DIRECTIONS = ("away", "toward")
ENDS = ("last", "first")
#: Allowed magnitudes (min, max), metres or degrees; the lower bound is exclusive.
LIMITS = {
    "depth_m": (0.0, 0.3),
    "length_m": (0.05, 3.0),
    "offset_m": (0.0, 0.5),
    "lean_deg": (0.0, 45.0),
    "drop_m": (0.0, 0.5),
}
_Z = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Damage:
    """One damage item of a run, checked. Fields its kind does not use keep their defaults
    (:data:`FIELDS` names those it uses).

    Attributes
    ----------
    kind : one of :data:`DAMAGE_KINDS`
    unit, pipe, pole : int, indices in the undamaged run (units and poles from 0 at its start,
        pipes in the design's order)
    at_m : float, a dent's centre along the run (m)
    depth_m, length_m, height_m : a dent's depth at its centre, its length along the rail (also
        its height across the rail: a round dent) and its centre's height above ground (m)
    offset_m : a bent pipe's bow at mid-unit, or a bent end's push at the end pole (m)
    lean_deg : a leaning post's angle from the vertical (degrees)
    direction : a leaning post's or bent pipe's direction (:data:`LEAN_DIRECTIONS`)
    drop_m : how much lower the run stands (m)
    end : the run end of ``end_missing`` / ``end_damaged`` (:data:`ENDS`)
    """

    kind: str
    unit: int = -1
    pipe: int = -1
    pole: int = -1
    at_m: float = 0.0
    depth_m: float = 0.0
    length_m: float = 0.0
    height_m: float = 0.0
    offset_m: float = 0.0
    lean_deg: float = 0.0
    direction: str = ""
    drop_m: float = 0.0
    end: str = ""


#: The fields of :class:`Damage` each kind uses (and its truth record carries).
FIELDS = {
    "dent": ("unit", "at_m", "depth_m", "length_m", "height_m"),
    "bent_pipe": ("unit", "pipe", "offset_m", "direction"),
    "missing_pipe": ("unit", "pipe"),
    "missing_post": ("pole",),
    "leaning_post": ("pole", "lean_deg", "direction"),
    "lowered": ("drop_m",),
    "end_missing": ("end",),
    "end_damaged": ("end", "offset_m"),
}
#: The field that is an item's magnitude, and its unit.
MAGNITUDE = {
    "dent": ("depth_m", "m"),
    "bent_pipe": ("offset_m", "m"),
    "leaning_post": ("lean_deg", "deg"),
    "lowered": ("drop_m", "m"),
    "end_damaged": ("offset_m", "m"),
}


def default_dent_height(design: Design) -> float:
    """Where a dent is centred when the spec leaves it open: the first beam's middle, or a
    pipe design's top rail (m above ground)."""
    if design.beams:
        return float(design.beams[0].section[:, 1].mean())
    return float(max(p.points[:, 1].max() for p in design.pipes))


def _magnitude(item: dict, key: str, where: str) -> float:
    value = spec_value(item, key, float, where)
    lo, hi = LIMITS[key]
    if not lo < value <= hi:
        raise SceneSpecError(f"{where}.{key}: {value} must lie in ({lo:g}, {hi:g}]")
    return value


def _index(item: dict, key: str, where: str, count: int, what: str) -> int:
    value = spec_value(item, key, int, where)
    if isinstance(value, bool) or not 0 <= value < count:
        raise SceneSpecError(
            f"{where}.{key}: {value!r} is not a {what} of the run (0..{count - 1})"
        )
    return int(value)


def _choice(item: dict, key: str, where: str, options: tuple[str, ...]) -> str:
    value = spec_value(item, key, str, where, options[0])
    if value not in options:
        raise SceneSpecError(f"{where}.{key}: {value!r}; expected one of {', '.join(options)}")
    return value


def parse_damage(items: object, where: str, design: Design, units: int, spacing: float) -> tuple:
    """The run's ``damage`` list read and checked into :class:`Damage` records.

    ``units`` and ``spacing`` (m) are the run's; ``where`` is the run's place in the spec
    (``guardrails[2]``). Raises :class:`SceneSpecError` naming the item and field at fault.
    """
    if items is None:
        return ()
    if not isinstance(items, list):
        raise SceneSpecError(f"{where}.damage: expected a list of {{kind: ...}} items")
    out: list[Damage] = []
    for k, item in enumerate(items):
        w = f"{where}.damage[{k}]"
        if not isinstance(item, dict):
            raise SceneSpecError(f"{w}: expected a mapping with a kind")
        kind = spec_value(item, "kind", str, w)
        if kind not in DAMAGE_KINDS:
            raise SceneSpecError(
                f"{w}.kind: unknown kind {kind!r} (known: {', '.join(DAMAGE_KINDS)})"
            )
        if kind in ("bent_pipe", "missing_pipe") and not design.pipes:
            raise SceneSpecError(f"{w}.kind: {kind} needs a pipe design; {design.name} has none")
        if kind == "dent":
            out.append(_dent(item, w, design, units, spacing))
        elif kind in ("bent_pipe", "missing_pipe"):
            d = Damage(
                kind,
                unit=_index(item, "unit", w, units, "unit"),
                pipe=_index(item, "pipe", w, len(design.pipes), "pipe of a unit"),
            )
            if kind == "bent_pipe":
                d = replace(
                    d,
                    offset_m=_magnitude(item, "offset_m", w),
                    direction=_choice(item, "direction", w, BEND_DIRECTIONS),
                )
            out.append(d)
        elif kind == "missing_post":
            out.append(Damage(kind, pole=_index(item, "pole", w, units + 1, "pole")))
        elif kind == "leaning_post":
            out.append(
                Damage(
                    kind,
                    pole=_index(item, "pole", w, units + 1, "pole"),
                    lean_deg=_magnitude(item, "lean_deg", w),
                    direction=_choice(item, "direction", w, LEAN_DIRECTIONS),
                )
            )
        elif kind == "lowered":
            out.append(Damage(kind, drop_m=_magnitude(item, "drop_m", w)))
        else:
            if units < 2:
                raise SceneSpecError(f"{w}.kind: {kind} needs a run of two units or more")
            d = Damage(kind, end=_choice(item, "end", w, ENDS))
            if kind == "end_damaged":
                d = replace(d, offset_m=_magnitude(item, "offset_m", w))
            out.append(d)
    _check_together(out, where, units)
    return tuple(out)


def _dent(item: dict, w: str, design: Design, units: int, spacing: float) -> Damage:
    if ("unit" in item) == ("at_m" in item):
        raise SceneSpecError(f"{w}: a dent needs either unit or at_m (its centre along the run)")
    if "unit" in item:
        unit = _index(item, "unit", w, units, "unit")
        at = (unit + 0.5) * spacing
    else:
        at = spec_value(item, "at_m", float, w)
        if not 0 <= at <= units * spacing:
            raise SceneSpecError(f"{w}.at_m: {at} m is not on the run (0..{units * spacing:g} m)")
        unit = min(int(at // spacing), units - 1)
    height = spec_value(item, "height_m", float, w, default_dent_height(design))
    if not 0 < height <= design.pole.height + 0.5:
        raise SceneSpecError(f"{w}.height_m: {height} m is not a height on the rails")
    return Damage(
        "dent",
        unit=unit,
        at_m=float(at),
        depth_m=_magnitude(item, "depth_m", w),
        length_m=_magnitude(item, "length_m", w),
        height_m=float(height),
    )


def _check_together(items: list[Damage], where: str, units: int) -> None:
    """Items that contradict each other: one target damaged twice, a target gone with an end."""
    seen: set[tuple] = set()
    gone_units: set[int] = set()
    gone_poles: set[int] = set()
    for d in items:
        if d.kind in ("lowered", "end_missing", "end_damaged"):
            key: tuple = ("end",) if d.kind.startswith("end") else ("lowered",)
        elif d.pole >= 0:
            key = ("pole", d.pole)
        elif d.pipe >= 0:
            key = ("pipe", d.unit, d.pipe)
        else:
            continue
        if key in seen:
            raise SceneSpecError(f"{where}.damage: {d.kind} repeats a damage to the same {key[0]}")
        seen.add(key)
        if d.kind == "end_missing":
            gone_units.add(units - 1 if d.end == "last" else 0)
            gone_poles.add(units if d.end == "last" else 0)
    for d in items:
        if d.kind != "end_missing" and (d.unit in gone_units or d.pole in gone_poles):
            raise SceneSpecError(
                f"{where}.damage: {d.kind} at a unit or pole that end_missing removes"
            )


# ----------------------------------------------------------------------------- geometry


def rail_push(items: tuple, s: np.ndarray, z: np.ndarray, pole_s: np.ndarray) -> np.ndarray:
    """Horizontal displacement (m, away from the road) of rail points at ``s`` (N,) metres along
    the run and ``z`` (N,) metres above the ground, from its dents and a bent end.

    A dent is ``depth * cos^2(pi ds / L) * cos^2(pi dz / L)`` within ``L / 2`` of its centre
    (smooth, ``depth`` at the centre); a bent end pushes its unit's rails by
    ``offset * t^2``, ``t`` from 0 at the unit's inner pole to 1 at the end pole.
    ``pole_s`` (P,): the poles' positions along the run.
    """
    s = np.asarray(s, np.float64)
    z = np.asarray(z, np.float64)
    push = np.zeros(np.broadcast(s, z).shape)
    for d in items:
        if d.kind == "dent":
            ds = (s - d.at_m) / d.length_m
            dz = (z - d.height_m) / d.length_m
            inside = (np.abs(ds) < 0.5) & (np.abs(dz) < 0.5)
            push += np.where(
                inside, d.depth_m * np.cos(np.pi * ds) ** 2 * np.cos(np.pi * dz) ** 2, 0
            )
        elif d.kind == "end_damaged":
            a, b = (pole_s[-2], pole_s[-1]) if d.end == "last" else (pole_s[1], pole_s[0])
            t = np.clip((s - a) / (b - a), 0.0, None)
            push += np.where(t <= 1.0, d.offset_m * np.minimum(t, 1.0) ** 2, 0.0)
    return push


def push_spans(items: tuple, pole_s: np.ndarray) -> list[tuple[float, float]]:
    """The stretches (m along the run) where :func:`rail_push` moves the rails."""
    spans = []
    for d in items:
        if d.kind == "dent":
            spans.append((d.at_m - d.length_m / 2, d.at_m + d.length_m / 2))
        elif d.kind == "end_damaged":
            ends = (pole_s[-2], pole_s[-1]) if d.end == "last" else (pole_s[0], pole_s[1])
            spans.append((float(ends[0]), float(ends[1])))
    return spans


def push_knots(items: tuple, pole_s: np.ndarray, step: float = 0.02) -> np.ndarray:
    """Positions along the run (m) at which to sample rails that :func:`rail_push` bends: every
    ``step`` metres over each dent and bent end, with each dent's centre exactly."""
    knots: list = [np.asarray(pole_s, np.float64)]
    for d in items:
        if d.kind == "dent":
            lo, hi = d.at_m - d.length_m / 2, d.at_m + d.length_m / 2
            knots += [np.linspace(lo, hi, int(np.ceil((hi - lo) / step)) + 1), [d.at_m]]
        elif d.kind == "end_damaged":
            lo, hi = (pole_s[-2], pole_s[-1]) if d.end == "last" else (pole_s[0], pole_s[1])
            knots.append(np.linspace(lo, hi, int(np.ceil((hi - lo) / step)) + 1))
    out = np.unique(np.concatenate(knots))
    return out[(out >= pole_s[0]) & (out <= pole_s[-1])]


def lean_rotation(
    lean_deg: float, direction: str, along: np.ndarray, away: np.ndarray
) -> np.ndarray:
    """Rotation (3, 3) tilting the vertical by ``lean_deg`` toward ``direction``: ``along``
    (3,) is the run's direction at the post, ``away`` (3,) horizontal from the road."""
    toward = {"away": away, "toward": -away, "forward": along, "back": -along}[direction]
    toward = toward - toward[2] * _Z
    toward = toward / np.linalg.norm(toward)
    k = np.cross(_Z, toward)  # the tilt axis
    angle = np.deg2rad(lean_deg)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def damage_record(d: Damage, *, poles: np.ndarray, pole_s: np.ndarray, design: Design) -> dict:
    """The truth record of ``d``: kind, where (unit/pole index, ``at_m`` along the run,
    ``position`` (3,) local metres) and ``magnitude`` with its ``magnitude_unit`` (m or deg),
    plus the item's own fields. ``poles`` (P, 3) and ``pole_s`` (P,) are the undamaged run's
    (lowered if it is)."""
    record: dict = {"kind": d.kind}
    if d.kind == "dent":
        at, height = d.at_m, d.height_m
    elif d.pole >= 0:
        at, height = float(pole_s[d.pole]), 0.0
    elif d.kind in ("end_missing", "end_damaged"):
        at, height = float(pole_s[-1] if d.end == "last" else pole_s[0]), 0.0
    elif d.unit >= 0:
        at = float((pole_s[d.unit] + pole_s[d.unit + 1]) / 2)
        height = float(design.pipes[d.pipe].points[:, 1].mean())
    else:  # lowered: the whole run, located at its middle
        at, height = float(pole_s[-1] / 2), 0.0
    base = np.array([np.interp(at, pole_s, poles[:, i]) for i in range(3)])
    record["at_m"] = round(float(at), 6)
    record["position"] = (base + height * _Z).tolist()
    for key in FIELDS[d.kind]:
        record[key] = getattr(d, key)
    if d.kind in MAGNITUDE:
        key, unit = MAGNITUDE[d.kind]
        record["magnitude"] = float(getattr(d, key))
        record["magnitude_unit"] = unit
    return record
