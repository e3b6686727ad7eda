"""One row of the guardrail inventory (:class:`InventoryRow`) and its two on-disk forms.

A run folder's ``reconstruction/inventory.geojson`` holds a row as a feature's ``properties``
(:meth:`InventoryRow.to_record`: plain JSON, None as null), ``reconstruction/inventory.csv`` as a
line of cells (:meth:`InventoryRow.to_csv_cells`: None as an empty cell, ``design`` as compact
JSON, numbers as ``str`` writes them). Both list the keys of :data:`ROW_KEYS` in that order; the
``from_*`` methods read them back and raise :class:`~guardrail_core.errors.RunFolderError` for a
missing or malformed key.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any

from guardrail_core.errors import RunFolderError

#: A run's ``status``: a unit model with pipes or a beam section; poles but no such model;
#: neither.
STATUSES = ("reconstructed", "poles only", "not reconstructed")
#: A run's ``type``: its unit model's, "unknown" without a model.
RUN_TYPES = ("pipe", "beam", "unknown")

#: ``design``: a pipe model's pipes, a beam model's section summary, or None.
Design = list[dict[str, Any]] | dict[str, Any] | None


@dataclass(frozen=True)
class InventoryRow:
    """What the reconstruction found of one guardrail run (Matsumoto et al. 2019, §4).

    Lengths and spacings are 3-D distances between consecutive poles' ground points, in metres;
    heights are metres above the ground line. A value the run lacks (no poles, no model) is None.

    Attributes
    ----------
    run_id : the run's id in the run folder
    status : one of :data:`STATUSES`
    type : one of :data:`RUN_TYPES` (the unit model's type)
    signature : the design as text, e.g. ``"beam h0.35 d0.085 y0.43-0.77"`` (pipe radii in mm,
        heights in m; :func:`~guardrail_core.reconstruct.inventory.pipe_signature`,
        :func:`~guardrail_core.reconstruct.inventory.beam_signature`); None without a model
    design : the design as plain JSON: a list of pipes ``{kind, radius_mm, y_min_m, y_max_m,
        x_min_m, x_max_m, n_points}`` or the beam's ``{height_m, depth_m, y_min_m, y_max_m,
        section}`` (section: [[z, y], ...] m); None without a model
    length_m : metres, the sum of the distances between consecutive poles
    height_m : metres, the higher of the poles' median height and the rails' top
    rail_top_m : metres, the rails' highest point (pipes' tops or the beam section's)
    pole_count : poles of the run, placed ones included
    poles_seen : poles with points (the others were placed where one was missing)
    pole_radius_m : metres, the poles' median radius
    pole_spacing_m, pole_spacing_min_m, pole_spacing_max_m : metres, the median, least and
        greatest distance between consecutive poles (None for fewer than two poles)
    start_x, start_y, start_z : the first pole's ground point, map coordinates (the drive's CRS,
        metres; local + the drive's origin, float64)
    end_x, end_y, end_z : the last pole's, likewise
    units : units (spans between consecutive poles) of the run
    units_registered : units that ICP registered onto the others
    units_superimposed : units superimposed into the unit model (0 without a model)
    n_points : guardrail points of the run
    notes : the run's and the model's notes, "; "-joined ("" for none)
    """

    run_id: int
    status: str
    type: str
    signature: str | None
    design: Design
    length_m: float | None
    height_m: float | None
    rail_top_m: float | None
    pole_count: int
    poles_seen: int
    pole_radius_m: float | None
    pole_spacing_m: float | None
    pole_spacing_min_m: float | None
    pole_spacing_max_m: float | None
    start_x: float | None
    start_y: float | None
    start_z: float | None
    end_x: float | None
    end_y: float | None
    end_z: float | None
    units: int
    units_registered: int
    units_superimposed: int
    n_points: int
    notes: str

    def to_record(self) -> dict[str, Any]:
        """The row as plain JSON (a GeoJSON feature's ``properties``), keys in
        :data:`ROW_KEYS` order; ``design`` is a copy, so the record never aliases the row."""
        return asdict(self)

    @classmethod
    def from_record(cls, record: Mapping[str, Any], where: str = "inventory row") -> InventoryRow:
        """The row of a :meth:`to_record` dict (e.g. a feature's ``properties``, read back).

        Integers must be JSON integers; a number of metres may be an integer or a float.
        Keys beyond :data:`ROW_KEYS` are ignored (a GIS tool may add its own).

        Raises
        ------
        RunFolderError
            A key is missing, or its value has the wrong type or is not an allowed value;
            the message starts with ``where``.
        """
        if not isinstance(record, Mapping):
            raise RunFolderError(f"{where}: expected an object, got {type(record).__name__}")
        return cls._parsed(record, where, _FROM_JSON)

    def to_csv_cells(self) -> list[str]:
        """The row as the cells of a CSV line, in :data:`ROW_KEYS` order: None as an empty
        cell, ``design`` as compact JSON, numbers as ``str`` writes them (a float's repr: full
        float64 precision for map coordinates)."""
        return [_cell(value) for value in self.to_record().values()]

    @classmethod
    def from_csv_record(
        cls, record: Mapping[str, str], where: str = "inventory row"
    ) -> InventoryRow:
        """The row of a CSV line as :class:`csv.DictReader` reads it ({key: cell}).

        An empty cell is None where the field allows it (an empty ``notes`` is ""); the CSV
        cannot tell an empty ``signature`` from None, and the inventory never writes one.

        Raises
        ------
        RunFolderError
            As :meth:`from_record`.
        """
        return cls._parsed(record, where, _FROM_CSV)

    @classmethod
    def _parsed(
        cls,
        record: Mapping[str, Any],
        where: str,
        parsers: Mapping[str, Callable[[Any], Any]],
    ) -> InventoryRow:
        values: dict[str, Any] = {}
        for field in fields(cls):
            if field.name not in record:
                raise RunFolderError(f"{where}: no {field.name!r}")
            raw = record[field.name]
            try:
                values[field.name] = parsers[str(field.type)](raw)
            except (TypeError, ValueError, OverflowError) as exc:
                raise RunFolderError(f"{where}: {field.name!r} is {raw!r}: {exc}") from exc
        for name, allowed in (("status", STATUSES), ("type", RUN_TYPES)):
            if values[name] not in allowed:
                raise RunFolderError(
                    f"{where}: {name!r} is {values[name]!r}, expected one of {allowed}"
                )
        return cls(**values)


#: The keys of a row, in the order of the CSV's columns and of the GeoJSON's properties.
ROW_KEYS = tuple(field.name for field in fields(InventoryRow))


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, list | dict):
        return json.dumps(value, separators=(",", ":"))
    return str(value)  # str(float) is repr: full float64 precision for map coordinates


def _json_int(value: Any) -> int:
    # bool is an int to Python, never to the inventory.
    if type(value) is not int:
        raise TypeError("expected an integer")
    return value


def _json_float(value: Any) -> float | None:
    if value is None:
        return None
    if type(value) not in (int, float) or not math.isfinite(value):
        raise TypeError("expected a finite number or null")
    return float(value)


def _json_str(value: Any) -> str:
    if not isinstance(value, str):
        raise TypeError("expected a string")
    return value


def _json_optional_str(value: Any) -> str | None:
    return None if value is None else _json_str(value)


def _json_design(value: Any) -> Design:
    if value is None or isinstance(value, dict):
        return value
    if isinstance(value, list) and all(isinstance(item, dict) for item in value):
        return value
    raise TypeError("expected a list of pipe objects, a beam object or null")


_INTEGER = re.compile(r"-?[0-9]+")


def _csv_int(cell: str) -> int:
    # Stricter than int(), which also takes "1_000" and " 7".
    if not _INTEGER.fullmatch(cell):
        raise ValueError("expected an integer")
    return int(cell)


def _csv_float(cell: str) -> float | None:
    if cell == "":
        return None
    value = float(cell)
    if not math.isfinite(value):
        raise ValueError("expected a finite number or an empty cell")
    return value


def _csv_design(cell: str) -> Design:
    return None if cell == "" else _json_design(json.loads(cell))


#: Per field annotation (as written above: ``from __future__ import annotations`` keeps them
#: text), how a value is read from JSON and from a CSV cell.
_FROM_JSON: dict[str, Callable[[Any], Any]] = {
    "int": _json_int,
    "str": _json_str,
    "str | None": _json_optional_str,
    "float | None": _json_float,
    "Design": _json_design,
}
_FROM_CSV: dict[str, Callable[[Any], Any]] = {
    "int": _csv_int,
    "str": _json_str,
    "str | None": lambda cell: None if cell == "" else _json_str(cell),
    "float | None": _csv_float,
    "Design": _csv_design,
}
