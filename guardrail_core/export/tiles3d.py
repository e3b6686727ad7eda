"""A run's guardrails as OGC 3D Tiles 1.1, georeferenced on the globe (CesiumJS and the like).

``guardrail export RUN_DIR --3dtiles OUT_DIR`` writes a folder:

* ``tileset.json``: 3D Tiles 1.1. A root tile without content (``refine`` ADD) whose
  ``transform`` places it on the globe, and one child tile per run with geometry, whose
  ``content.uri`` is the run's glTF (3D Tiles 1.1 takes glTF as tile content directly). Each run
  tile carries the run's inventory values as 3D Tiles 1.1 metadata: the tileset's ``schema``
  declares the class ``guardrail`` (``run_id``, ``type``, ``signature``, ``height``,
  ``pole_count``, ``length``) and the tile's ``metadata`` is an entity of that class (values the
  inventory lacks for a run are left out: those properties are optional).
* ``run_NNN.glb``: glTF 2.0 binary, a node per part (``pipes`` or ``beam``, and ``poles``) with
  positions, normals and vertex colours.

Frames, from the globe down (all metres):

* ECEF: EPSG:4978 (WGS 84 geocentric).
* The root frame: east-north-up (z along the WGS 84 ellipsoid's normal) at the drive's origin,
  the origin converted from the drive's CRS to ECEF with pyproj. ``root.transform`` maps it to
  ECEF (column-major, as 3D Tiles stores matrices).
* A run's tile frame: the root frame shifted to the centre of the run's box (``transform`` of
  the run's tile), so the glTF's float32 coordinates are as precise wherever the run lies (a
  km-long run: 0.03 mm).
* The glTF: 3D Tiles rotates glTF content by +90 degrees about x (glTF is y-up, 3D Tiles z-up)
  before the tile's transform, so the glTF point ``(x, y, z)`` is the tile point
  ``(x, -z, y)``; a tile point (east, north, up) is therefore stored as (east, up, -north).

Every vertex is placed exactly: its map coordinates (local + the drive's origin, float64) are
converted to ECEF with pyproj, then into the tile's frame. The drive's local frame is a grid of
its projected CRS, not an east-north-up frame, and no rigid transform maps a drive onto the
globe to the centimetre: taking local x, y, z as east, north, up at the origin misplaces a
vertex by the grid convergence (-0.048 degrees, 0.84 m per km, at the test drive's origin in
EPSG:6677), the scale factor (0.9999: 0.1 m per km), and the Earth's curvature, which even the
projection's exact linearisation at the origin leaves (d^2 / 2R: 8 mm at 300 m, 8 cm at 1 km,
31 cm at 2 km, 2 m at 5 km). Normals are computed from the placed vertices.

Heights: pyproj takes the z of a 2-D projected CRS (like EPSG:6677) as a height above the
ellipsoid; a drive whose heights are above the geoid then sits the geoid's undulation too low on
an ellipsoid-height terrain (some 30-40 m in Japan). A compound CRS with a vertical datum is
converted with its geoid only where PROJ has the geoid's grid installed.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from pyproj import Transformer
from pyproj.exceptions import ProjError

from guardrail_core.errors import ExportError
from guardrail_core.export.run_export import load_export_source
from guardrail_core.formats.atomic import check_output, staged_folder
from guardrail_core.io.meshes import run_file_stem
from guardrail_core.reconstruct.inventory_row import InventoryRow

TILESET_FILE = "tileset.json"
ECEF_CRS = "EPSG:4978"
#: Metres added around each tile's content in its box, so that a reader's float rounding never
#: puts a vertex outside.
BOX_MARGIN_M = 0.001
#: glTF's y-up to 3D Tiles' z-up (3D Tiles 1.1, "glTF transforms"): +90 degrees about x, so
#: the glTF point (x, y, z) is the tile point (x, -z, y).
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: The metadata class of a run tile: property id -> (its value in the run's inventory row,
#: 3D Tiles definition).
RUN_PROPERTIES: dict[str, tuple[Callable[[InventoryRow], Any], dict[str, Any]]] = {
    "run_id": (
        lambda row: row.run_id,
        {"type": "SCALAR", "componentType": "INT32", "required": True, "description": "Run id"},
    ),
    "type": (
        lambda row: row.type,
        {"type": "STRING", "required": True, "description": "pipe, beam or unknown"},
    ),
    "signature": (
        lambda row: row.signature,
        {"type": "STRING", "description": "The rails' design: pipes (radius mm, height m) or beam"},
    ),
    "height": (
        lambda row: row.height_m,
        {
            "type": "SCALAR",
            "componentType": "FLOAT64",
            "description": "Top of the poles or rails above the ground, m",
        },
    ),
    "pole_count": (
        lambda row: row.pole_count,
        {"type": "SCALAR", "componentType": "INT32", "required": True, "description": "Poles"},
    ),
    "length": (
        lambda row: row.length_m,
        {
            "type": "SCALAR",
            "componentType": "FLOAT64",
            "description": "Length along the poles' ground points, m",
        },
    ),
}
METADATA_SCHEMA = {
    "id": "guardrail",
    "classes": {
        "guardrail": {
            "name": "Guardrail run",
            "properties": {name: spec for name, (_, spec) in RUN_PROPERTIES.items()},
        }
    },
}

# glTF 2.0 constants
_FLOAT, _UNSIGNED_BYTE, _UNSIGNED_INT = 5126, 5121, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_TRIANGLES = 4


@dataclass(frozen=True)
class TilesSummary:
    """What :func:`export_run_3dtiles` wrote.

    Attributes
    ----------
    out : the tileset folder (``tileset.json`` and a ``run_NNN.glb`` per tile)
    tiles : run tiles written (runs with geometry)
    triangles : triangles in all the glTFs
    crs : the drive's CRS the map coordinates were converted from (to EPSG:4978)
    empty_runs : ids of runs without geometry (no poles and no model), left out
    """

    out: Path
    tiles: int
    triangles: int
    crs: str
    empty_runs: tuple[int, ...]


@dataclass(frozen=True)
class DriveFrame:
    """The east-north-up frame at a drive's origin, and the way into it from map coordinates.

    Attributes
    ----------
    crs : the drive's CRS
    ecef_from_enu : (4, 4) float64: columns east, north, up (unit vectors) and the origin's
        ECEF position (metres); the root tile's ``transform``
    to_ecef : pyproj's conversion from ``crs`` (x east, y north: ``always_xy``) to ECEF
    """

    crs: str
    ecef_from_enu: np.ndarray
    to_ecef: Transformer

    @classmethod
    def at(cls, crs: str, origin: np.ndarray) -> DriveFrame:
        """The frame at ``origin``, (3,) float64 map coordinates in ``crs``.

        Raises
        ------
        ExportError
            PROJ does not know ``crs`` or cannot convert ``origin`` to ECEF.
        """
        try:
            to_ecef = Transformer.from_crs(crs, ECEF_CRS, always_xy=True)
        except ProjError as error:
            raise ExportError(
                f"the drive's CRS {crs!r} cannot be converted to ECEF: {error}"
            ) from error
        ecef = _convert(to_ecef, np.asarray(origin, np.float64).reshape(1, 3))[0]
        lon, lat, _ = Transformer.from_crs(ECEF_CRS, "EPSG:4979", always_xy=True).transform(
            ecef[0], ecef[1], ecef[2], radians=True
        )
        east = [-np.sin(lon), np.cos(lon), 0.0]
        north = [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)]
        up = [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]
        matrix = np.eye(4)
        matrix[:3, :3] = np.column_stack([east, north, up])
        matrix[:3, 3] = ecef
        return cls(crs=crs, ecef_from_enu=matrix, to_ecef=to_ecef)

    def to_enu(self, map_xyz: np.ndarray) -> np.ndarray:
        """(N, 3) float64 root-frame coordinates (east, north, up, metres) of (N, 3) map
        coordinates, each converted exactly (pyproj to ECEF, then rotated).

        Raises
        ------
        ExportError
            A coordinate lies outside what the CRS can convert.
        """
        ecef = _convert(self.to_ecef, map_xyz)
        rotation = self.ecef_from_enu[:3, :3]
        return (ecef - self.ecef_from_enu[:3, 3]) @ rotation  # rotation^T (ecef - origin)


def export_run_3dtiles(
    run_dir: str | Path,
    out_dir: str | Path,
    *,
    drive_dir: str | Path | None = None,
    overwrite: bool = False,
) -> TilesSummary:
    """Write a run's reconstructed guardrails as a 3D Tiles 1.1 tileset folder.

    Parameters
    ----------
    run_dir : a run folder with a reconstruction (``guardrail process`` or ``reconstruct``)
    out_dir : the folder to write (``tileset.json`` and ``run_NNN.glb``; see the module
        docstring for frames and metadata)
    drive_dir : the run's drive (default: ``run.json``'s ``drive.path``)
    overwrite : replace ``out_dir`` if it exists and is not empty

    Returns
    -------
    A :class:`TilesSummary`. The folder appears whole or not at all
    (:func:`guardrail_core.formats.atomic.staged_folder`); the output is checked once the run's
    reconstruction and drive are read, before any work.

    Raises
    ------
    OutputExistsError
        ``out_dir`` exists, is not empty, and ``overwrite`` is false.
    InputInsideOutputError
        ``out_dir`` is, holds, or would replace part of something the export reads (the run
        folder's files, ``reconstruction/``, the drive's parts), even with ``overwrite``.
    OutputKindError, OutputSymlinkError
        ``out_dir`` is a file, or a symbolic link.
    ExportError
        The drive names no CRS, PROJ cannot convert it to ECEF, or no run has geometry.
    RunFolderError, DriveError
        The run folder, its reconstruction or the drive cannot be read.
    """
    out_dir = Path(out_dir)
    source = load_export_source(run_dir, drive_dir)
    check_output(out_dir, folder=True, overwrite=overwrite, inputs=source.inputs)
    frame = DriveFrame.at(source.crs, source.origin)

    tiles: list[_Tile] = []
    empty: list[int] = []
    for run, row in zip(source.runs, source.rows, strict=True):
        parts = {name: mesh for name, mesh in source.parts(run).items() if len(mesh.faces)}
        if parts:
            tiles.append(_run_tile(frame, source.to_map, run.run_id, parts, row))
        else:
            empty.append(run.run_id)
    if not tiles:
        raise ExportError(
            f"{source.run_dir}: no reconstructed run has geometry (poles or rails); "
            "a tileset needs at least one"
        )

    bounds = np.stack([tile.bounds for tile in tiles])
    low, high = bounds[:, 0].min(axis=0), bounds[:, 1].max(axis=0)
    # Drawing the root without its children shows nothing: its error is the whole extent.
    extent = float(np.linalg.norm(high - low))
    tileset = {
        "asset": {
            "version": "1.1",
            "extras": {
                "generator": "guardrail export",
                "drive": source.drive_name,
                "crs": source.crs,
                "origin": source.origin.tolist(),
            },
        },
        "schema": METADATA_SCHEMA,
        "geometricError": extent,
        "root": {
            "transform": _column_major(frame.ecef_from_enu),
            "boundingVolume": {"box": _box(low, high)},
            "geometricError": extent,
            "refine": "ADD",
            "children": [tile.entry for tile in tiles],
        },
    }
    with staged_folder(out_dir, overwrite=overwrite, inputs=source.inputs) as staging:
        for tile in tiles:
            (staging / tile.entry["content"]["uri"]).write_bytes(tile.glb)
        (staging / TILESET_FILE).write_text(json.dumps(tileset, indent=1, allow_nan=False) + "\n")
    return TilesSummary(
        out=out_dir,
        tiles=len(tiles),
        triangles=sum(tile.triangles for tile in tiles),
        crs=source.crs,
        empty_runs=tuple(empty),
    )


def format_tiles_summary(summary: TilesSummary) -> str:
    """The summary as the CLI prints it."""
    empty = ""
    if summary.empty_runs:
        ids = ", ".join(str(i) for i in summary.empty_runs)
        empty = f"; left out without geometry: run {ids}"
    return (
        f"{summary.tiles} run tile{'s' if summary.tiles != 1 else ''} "
        f"({summary.triangles:,} triangles) as 3D Tiles 1.1, from {summary.crs} to ECEF "
        f"(EPSG:4978){empty}\nwrote {summary.out / TILESET_FILE}"
    )


# ------------------------------------------------------------------------------------ helpers


@dataclass(frozen=True)
class _Tile:
    """A run's tile.

    Attributes
    ----------
    entry : its tile in ``tileset.json``
    glb : its content, a GLB
    bounds : (2, 3) float64, metres: its box's lowest and highest corner in the root frame
    triangles : triangles in ``glb``
    """

    entry: dict
    glb: bytes
    bounds: np.ndarray
    triangles: int


def _run_tile(
    frame: DriveFrame,
    to_map: Callable[[np.ndarray], np.ndarray],
    run_id: int,
    parts: Mapping[str, trimesh.Trimesh],
    row: InventoryRow,
) -> _Tile:
    """The tile of run ``run_id``: its ``parts`` (local frame, vertex-coloured, each with
    faces) placed exactly in a frame at the centre of their box, ``row`` (its inventory row) as
    metadata."""
    enu = {name: frame.to_enu(to_map(mesh.vertices)) for name, mesh in parts.items()}
    everything = np.concatenate(list(enu.values()))
    centre = (everything.min(axis=0) + everything.max(axis=0)) / 2
    # Row vectors: tile = Y_UP_TO_Z_UP @ glTF, so glTF = tile @ Y_UP_TO_Z_UP. Rounded to the
    # float32 the GLB stores, so that the box and the normals are those of what is written.
    gltf = {
        name: trimesh.Trimesh(
            ((enu[name] - centre) @ Y_UP_TO_Z_UP).astype(np.float32).astype(np.float64),
            mesh.faces,
            vertex_colors=mesh.visual.vertex_colors,  # type: ignore[union-attr]
            process=False,
        )
        for name, mesh in parts.items()
    }
    stored = np.concatenate([mesh.vertices for mesh in gltf.values()]) @ Y_UP_TO_Z_UP.T
    low = stored.min(axis=0) - BOX_MARGIN_M
    high = stored.max(axis=0) + BOX_MARGIN_M
    stem = run_file_stem(run_id)
    entry = {
        "transform": _column_major(_translation(centre)),
        "boundingVolume": {"box": _box(low, high)},
        "geometricError": 0.0,  # the run's full mesh: nothing finer to show
        "content": {"uri": f"{stem}.glb"},
        "metadata": _run_metadata(row),
    }
    return _Tile(
        entry=entry,
        glb=_glb(stem, gltf),
        bounds=np.stack([low, high]) + centre,
        triangles=sum(len(mesh.faces) for mesh in parts.values()),
    )


def _convert(to_ecef: Transformer, map_xyz: np.ndarray) -> np.ndarray:
    """(N, 3) float64 ECEF of (N, 3) map coordinates."""
    xyz = np.asarray(map_xyz, np.float64)
    ecef = np.column_stack(to_ecef.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2]))
    if not np.isfinite(ecef).all():  # PROJ answers inf outside the projection's domain
        raise ExportError(
            f"map coordinates in {to_ecef.source_crs} lie outside what it can convert to ECEF"
        )
    return ecef


def _translation(offset: np.ndarray) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, 3] = offset
    return matrix


def _column_major(matrix: np.ndarray) -> list[float]:
    """A (4, 4) matrix as 3D Tiles stores it: 16 numbers, column by column."""
    return [float(v) for v in np.asarray(matrix, np.float64).T.ravel()]


def _box(low: np.ndarray, high: np.ndarray) -> list[float]:
    """A 3D Tiles ``box`` (centre, then the x, y and z half-axes) of an axis-aligned box."""
    half = (high - low) / 2
    return [float(v) for v in np.concatenate([(low + high) / 2, np.diag(half).ravel()])]


def _run_metadata(row: InventoryRow) -> dict:
    """The run tile's metadata entity; values the inventory lacks (None) are left out."""
    values = {name: value_of(row) for name, (value_of, _) in RUN_PROPERTIES.items()}
    properties = {name: value for name, value in values.items() if value is not None}
    return {"class": "guardrail", "properties": properties}


