"""The guardrail inventory: one row per run, as GeoJSON and CSV (Matsumoto et al. 2019, §4).

A row (:class:`~guardrail_core.reconstruct.inventory_row.InventoryRow`, where each field's unit
is given) says what was reconstructed (status, pipe or beam, the design's signature), how long and
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

from guardrail_core.errors import InvalidOptionError, ReconstructionError, RunFolderError
from guardrail_core.formats.atomic import atomic_write
from guardrail_core.params import StageParams, param
from guardrail_core.reconstruct.inventory_row import ROW_KEYS, InventoryRow
from guardrail_core.reconstruct.model import RunModel, UnitModel


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
) -> list[InventoryRow]:
    """One :class:`InventoryRow` per run, in the order of ``runs``.

    Parameters
    ----------
    runs : RunModel per run
    origin : (3,) float64, map coordinates of the local frame (``drive.json``)
    params : InventoryParams

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
        start = [float(v) for v in positions[0] + o] if len(positions) else [None] * 3
        end = [float(v) for v in positions[-1] + o] if len(positions) else [None] * 3
        notes = list(run.notes) + (list(model.notes) if model is not None else [])
        rows.append(
            InventoryRow(
                run_id=int(run.run_id),
                status=status,
                type=model.type if model is not None else "unknown",
                signature=signature,
                design=design,
                length_m=_round(spacing.sum(), 3) if len(positions) else None,
                height_m=_round(max(heights), 3) if heights else None,
                rail_top_m=_round(rail_top, 3) if rail_top is not None else None,
                pole_count=len(run.poles),
                poles_seen=sum(1 for p in run.poles if p.n_points > 0),
                pole_radius_m=(
                    _round(np.median([p.radius for p in run.poles]), 4) if run.poles else None
                ),
                pole_spacing_m=_round(np.median(spacing), 3) if len(spacing) else None,
                pole_spacing_min_m=_round(spacing.min(), 3) if len(spacing) else None,
                pole_spacing_max_m=_round(spacing.max(), 3) if len(spacing) else None,
                start_x=start[0],
                start_y=start[1],
                start_z=start[2],
                end_x=end[0],
                end_y=end[1],
                end_z=end[2],
                units=len(run.units),
                units_registered=int(np.count_nonzero(np.asarray(run.registered, bool))),
                units_superimposed=int(model.n_units) if model is not None else 0,
                n_points=int(run.n_points),
                notes="; ".join(notes),
            )
        )
    return rows


def inventory_geojson(
    rows: Sequence[InventoryRow], runs: Sequence[RunModel], origin: np.ndarray, crs: str
) -> dict:
    """The inventory as a GeoJSON FeatureCollection (a dict); see the module docstring.

    Feature ``i`` has ``rows[i].to_record()`` as properties and the geometry of ``runs[i]``'s
    poles' ground points + ``origin``, map coordinates in ``crs`` (float64, written at full
    precision).
    """
    o = _origin(origin)
    if not isinstance(crs, str) or not crs:
        raise InvalidOptionError(f"crs must be a non-empty string, got {crs!r}")
    if len(rows) != len(runs):
        raise InvalidOptionError(f"{len(rows)} rows for {len(runs)} runs")
    features = []
    for row, run in zip(rows, runs, strict=True):
        if row.run_id != run.run_id:
            raise InvalidOptionError(
                f"row of run {row.run_id} paired with run {run.run_id}; keep their order"
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
            {
                "type": "Feature",
                "id": int(run.run_id),
                "geometry": geometry,
                "properties": row.to_record(),
            }
        )
    return {
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": crs}},
        "features": features,
    }


def write_inventory_geojson(
    path: Path, rows: Sequence[InventoryRow], runs: Sequence[RunModel], origin: np.ndarray, crs: str
) -> None:
    """Write :func:`inventory_geojson` to ``path``, whole or not at all (:func:`atomic_write`)."""
    text = json.dumps(inventory_geojson(rows, runs, origin, crs), indent=1, allow_nan=False)
    atomic_write(path, text + "\n", overwrite=True)


def write_inventory_csv(path: Path, rows: Sequence[InventoryRow]) -> None:
    """Write the rows as CSV: a header (:data:`ROW_KEYS`), a line per row
    (:meth:`InventoryRow.to_csv_cells`: None as an empty cell, ``design`` as compact JSON)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(ROW_KEYS)
    for row in rows:
        writer.writerow(row.to_csv_cells())
    atomic_write(path, buffer.getvalue(), overwrite=True)


def read_inventory_geojson(path: Path) -> list[InventoryRow]:
    """The rows of an ``inventory.geojson`` (:func:`write_inventory_geojson`), in file order.

    Raises
    ------
    RunFolderError
        The file cannot be read, is not a FeatureCollection, or a feature's properties are
        not a row (:meth:`InventoryRow.from_record`).
    """
    try:
        document = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RunFolderError(f"{path}: cannot be read as JSON ({exc})") from exc
    features = document.get("features") if isinstance(document, dict) else None
    if not isinstance(features, list) or not all(isinstance(f, dict) for f in features):
        raise RunFolderError(f"{path}: expected a FeatureCollection with a 'features' list")
    return [
        InventoryRow.from_record(feature.get("properties"), f"{path}: feature {k}")
        for k, feature in enumerate(features)
    ]


def read_inventory_csv(path: Path) -> list[InventoryRow]:
    """The rows of an ``inventory.csv`` (:func:`write_inventory_csv`), in file order.

    Raises
    ------
    RunFolderError
        The file cannot be read, or a line is not a row (:meth:`InventoryRow.from_csv_record`).
    """
    try:
        with Path(path).open(newline="", encoding="utf-8") as handle:
            reader = csv.DictReader(handle)
            missing = [key for key in ROW_KEYS if key not in (reader.fieldnames or ())]
            if missing:
                raise RunFolderError(f"{path}: the header lacks {', '.join(missing)}")
            # Line 1 is the header: the first row is on line 2.
            return [
                InventoryRow.from_csv_record(record, f"{path}: line {k}")
                for k, record in enumerate(reader, start=2)
            ]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise RunFolderError(f"{path}: cannot be read as CSV ({exc})") from exc
