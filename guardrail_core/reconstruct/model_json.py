"""Run models to and from plain JSON (``reconstruction/models.json`` of a run folder).

Everything a reader needs to redraw, measure or evaluate a reconstruction without re-running it:
poles, unit frames, the unit model's pipes or beam section, registration flags and notes.
Coordinates are the drive's local frame (metres); add ``drive.json``'s origin for map coordinates.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from guardrail_core.errors import RunFolderError
from guardrail_core.reconstruct.model import Pipe, Pole, RunModel, UnitModel
from guardrail_core.reconstruct.unit_frame import UnitFrame


def run_model_to_json(run: RunModel) -> dict[str, Any]:
    """A :class:`RunModel` as a JSON-ready dict (floats rounded to 0.1 mm)."""
    model = run.model
    return {
        "run_id": run.run_id,
        "n_points": run.n_points,
        "notes": list(run.notes),
        "poles": [
            {
                "position": _r(p.position),
                "radius": _r(p.radius),
                "height": _r(p.height),
                "n_points": p.n_points,
            }
            for p in run.poles
        ],
        "units": [
            {
                "origin": _r(f.origin),
                "along": [round(float(v), 9) for v in f.along],
                "length": _r(f.length),
                "slope": round(float(f.slope), 9),
            }
            for f in run.units
        ],
        "registered": [bool(v) for v in np.asarray(run.registered, bool)],
        "model": None
        if model is None
        else {
            "type": model.type,
            "length": _r(model.length),
            "pole_radius": _r(model.pole_radius),
            "pole_height": _r(model.pole_height),
            "n_units": model.n_units,
            "notes": list(model.notes),
            "pipes": [
                {"kind": p.kind, "radius": _r(p.radius), "n_points": p.n_points, "axis": _r(p.axis)}
                for p in model.pipes
            ],
            "section": None if model.section is None else _r(model.section),
        },
    }


def run_model_from_json(data: dict[str, Any], *, where: str = "models.json") -> RunModel:
    """Inverse of :func:`run_model_to_json`.

    Raises
    ------
    RunFolderError
        A key is missing or a value has the wrong shape.
    """
    try:
        poles = [
            Pole(np.asarray(p["position"], np.float64), p["radius"], p["height"], p["n_points"])
            for p in data["poles"]
        ]
        units = [
            UnitFrame(
                np.asarray(u["origin"], np.float64),
                np.asarray(u["along"], np.float64),
                float(u["length"]),
                float(u["slope"]),
            )
            for u in data["units"]
        ]
        m = data["model"]
        model = None
        if m is not None:
            model = UnitModel(
                type=m["type"],
                length=float(m["length"]),
                pipes=tuple(
                    Pipe(
                        np.asarray(p["axis"], np.float64).reshape(-1, 3),
                        float(p["radius"]),
                        p["kind"],
                        int(p["n_points"]),
                    )
                    for p in m["pipes"]
                ),
                section=None
                if m["section"] is None
                else np.asarray(m["section"], np.float64).reshape(-1, 2),
                pole_radius=float(m["pole_radius"]),
                pole_height=float(m["pole_height"]),
                n_units=int(m["n_units"]),
                notes=tuple(m["notes"]),
            )
        return RunModel(
            run_id=int(data["run_id"]),
            poles=poles,
            units=units,
            model=model,
            registered=np.asarray(data["registered"], bool),
            n_points=int(data["n_points"]),
            notes=list(data["notes"]),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise RunFolderError(f"{where}: not a reconstructed run ({exc!r})") from exc


def _r(value: Any) -> Any:
    """Round metres to 0.1 mm for JSON (float, or nested lists from an array)."""
    if isinstance(value, np.ndarray):
        return np.round(value.astype(np.float64), 4).tolist()
    return round(float(value), 4)
