"""Build a guardrail run (poles + unit shapes) from a :class:`Design` into a scene mesh.

Matsumoto et al. 2019, §4.1: a guardrail is basic units assembled between poles. Pipe units
(§4.3) are copied between every pair of consecutive poles, scaled to the actual pole spacing;
beams (§4.4) are one section curve swept along the whole run. The truth record returned is
exactly what the mesh was built from, so reconstruction can be scored against it.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.classes import TruthClass
from guardrail_core.geom.mesh import cylinder, dome, grid_surface, sweep, thick_outline, tube
from guardrail_core.synth.damage import (
    Damage,
    damage_record,
    lean_rotation,
    push_knots,
    push_spans,
    rail_push,
)
from guardrail_core.synth.designs import Design
from guardrail_core.synth.materials import PAINTS
from guardrail_core.synth.mesh import MeshBuilder

#: Circle segments of pipe tubes and of posts.
PIPE_SECTIONS = 12
POLE_SECTIONS = 16
_Z = np.array([0.0, 0.0, 1.0])


def _validate_run(poles: np.ndarray, toward_road: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    poles = np.asarray(poles, dtype=np.float64)
    toward = np.asarray(toward_road, dtype=np.float64)
    if poles.ndim != 2 or poles.shape[1] != 3 or len(poles) < 2:
        raise ValueError(f"poles must be (P, 3) with P >= 2, got shape {poles.shape}")
    if toward.shape != poles.shape:
        raise ValueError(
            f"toward_road must have the poles' shape {poles.shape}, got {toward.shape}"
        )
    if not (np.isfinite(poles).all() and np.isfinite(toward).all()):
        raise ValueError("poles and toward_road must be finite")
    chord = np.linalg.norm(np.diff(poles[:, :2], axis=0), axis=1)
    if (chord < 1e-3).any():
        raise ValueError(
            f"consecutive poles {int(np.argmin(chord))} and {int(np.argmin(chord)) + 1} are less "
            "than 1 mm apart horizontally"
        )
    horiz = toward.copy()
    horiz[:, 2] = 0.0
    norm = np.linalg.norm(horiz, axis=1, keepdims=True)
    if (norm < 1e-6).any():
        raise ValueError("toward_road must have a horizontal component at every pole")
    return poles, horiz / norm


def _pipe_axis(
    points: np.ndarray, p0: np.ndarray, p1: np.ndarray, unit_length: float
) -> np.ndarray:
    """World axis (K, 3) of a unit-coordinate pipe (K, 2) between ground points ``p0``, ``p1``.

    x is scaled by horizontal chord / unit_length; the ground under the pipe is interpolated
    linearly between the poles (rails follow a slope), y is added straight up.
    """
    f = points[:, 0:1] / unit_length
    return p0 + f * (p1 - p0) + points[:, 1:2] * _Z


def build_guardrail_run(
    design: Design,
    poles: np.ndarray,
    toward_road: np.ndarray,
    *,
    paint: str,
    object_id: int,
    builder: MeshBuilder,
    damage: tuple[Damage, ...] = (),
) -> dict:
    """Add one guardrail run to ``builder`` and return its truth record.

    Parameters
    ----------
    design : Design
    poles : (P, 3) float64, metres
        Ground points of the pole axes in order along the run, P >= 2.
    toward_road : (P, 3) float64
        Horizontal directions from the run toward the road at each pole (normalised here).
        Beams are offset and bulge toward this side; pipes lie in the plane of the pole axes.
    paint : str
        A key of :data:`~guardrail_core.synth.materials.PAINTS`; used on every face.
    object_id : int
        Written on every face and as the record's ``id``.
    builder : MeshBuilder
    damage : tuple of :class:`~guardrail_core.synth.damage.Damage`, checked against this run
        (indices of the undamaged run). The mesh is built damaged; see :func:`_damaged`.

    Returns
    -------
    dict
        Plain-JSON truth record: ``id, kind='guardrail', design, type, paint, poles, units,
        pipes, beams, length``. Pipe ``axis`` and beam ``section``/``path``/``across`` are exactly
        the geometry the mesh was swept from. ``units[i].length`` is the 3-D distance between
        the ground points; ``length`` is their sum. A damaged run's record also has ``damage``
        (:func:`~guardrail_core.synth.damage.damage_record` per item); its poles and pipes are
        those built (a missing post or pipe is absent, poles then carry their ``index``; a
        leaning post has its ``axis``, a unit vector from its foot).
    """
    if paint not in PAINTS:
        raise ValueError(f"unknown paint {paint!r}; expected one of {sorted(PAINTS)}")
    poles, across = _validate_run(poles, toward_road)
    oid = int(object_id)
    pole_spec = design.pole

    if damage:
        return _damaged(design, poles, across, paint, oid, builder, tuple(damage))

    pole_records = []
    for p in poles:
        _add_pole(builder, design, p, None, paint, oid)
        pole_records.append(
            {
                "position": p.tolist(),
                "radius": float(pole_spec.radius),
                "height": float(pole_spec.height),
            }
        )

    unit_records, pipe_records = [], []
    for i in range(len(poles) - 1):
        p0, p1 = poles[i], poles[i + 1]
        unit_records.append(
            {
                "index": i,
                "start_pole": i,
                "end_pole": i + 1,
                "start": p0.tolist(),
                "end": p1.tolist(),
                "length": float(np.linalg.norm(p1 - p0)),
            }
        )
        for pipe in design.pipes:
            axis = _pipe_axis(pipe.points, p0, p1, design.unit_length)
            builder.add(
                tube(axis, pipe.radius, sections=PIPE_SECTIONS, caps=True),
                cls=TruthClass.GUARDRAIL,
                object_id=oid,
                material=paint,
            )
            pipe_records.append(
                {
                    "unit": i,
                    "kind": pipe.kind,
                    "axis": axis.tolist(),
                    "radius": float(pipe.radius),
                }
            )

    beam_records = []
    up = np.broadcast_to(_Z, poles.shape)
    for beam in design.beams:
        outline = thick_outline(beam.section, beam.thickness)
        builder.add(
            sweep(outline, poles, across, up),
            cls=TruthClass.GUARDRAIL,
            object_id=oid,
            material=paint,
        )
        beam_records.append(
            {
                "section": beam.section.tolist(),
                "path": poles.tolist(),
                "across": across.tolist(),
                "thickness": float(beam.thickness),
            }
        )

    return _truth_record(oid, design, paint, pole_records, unit_records, pipe_records, beam_records)


def _add_pole(
    builder: MeshBuilder,
    design: Design,
    foot: np.ndarray,
    rotation: np.ndarray | None,
    paint: str,
    oid: int,
) -> None:
    """A post (and its cap) standing on ``foot`` (3,); ``rotation`` (3, 3) tilts it about its foot."""
    spec = design.pole
    top = foot + spec.height * _Z
    meshes = [cylinder(foot, top, spec.radius, sections=POLE_SECTIONS)]
    if spec.cap:
        meshes.append(dome(top, spec.radius, sections=POLE_SECTIONS))
    for vertices, faces in meshes:
        if rotation is not None:
            vertices = foot + (vertices - foot) @ rotation.T
        builder.add((vertices, faces), cls=TruthClass.GUARDRAIL_POLE, object_id=oid, material=paint)


def _damaged(
    design: Design,
    poles: np.ndarray,
    across: np.ndarray,
    paint: str,
    oid: int,
    builder: MeshBuilder,
    damage: tuple[Damage, ...],
) -> dict:
    """:func:`build_guardrail_run` of a damaged run (``poles`` (P, 3), ``across`` (P, 3) toward
    the road, checked).

    A lowered run stands ``drop_m`` lower (its posts sunk, its rails lower above the ground); a
    missing end loses its end unit and end post; a missing post or pipe is not built; a leaning
    post is rotated about its foot; dents and a bent end push the rails away from the road
    (:func:`~guardrail_core.synth.damage.rail_push`), sampled densely where they bend; a bent
    pipe bows ``offset_m * sin(pi x / unit_length)`` across its unit.
    """
    spec = design.pole
    n = len(poles)
    poles = poles - sum(d.drop_m for d in damage if d.kind == "lowered") * _Z
    pole_s = np.concatenate(
        [[0.0], np.cumsum(np.linalg.norm(np.diff(poles[:, :2], axis=0), axis=1))]
    )
    along = np.gradient(poles, axis=0)
    kept_units = list(range(n - 1))
    kept_poles = list(range(n))
    for d in damage:
        if d.kind == "end_missing":
            kept_units.remove(n - 2 if d.end == "last" else 0)
            kept_poles.remove(n - 1 if d.end == "last" else 0)
        elif d.kind == "missing_post":
            kept_poles.remove(d.pole)
    leans = {d.pole: (d.lean_deg, d.direction) for d in damage if d.kind == "leaning_post"}
    for d in damage:
        if d.kind == "end_damaged":  # the end post goes over with its rails
            end = n - 1 if d.end == "last" else 0
            leans[end] = (float(np.rad2deg(np.arctan2(d.offset_m, spec.height))), "away")

    pole_records = []
    for i in kept_poles:
        rotation = None
        record: dict = {"position": poles[i].tolist()}
        if i in leans:
            rotation = lean_rotation(*leans[i], along=along[i], away=-across[i])
            record["axis"] = (rotation @ _Z).tolist()
        _add_pole(builder, design, poles[i], rotation, paint, oid)
        record.update({"radius": float(spec.radius), "height": float(spec.height)})
        if len(kept_poles) < n:
            record["index"] = i
        pole_records.append(record)

    pushed = tuple(d for d in damage if d.kind in ("dent", "end_damaged"))
    missing = {(d.unit, d.pipe) for d in damage if d.kind == "missing_pipe"}
    bent = {(d.unit, d.pipe): d for d in damage if d.kind == "bent_pipe"}
    spans = push_spans(pushed, pole_s)
    unit_records, pipe_records = [], []
    for i in kept_units:
        p0, p1 = poles[i], poles[i + 1]
        # Only a unit the rails bend in is sampled densely (a pipe's points: a few metres).
        pushed_here = any(lo < pole_s[i + 1] and hi > pole_s[i] for lo, hi in spans)
        unit_records.append(
            {
                "index": i,
                "start_pole": i,
                "end_pole": i + 1,
                "start": p0.tolist(),
                "end": p1.tolist(),
                "length": float(np.linalg.norm(p1 - p0)),
            }
        )
        for j, pipe in enumerate(design.pipes):
            if (i, j) in missing:
                continue
            points = pipe.points
            if pushed_here or (i, j) in bent:
                points = _resampled(points)
            axis = _pipe_axis(points, p0, p1, design.unit_length)
            if pushed_here or (i, j) in bent:
                f = points[:, 0] / design.unit_length
                away = -((1 - f)[:, None] * across[i] + f[:, None] * across[i + 1])
                away /= np.linalg.norm(away, axis=1, keepdims=True)
                push = rail_push(
                    pushed, pole_s[i] + f * (pole_s[i + 1] - pole_s[i]), points[:, 1], pole_s
                )
                if (i, j) in bent:
                    sign = 1.0 if bent[i, j].direction == "away" else -1.0
                    push = push + sign * bent[i, j].offset_m * np.sin(np.pi * np.clip(f, 0, 1))
                axis = axis + push[:, None] * away
            builder.add(
                tube(axis, pipe.radius, sections=PIPE_SECTIONS, caps=True),
                cls=TruthClass.GUARDRAIL,
                object_id=oid,
                material=paint,
            )
            pipe_records.append(
                {
                    "unit": i,
                    "pipe": j,
                    "kind": pipe.kind,
                    "axis": axis.tolist(),
                    "radius": float(pipe.radius),
                }
            )

    beam_records = []
    first, last = kept_units[0], kept_units[-1] + 1
    path, path_across = poles[first : last + 1], across[first : last + 1]
    for beam in design.beams:
        outline = thick_outline(beam.section, beam.thickness)
        if pushed:  # sampled densely where the rails bend, each sample pushed away from the road
            s = push_knots(pushed, pole_s[first : last + 1])
            at = np.stack([np.interp(s, pole_s, poles[:, k]) for k in range(3)], axis=1)
            toward = np.stack([np.interp(s, pole_s, across[:, k]) for k in range(3)], axis=1)
            toward /= np.linalg.norm(toward, axis=1, keepdims=True)
            push = rail_push(pushed, s[:, None], outline[None, :, 1], pole_s)
            grid = (
                at[:, None, :]
                + (outline[None, :, 0] - push)[:, :, None] * toward[:, None, :]
                + outline[None, :, 1:2] * _Z
            )
            mesh = grid_surface(grid)
        else:
            mesh = sweep(outline, path, path_across, np.broadcast_to(_Z, path.shape))
        builder.add(mesh, cls=TruthClass.GUARDRAIL, object_id=oid, material=paint)
        beam_records.append(
            {
                "section": beam.section.tolist(),
                "path": path.tolist(),
                "across": path_across.tolist(),
                "thickness": float(beam.thickness),
            }
        )

    record = _truth_record(
        oid, design, paint, pole_records, unit_records, pipe_records, beam_records
    )
    record["damage"] = [damage_record(d, poles=poles, pole_s=pole_s, design=design) for d in damage]
    return record


def _resampled(points: np.ndarray, step: float = 0.02) -> np.ndarray:
    """A unit-coordinate polyline (K, 2) with points at most ``step`` metres apart (each
    segment split evenly, so a straight rail keeps its midpoint)."""
    out = [points[:1]]
    for a, b in zip(points[:-1], points[1:], strict=True):
        k = 2 * max(1, int(np.ceil(np.linalg.norm(b - a) / step / 2)))
        out.append(a + np.linspace(0.0, 1.0, k + 1)[1:, None] * (b - a))
    return np.concatenate(out)


def _truth_record(
    oid: int,
    design: Design,
    paint: str,
    poles: list[dict],
    units: list[dict],
    pipes: list[dict],
    beams: list[dict],
) -> dict:
    """A guardrail run's entry of ``truth/objects.json`` (lengths in metres)."""
    return {
        "id": oid,
        "kind": "guardrail",
        "design": design.name,
        "type": design.type,
        "paint": paint,
        "poles": poles,
        "units": units,
        "pipes": pipes,
        "beams": beams,
        "length": float(sum(u["length"] for u in units)),
    }