def _srgb_to_linear(rgba: np.ndarray) -> np.ndarray:
    """(V, 4) uint8 sRGB colours as (V, 4) uint8 linear ones: glTF's ``COLOR_0`` is linear."""
    out = np.asarray(rgba, np.uint8).copy()
    c = out[:, :3] / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    out[:, :3] = np.round(linear * 255)
    return out


def _glb(name: str, parts: Mapping[str, trimesh.Trimesh]) -> bytes:
    """A glTF 2.0 binary: a node ``name`` with a child node and mesh per part.

    Parameters
    ----------
    name : the root node's name (``run_NNN``)
    parts : the run's meshes by part in glTF (y-up) coordinates, metres, float32 values;
        vertex-coloured (sRGB)
    """
    blob = bytearray()
    views: list[dict] = []
    accessors: list[dict] = []

    def add(array: np.ndarray, target: int, accessor: dict) -> int:
        views.append(
            {"buffer": 0, "byteOffset": len(blob), "byteLength": array.nbytes, "target": target}
        )
        blob.extend(array.tobytes())  # every array here is a multiple of 4 bytes long
        accessors.append({"bufferView": len(views) - 1, "count": len(array), **accessor})
        return len(accessors) - 1

    meshes, nodes = [], []
    for part, mesh in parts.items():
        xyz = np.asarray(mesh.vertices, np.float32)
        colors = mesh.visual.vertex_colors  # type: ignore[union-attr]
        attributes = {
            "POSITION": add(
                xyz,
                _ARRAY_BUFFER,
                {
                    "componentType": _FLOAT,
                    "type": "VEC3",
                    "min": [float(v) for v in xyz.min(axis=0)],
                    "max": [float(v) for v in xyz.max(axis=0)],
                },
            ),
            "NORMAL": add(
                np.asarray(mesh.vertex_normals, np.float32),
                _ARRAY_BUFFER,
                {"componentType": _FLOAT, "type": "VEC3"},
            ),
            "COLOR_0": add(
                _srgb_to_linear(colors),
                _ARRAY_BUFFER,
                {"componentType": _UNSIGNED_BYTE, "normalized": True, "type": "VEC4"},
            ),
        }
        indices = add(
            np.asarray(mesh.faces, np.uint32).ravel(),
            _ELEMENT_ARRAY_BUFFER,
            {"componentType": _UNSIGNED_INT, "type": "SCALAR"},
        )
        primitive = {
            "attributes": attributes,
            "indices": indices,
            "material": 0,
            "mode": _TRIANGLES,
        }
        meshes.append({"name": part, "primitives": [primitive]})
        nodes.append({"name": part, "mesh": len(meshes) - 1})
    document = {
        "asset": {"version": "2.0", "generator": "guardrail export"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": name, "children": list(range(1, len(nodes) + 1))}, *nodes],
        "meshes": meshes,
        # Not metallic: without an environment map, viewers draw a metal nearly black. Double
        # sided: a sweep without caps is an open surface.
        "materials": [
            {
                "name": "guardrail",
                "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 0.8},
                "doubleSided": True,
            }
        ],
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": views,
        "accessors": accessors,
    }
    text = json.dumps(document, separators=(",", ":"), allow_nan=False).encode("utf-8")
    text += b" " * (-len(text) % 4)  # chunks are 4-byte aligned: JSON padded with spaces
    total = 12 + 8 + len(text) + 8 + len(blob)
    return b"".join(
        [
            struct.pack("<4sII", b"glTF", 2, total),
            struct.pack("<I4s", len(text), b"JSON"),
            text,
            struct.pack("<I4s", len(blob), b"BIN\x00"),
            bytes(blob),
        ]
    )
