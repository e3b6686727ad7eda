"""The guardrail inventory: one row per run, as GeoJSON and CSV (Matsumoto et al. 2019, §4).

A row says what was reconstructed (status, pipe or beam, the design's signature), how long and
high the run is, where its poles stand (count, spacing) and where it starts and ends in map
coordinates (local + the drive's origin, float64). Lengths and spacings are 3-D distances between
consecutive poles' ground points (along the ground); heights are above the ground line.

The GeoJSON has one LineString per run through its poles' ground points (a Point for a run of
one pole, a null geometry for none) in the drive's CRS, not WGS84: RFC 7946 has no CRS member, so
the CRS is named in the old-style (GeoJSON 2008) top-level member
``"crs": {"type": "name", "properties": {"name": <the drive's CRS>}}``, which QGIS and GDAL read.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.errors import InvalidOptionError, ReconstructionError
from guardrail_core.formats.atomic import atomic_write
from guardrail_core.params import StageParams, param
from guardrail_core.reconstruct.model import RunModel, UnitModel

STATUSES = ("reconstructed", "poles only", "not reconstructed")
#: The keys of a row, in the CSV's column order.
ROW_KEYS = (
    "run_id", "status", "type", "signature", "design", "length_m", "height_m", "rail_top_m",
    "pole_count", "poles_seen", "pole_radius_m", "pole_spacing_m", "pole_spacing_min_m", "pole_spacing_max_m",
    "start_x", "start_y", "start_z", "end_x", "end_y", "end_z",
    "units", "units_registered", "units_superimposed", "n_points", "notes",
)  # fmt: skip


@dataclass(frozen=True)
class InventoryParams(StageParams):
    """How runs are summarised."""

    flat_pipe_m: float = param(
        0.05,
        unit="m",
        ge=0,
        le=1.0,
        doc="A pipe whose axis height varies less than this is written with one height in the "
        "signature, else with its range.",
    )


def _origin(origin: np.ndarray) -> np.ndarray:
    o = np.asarray(origin, np.float64)
    if o.shape != (3,) or not np.isfinite(o).all():
        raise InvalidOptionError(f"origin must be 3 finite map coordinates, got {o!r}")
    return o


def _round(value: float, digits: int) -> float:
    return float(round(float(value), digits))


def pipe_signature(
    model: UnitModel, params: InventoryParams = InventoryParams()
) -> tuple[str, list[dict]]:
    """Compact text and structured list of a pipe model's pipes, top to bottom.

    Text: ``"3 pipes: horizontal r24.3 y0.95, vertical r17 y0.10-0.90, ..."`` (radius in mm,
    height y in m: one value for a pipe level within ``params.flat_pipe_m``, else its
    range). List: ``{kind, radius_mm, y_min_m, y_max_m, x_min_m, x_max_m, n_points}`` per pipe.
    """
    items: list[dict[str, Any]] = []
    for pipe in model.pipes:
        axis = np.asarray(pipe.axis, np.float64)
        items.append(
            {
                "kind": pipe.kind,
                "radius_mm": _round(pipe.radius * 1000, 1),
                "y_min_m": _round(axis[:, 1].min(), 3),
                "y_max_m": _round(axis[:, 1].max(), 3),
                "x_min_m": _round(axis[:, 0].min(), 3),
                "x_max_m": _round(axis[:, 0].max(), 3),
                "n_points": int(pipe.n_points),
            }
        )
    items.sort(key=lambda p: (-p["y_max_m"], p["x_min_m"]))
    texts = []
    for p in items:
        if p["y_max_m"] - p["y_min_m"] < params.flat_pipe_m:
            y = f"y{(p['y_min_m'] + p['y_max_m']) / 2:.2f}"
        else:
            y = f"y{p['y_min_m']:.2f}-{p['y_max_m']:.2f}"
        texts.append(f"{p['kind']} r{p['radius_mm']:g} {y}")
    head = f"{len(items)} pipe{'s' if len(items) != 1 else ''}"
    return (f"{head}: " + ", ".join(texts)) if texts else head, items


def beam_signature(model: UnitModel) -> tuple[str, dict]:
    """Compact text and structured summary of a beam section (z, y) metres.

    Returns ``"beam h0.35 d0.05 y0.35-0.70"`` and ``{height_m, depth_m, y_min_m, y_max_m,
    section}`` where height is the section's y extent, depth its z extent (toward the road) and
    ``section`` the points [[z, y], ...] in metres.
    """
    if model.section is None or len(model.section) == 0:
        return "beam (no section)", {"section": []}
    sec = np.asarray(model.section, np.float64)
    y0, y1 = sec[:, 1].min(), sec[:, 1].max()
    info = {
        "height_m": _round(y1 - y0, 3),
        "depth_m": _round(np.ptp(sec[:, 0]), 3),
        "y_min_m": _round(y0, 3),
        "y_max_m": _round(y1, 3),
        "section": [[_round(z, 4), _round(y, 4)] for z, y in sec],
    }
    text = f"beam h{info['height_m']:.2f} d{info['depth_m']:.3f} y{y0:.2f}-{y1:.2f}"
    return text, info


def _model_top(model: UnitModel) -> float:
    """Highest point of the rails above the ground line, metres (0 without geometry)."""
    tops = [np.asarray(p.axis)[:, 1].max() + p.radius for p in model.pipes]
    if model.section is not None and len(model.section):
        tops.append(np.asarray(model.section)[:, 1].max())
    return float(max(tops, default=0.0))


def inventory_rows(
    runs: Sequence[RunModel], origin: np.ndarray, params: InventoryParams = InventoryParams()
) -> list[dict]:
    """One plain-JSON row per run.

    Parameters
    ----------
    runs : RunModel per run
    origin : (3,) float64, map coordinates of the local frame (``drive.json``)
    params : InventoryParams

    Returns
    -------
    list of dict
        Keys (:data:`ROW_KEYS`): ``run_id``; ``status`` ("reconstructed": a unit model with pipes or a beam section;
        "poles only": poles but no such model; "not reconstructed": neither); ``type`` ("pipe" | "beam" | "unknown");
        ``signature`` (text, see :func:`pipe_signature` / :func:`beam_signature`) and
        ``design`` (structured: a list of pipes, or the beam's section summary; None);
        ``length_m`` (sum of distances between consecutive poles); ``height_m`` (the highest of
        the median pole height and the rails' top); ``rail_top_m``; ``pole_count``;
        ``poles_seen`` (poles with points; the others were placed where one was missing);
        ``pole_radius_m`` (median); ``pole_spacing_m`` (median) with ``pole_spacing_min_m`` and
        ``pole_spacing_max_m``; ``start_x, start_y, start_z, end_x, end_y, end_z`` (first and last
        pole's ground point, map coordinates, float64); ``units``; ``units_registered``;
        ``units_superimposed``; ``n_points``; ``notes`` (the run's and the model's, "; "-joined).
        Values missing for a run (no poles, no model) are None.

    References
    ----------
    Matsumoto et al. 2019, §4.1 (poles and units), §4.3-4.4 (pipe and beam models).
    """
    o = _origin(origin)
    rows = []
    for run in runs:
        positions = np.array([np.asarray(p.position, np.float64) for p in run.poles]).reshape(-1, 3)
        if not np.isfinite(positions).all():
            raise ReconstructionError(f"run {run.run_id}: pole positions must be finite")
        spacing = np.linalg.norm(np.diff(positions, axis=0), axis=1)
        model = run.model
        if model is not None and (model.pipes or model.section is not None):
            status = "reconstructed"
        elif len(run.poles):
            status = "poles only"
        else:
            status = "not reconstructed"
        signature: str | None = None
        design: list[dict] | dict | None = None
        if model is not None and model.type == "pipe":
            signature, design = pipe_signature(model, params)
        elif model is not None and model.type == "beam":
            signature, design = beam_signature(model)
        pole_height = float(np.median([p.height for p in run.poles])) if run.poles else None
        rail_top = _model_top(model) if model is not None else None
        heights = [h for h in (pole_height, rail_top) if h is not None]
        start = positions[0] + o if len(positions) else [None] * 3
        end = positions[-1] + o if len(positions) else [None] * 3
        notes = list(run.notes) + (list(model.notes) if model is not None else [])
        rows.append(
            {
                "run_id": int(run.run_id),
                "status": status,
                "type": model.type if model is not None else "unknown",
                "signature": signature,
                "design": design,
                "length_m": _round(spacing.sum(), 3) if len(positions) else None,
                "height_m": _round(max(heights), 3) if heights else None,
                "rail_top_m": _round(rail_top, 3) if rail_top is not None else None,
                "pole_count": len(run.poles),
                "poles_seen": sum(1 for p in run.poles if p.n_points > 0),
                "pole_radius_m": (
                    _round(np.median([p.radius for p in run.poles]), 4) if run.poles else None
                ),
                "pole_spacing_m": _round(np.median(spacing), 3) if len(spacing) else None,
                "pole_spacing_min_m": _round(spacing.min(), 3) if len(spacing) else None,
                "pole_spacing_max_m": _round(spacing.max(), 3) if len(spacing) else None,
                **{f"start_{a}": _float(v) for a, v in zip("xyz", start, strict=True)},
                **{f"end_{a}": _float(v) for a, v in zip("xyz", end, strict=True)},
                "units": len(run.units),
                "units_registered": int(np.count_nonzero(np.asarray(run.registered, bool))),
                "units_superimposed": int(model.n_units) if model is not None else 0,
                "n_points": int(run.n_points),
                "notes": "; ".join(notes),
            }
        )
    return rows


def _float(value) -> float | None:
    return None if value is None else float(value)


def inventory_geojson(
    rows: Sequence[dict], runs: Sequence[RunModel], origin: np.ndarray, crs: str
) -> dict:
    """The inventory as a GeoJSON FeatureCollection (a dict); see the module docstring.

    Feature ``i`` has ``rows[i]`` as properties and the geometry of ``runs[i]``'s poles' ground
    points + ``origin``, map coordinates in ``crs`` (float64, written at full precision).
    """
    o = _origin(origin)
    if not isinstance(crs, str) or not crs:
        raise InvalidOptionError(f"crs must be a non-empty string, got {crs!r}")
    if len(rows) != len(runs):
        raise InvalidOptionError(f"{len(rows)} rows for {len(runs)} runs")
    features = []
    for row, run in zip(rows, runs, strict=True):
        if row.get("run_id") != run.run_id:
            raise InvalidOptionError(
                f"row of run {row.get('run_id')} paired with run {run.run_id}; keep their order"
            )
        pts = np.array([np.asarray(p.position, np.float64) for p in run.poles]).reshape(-1, 3) + o
        coords = pts.tolist()
        if len(coords) >= 2:
            geometry = {"type": "LineString", "coordinates": coords}
        elif len(coords) == 1:
            geometry = {"type": "Point", "coordinates": coords[0]}
        else:
            geometry = None
        features.append(
            {"type": "Feature", "id": int(run.run_id), "geometry": geometry, "properties": row}
        )
    return {
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": crs}},
        "features": features,
    }


def write_inventory_geojson(
    path: Path, rows: Sequence[dict], runs: Sequence[RunModel], origin: np.ndarray, crs: str
) -> None:
    """Write :func:`inventory_geojson` to ``path``, whole or not at all (:func:`atomic_write`)."""
    text = json.dumps(inventory_geojson(rows, runs, origin, crs), indent=1, allow_nan=False)
    atomic_write(path, text + "\n", overwrite=True)


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, list | dict):
        return json.dumps(value, separators=(",", ":"))
    return str(value)  # str(float) is repr: full float64 precision for map coordinates


def write_inventory_csv(path: Path, rows: Sequence[dict]) -> None:
    """Write the rows as CSV: a header (:data:`ROW_KEYS`, then any other keys), a line per row.

    Lists and dicts (``design``) are written as compact JSON, None as an empty cell.
    """
    keys = list(ROW_KEYS)
    for row in rows:
        keys += [k for k in row if k not in keys]
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(keys)
    for row in rows:
        writer.writerow([_cell(row.get(k)) for k in keys])
    atomic_write(path, buffer.getvalue(), overwrite=True)
