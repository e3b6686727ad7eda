"""A run's guardrails as a CityJSON 2.0 file: one ``CityFurniture`` city object per run.

``export_run_cityjson(RUN_DIR, OUT.city.json)`` writes what the run reconstructed for 3D city
model tools (cjio, QGIS, 3DCityDB, citygml-tools; https://www.cityjson.org/specs/2.0.1/):

* one ``CityFurniture`` per run (id ``guardrail-run-000`` for run 0) whose inventory status is
  "reconstructed" or "poles only"; a "not reconstructed" run (no unit model and no pole) has no
  geometry to write and is skipped (:attr:`CityJsonSummary.skipped_runs`)
* geometry, in the drive's CRS:

  - LOD2 ``MultiSurface`` (a reconstructed run): every triangle of the run's meshes
    (:meth:`ExportSource.parts <guardrail_core.export.run_export.ExportSource.parts>`) as a
    surface, the rails (``pipes`` or ``beam``) first, then the poles, without semantics (CityJSON
    has no semantic surface type for city furniture). One geometry, not one per part: citygml4j
    (citygml-tools) keeps only the last of two geometries of the same LOD.
  - LOD1 ``MultiLineString`` (every run with poles): the line through the poles' ground points,
    then each pole's axis from its ground point to its top (so a run of one pole has a line too).
    Lines, not a box per pole: citygml4j turns a LOD1 ``MultiSurface`` into one solid.

* attributes (:data:`ROW_ATTRIBUTES`, from the run's inventory row,
  :class:`~guardrail_core.reconstruct.inventory_row.InventoryRow`; a value the row lacks is left
  out, not written as null): ``function``, ``status``, ``guardrail_type`` ("pipe", "beam" or
  "unknown"), ``signature`` (the design, e.g. ``beam h0.35 d0.085 y0.43-0.78``), ``height_m``,
  ``rail_top_m``, ``pole_count``, ``pole_spacing_m`` (median), ``length_m``, ``run_id``, and
  ``source_drive`` (the drive folder's name).
  ``function`` is the text ``"guardrail"``: SIG3D's CityGML 2.0 code list for
  ``CityFurniture/function`` (the one CityGML 2.0 suggests) has no code for a guardrail or crash
  barrier (the nearest are 1440 "fence" and 1540 "others"), and the code of a national list
  (PLATEAU's) could not be established here. citygml-tools writes it as ``frn:function``.

Vertices are integers with ``transform`` scale 1 mm and translate = the drive's origin, so a map
coordinate is ``vertex * 0.001 + origin`` and stays within 0.5 mm (per axis) of the mesh; each
distinct vertex is written once. A triangle whose corners are collinear at 1 mm (a sliver of a
thin pipe) is not a valid surface and is left out (:attr:`CityJsonSummary.degenerate_triangles`).
``metadata.referenceSystem`` names the drive's CRS as an OGC URL
(``EPSG:6677`` -> ``https://www.opengis.net/def/crs/EPSG/0/6677``); a CRS that is not
``EPSG:<code>`` (a compound ``EPSG:6677+6695``, WKT, ``unknown``) is refused, since CityJSON names
one CRS by one URL. The file is written whole or not at all
(:func:`guardrail_core.formats.atomic.atomic_write`) and never over an input.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from guardrail_core.errors import ExportError
from guardrail_core.export.run_export import ExportSource, load_export_source
from guardrail_core.formats.atomic import atomic_write, check_output
from guardrail_core.reconstruct.inventory_row import InventoryRow
from guardrail_core.reconstruct.model import Pole

CITYJSON_VERSION = "2.0"
#: Metres per integer vertex unit (``transform.scale``).
SCALE_M = 0.001
#: The ``function`` attribute of every guardrail (see the module docstring).
FUNCTION = "guardrail"
#: The city object id of run ``run_id``.
OBJECT_ID = "guardrail-run-{run_id:03d}"
#: (attribute, its value in the run's inventory row) of the attributes taken from the row.
ROW_ATTRIBUTES: tuple[tuple[str, Callable[[InventoryRow], Any]], ...] = (
    ("status", lambda row: row.status),
    ("guardrail_type", lambda row: row.type),
    ("signature", lambda row: row.signature),
    ("height_m", lambda row: row.height_m),
    ("rail_top_m", lambda row: row.rail_top_m),
    ("pole_count", lambda row: row.pole_count),
    ("pole_spacing_m", lambda row: row.pole_spacing_m),
    ("length_m", lambda row: row.length_m),
    ("run_id", lambda row: row.run_id),
)
_EPSG = re.compile(r"EPSG:(\d+)", re.IGNORECASE)


@dataclass(frozen=True)
class CityJsonSummary:
    """What :func:`export_run_cityjson` wrote.

    Attributes
    ----------
    out : the CityJSON file
    objects : CityFurniture city objects (one per run with a geometry)
    lod2_objects : objects with LOD2 surfaces (and LOD1 lines)
    lod1_only_objects : objects with LOD1 lines only (runs with poles but no rails)
    skipped_runs : runs with neither a unit model nor a pole (nothing to draw)
    degenerate_triangles : mesh triangles left out, collinear at 1 mm
    vertices : distinct vertices written
    crs : the drive's CRS (``EPSG:<code>``), named in ``metadata.referenceSystem``
    """

    out: Path
    objects: int
    lod2_objects: int
    lod1_only_objects: int
    skipped_runs: int
    degenerate_triangles: int
    vertices: int
    crs: str


def export_run_cityjson(
    run_dir: str | Path,
    out: str | Path,
    *,
    drive_dir: str | Path | None = None,
    overwrite: bool = False,
) -> CityJsonSummary:
    """Write a run's reconstructed guardrails as CityJSON 2.0 (see the module docstring).

    Parameters
    ----------
    run_dir : a run folder with a reconstruction (``guardrail process`` or ``reconstruct``)
    out : the file to write, ``.json`` (by convention ``.city.json``)
    drive_dir : the run's drive (default: ``run.json``'s ``drive.path``)
    overwrite : replace ``out`` if it exists

    Returns
    -------
    A :class:`CityJsonSummary`.

    Raises
    ------
    ExportError
        ``out`` is not a ``.json`` path, or the drive's CRS is not ``EPSG:<code>`` (or is none).
    OutputExistsError
        ``out`` exists and ``overwrite`` is false.
    InputInsideOutputError, OutputKindError, OutputSymlinkError
        ``out`` is a file the export reads, a folder or a symbolic link (checked before any
        geometry is built).
    NoReconstructionError, RunFolderError
        The run folder has no reconstruction, or it cannot be read.
    DriveError
        The drive's ``drive.json`` or trajectory cannot be read.
    """
    out = Path(out)
    if out.suffix.lower() != ".json":
        raise ExportError(f"{out}: give a .json file name (by convention .city.json)")
    source = load_export_source(run_dir, drive_dir)
    check_output(out, folder=False, overwrite=overwrite, inputs=source.inputs)
    reference_system = ogc_crs_url(source.crs)
    document, summary = cityjson_document(source, reference_system)
    text = json.dumps(document, separators=(",", ":"), allow_nan=False)
    atomic_write(out, text + "\n", overwrite=overwrite, inputs=source.inputs)
    return CityJsonSummary(out=out, crs=source.crs, **summary)


def format_cityjson_summary(summary: CityJsonSummary) -> str:
    """The summary as the CLI prints it (what was left out only when something was)."""
    left_out = ""
    if summary.skipped_runs:
        left_out += f"; runs skipped (no model, no poles): {summary.skipped_runs}"
    if summary.degenerate_triangles:
        left_out += f"; triangles left out (collinear at 1 mm): {summary.degenerate_triangles:,}"
    return (
        f"{summary.objects} CityFurniture objects ({summary.lod2_objects} with LOD2 surfaces, "
        f"{summary.lod1_only_objects} with LOD1 lines only), {summary.vertices:,} vertices, "
        f"CityJSON {CITYJSON_VERSION}, CRS {summary.crs}{left_out}\n"
        f"wrote {summary.out}"
    )


def ogc_crs_url(crs: str) -> str:
    """The OGC URL of an ``EPSG:<code>`` CRS (``https://www.opengis.net/def/crs/EPSG/0/<code>``).

    Raises
    ------
    ExportError
        ``crs`` is not ``EPSG:<code>`` (the message names it).
    """
    match = _EPSG.fullmatch(crs)
    if match is None:
        raise ExportError(
            f"the drive's CRS {crs!r} is not of the form EPSG:<code>; CityJSON names one CRS "
            "by its EPSG code (a compound CRS by the code of the compound)"
        )
    return f"https://www.opengis.net/def/crs/EPSG/0/{int(match.group(1))}"


def cityjson_document(source: ExportSource, reference_system: str) -> tuple[dict, dict[str, int]]:
    """The CityJSON document of ``source``'s runs, and its counts.

    Parameters
    ----------
    source : what :func:`load_export_source` read
    reference_system : ``metadata.referenceSystem`` (:func:`ogc_crs_url`)

    Returns
    -------
    document : the CityJSON 2.0 object, ready for :func:`json.dumps`
    counts : ``objects``, ``lod2_objects``, ``lod1_only_objects``, ``skipped_runs``,
        ``degenerate_triangles``, ``vertices`` (the fields of :class:`CityJsonSummary`)
    """
    counts = dict.fromkeys(
        ("objects", "lod2_objects", "lod1_only_objects", "skipped_runs", "degenerate_triangles"),
        0,
    )
    drafts: list[tuple[str, dict[str, Any], list[_Geometry]]] = []
    for run, row in zip(source.runs, source.rows, strict=True):
        geometries = []
        if row.status == "reconstructed":
            surfaces, dropped = _surfaces(source.parts(run).values())
            counts["degenerate_triangles"] += dropped
            if surfaces is not None:
                geometries.append(surfaces)
        lines = _pole_lines(run.poles)
        if lines is not None:
            geometries.append(lines)
        if not geometries:
            counts["skipped_runs"] += 1
            continue
        counts["objects"] += 1
        counts["lod2_objects" if geometries[0].lod == "2" else "lod1_only_objects"] += 1
        attributes: dict[str, Any] = {"function": FUNCTION}
        values = ((name, value_of(row)) for name, value_of in ROW_ATTRIBUTES)
        attributes.update((name, value) for name, value in values if value is not None)
        attributes["source_drive"] = source.drive_name
        drafts.append((OBJECT_ID.format(run_id=run.run_id), attributes, geometries))

    vertices, written = _index([g for _, _, geometries in drafts for g in geometries])
    in_order = iter(written)
    objects = {
        object_id: {
            "type": "CityFurniture",
            "attributes": attributes,
            "geometry": [next(in_order) for _ in geometries],
        }
        for object_id, attributes, geometries in drafts
    }
    metadata: dict[str, Any] = {
        "title": f"Guardrails reconstructed from the drive {source.drive_name}",
        "referenceSystem": reference_system,
    }
    if len(vertices):
        lo = vertices.min(axis=0) * SCALE_M + source.origin
        hi = vertices.max(axis=0) * SCALE_M + source.origin
        metadata["geographicalExtent"] = [float(v) for v in (*lo, *hi)]
    document = {
        "type": "CityJSON",
        "version": CITYJSON_VERSION,
        "transform": {"scale": [SCALE_M] * 3, "translate": [float(v) for v in source.origin]},
        "metadata": metadata,
        "CityObjects": objects,
        "vertices": vertices.tolist(),
    }
    return document, {**counts, "vertices": len(vertices)}


# ------------------------------------------------------------------------------------ helpers


@dataclass(frozen=True)
class _Geometry:
    """A geometry whose boundaries are still coordinates, not indices into the vertex list.

    Attributes
    ----------
    type : "MultiSurface" (triangles: every 3 points one surface's ring) or "MultiLineString"
    lod : "2" or "1"
    points : (N, 3) int64 vertex coordinates, mm from the drive's origin
    line_sizes : points of each line, in order (MultiLineString only)
    """

    type: str
    lod: str
    points: np.ndarray
    line_sizes: tuple[int, ...] = ()

    def to_json(self, indices: np.ndarray) -> dict[str, Any]:
        """The CityJSON geometry object, with ``indices`` (N,) the vertex index of each point."""
        if self.type == "MultiSurface":
            boundaries: list = [[ring] for ring in indices.reshape(-1, 3).tolist()]
        else:
            ends = np.cumsum(self.line_sizes)[:-1]
            boundaries = [line.tolist() for line in np.split(indices, ends)]
        return {"type": self.type, "lod": self.lod, "boundaries": boundaries}


def _mm(local: np.ndarray) -> np.ndarray:
    """(..., 3) int64 vertex coordinates of (..., 3) local metres (``transform`` undone)."""
    return np.rint(np.asarray(local, np.float64) / SCALE_M).astype(np.int64)


def _surfaces(meshes: Iterable[trimesh.Trimesh]) -> tuple[_Geometry | None, int]:
    """The LOD2 MultiSurface of ``meshes`` (trimesh, local frame), one surface per triangle, and
    how many triangles were left out: those whose corners are collinear once rounded to 1 mm
    (a polygon must enclose an area). None when no triangle is left."""
    triangles = [np.asarray(m.vertices)[np.asarray(m.faces)] for m in meshes if len(m.faces)]
    if not triangles:
        return None, 0
    corners = _mm(np.concatenate(triangles))  # (T, 3, 3)
    keep = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]).any(axis=1)
    dropped = int(np.count_nonzero(~keep))
    if not keep.any():
        return None, dropped
    return _Geometry("MultiSurface", "2", corners[keep].reshape(-1, 3)), dropped


def _pole_lines(poles: list[Pole]) -> _Geometry | None:
    """The LOD1 MultiLineString of a run's poles: the line through their ground points (when
    two or more differ at 1 mm), then each pole's axis from the ground to its top (when it is
    1 mm or more). None for a run without poles."""
    if not poles:
        return None
    ground_m = np.array([p.position for p in poles], np.float64).reshape(-1, 3)
    top_m = ground_m.copy()
    top_m[:, 2] += [p.height for p in poles]
    ground, top = _mm(ground_m), _mm(top_m)
    # Two poles within 1 mm would repeat a point, and a line must not.
    distinct = np.r_[True, np.diff(ground, axis=0).any(axis=1)]
    lines = [ground[distinct]] if np.count_nonzero(distinct) >= 2 else []
    lines += [np.stack([g, t]) for g, t in zip(ground, top, strict=True) if (g != t).any()]
    if not lines:
        return None
    return _Geometry(
        "MultiLineString", "1", np.concatenate(lines), tuple(len(line) for line in lines)
    )


def _index(geometries: list[_Geometry]) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """The distinct vertices of ``geometries`` (V, 3) int64 (sorted) and each geometry's CityJSON
    object indexing them; every vertex is used."""
    if not geometries:
        return np.empty((0, 3), np.int64), []
    points = np.concatenate([g.points for g in geometries])
    vertices, inverse = np.unique(points, axis=0, return_inverse=True)
    ends = np.cumsum([len(g.points) for g in geometries])
    return vertices, [
        g.to_json(indices)
        for g, indices in zip(geometries, np.split(inverse.reshape(-1), ends[:-1]), strict=True)
    ]
