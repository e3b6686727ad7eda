"""Build a guardrail run (poles + unit shapes) from a :class:`Design` into a scene mesh.

Matsumoto et al. 2019, §4.1: a guardrail is basic units assembled between poles. Pipe units
(§4.3) are copied between every pair of consecutive poles, scaled to the actual pole spacing;
beams (§4.4) are one section curve swept along the whole run. The truth record returned is
exactly what the mesh was built from, so reconstruction can be scored against it.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.classes import TruthClass
from guardrail_core.geom.mesh import cylinder, dome, sweep, thick_outline, tube
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

    Returns
    -------
    dict
        Plain-JSON truth record: ``id, kind='guardrail', design, type, paint, poles, units,
        pipes, beams, length``. Pipe ``axis`` and beam ``section``/``path``/``across`` are exactly
        the geometry the mesh was swept from. ``units[i].length`` is the 3-D distance between
        the ground points; ``length`` is their sum.
    """
    if paint not in PAINTS:
        raise ValueError(f"unknown paint {paint!r}; expected one of {sorted(PAINTS)}")
    poles, across = _validate_run(poles, toward_road)
    oid = int(object_id)
    pole_spec = design.pole

    pole_records = []
    for p in poles:
        top = p + pole_spec.height * _Z
        builder.add(
            cylinder(p, top, pole_spec.radius, sections=POLE_SECTIONS),
            cls=TruthClass.GUARDRAIL_POLE,
            object_id=oid,
            material=paint,
        )
        if pole_spec.cap:
            builder.add(
                dome(top, pole_spec.radius, sections=POLE_SECTIONS),
                cls=TruthClass.GUARDRAIL_POLE,
                object_id=oid,
                material=paint,
            )
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

    return {
        "id": oid,
        "kind": "guardrail",
        "design": design.name,
        "type": design.type,
        "paint": paint,
        "poles": pole_records,
        "units": unit_records,
        "pipes": pipe_records,
        "beams": beam_records,
        "length": float(sum(u["length"] for u in unit_records)),
    }
