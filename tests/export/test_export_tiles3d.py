"""``guardrail export RUN_DIR --3dtiles OUT_DIR``: OGC 3D Tiles 1.1, read back independently.

``tileset.json`` is read as plain JSON and every glTF with pygltflib (the export writes its
glTFs itself, not with trimesh). Each vertex is carried through the tile transforms as 3D Tiles
prescribes (glTF y-up to z-up, the run tile's transform, the root's) and must land within 1 cm
of its ECEF position, which pyproj computes from the mesh vertex's map coordinates.
``tileset.json`` is validated against the official 3D Tiles 1.1 schema (``tests/data/schemas``).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from pyproj import Transformer

from guardrail_core.errors import ExportError, InputInsideOutputError, OutputExistsError
from guardrail_core.export.run_export import ExportSource, load_export_source
from guardrail_core.export.tiles3d import (
    TILESET_FILE,
    TilesSummary,
    export_run_3dtiles,
    format_tiles_summary,
)
from guardrail_core.formats.run_folder_paths import RunFolder
from tests.json_schemas import schema_errors

CM = 0.01
#: glTF y-up to 3D Tiles z-up, as the 3D Tiles 1.1 specification writes it (+90 deg about x).
Y_UP_TO_Z_UP = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], float)
#: glTF accessor component types and widths.
COMPONENTS = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
WIDTH = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}


@dataclass
class Part:
    """One mesh node of a glTF as a reader sees it: glTF (y-up) coordinates."""

    positions: np.ndarray  # (V, 3) float64
    normals: np.ndarray  # (V, 3) float64
    colors: np.ndarray  # (V, 4) uint8
    faces: np.ndarray  # (F, 3) int64


@pytest.fixture(scope="module")
def source(run_path: Path, drive_path: Path) -> ExportSource:
    return load_export_source(run_path, drive_path)


@pytest.fixture(scope="module")
def exported(
    run_path: Path, drive_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> tuple[TilesSummary, dict]:
    out = tmp_path_factory.mktemp("tiles3d") / "tiles"
    summary = export_run_3dtiles(run_path, out, drive_dir=drive_path)
    return summary, json.loads((out / TILESET_FILE).read_text())


# ----------------------------------------------------------------------------- an independent reader


def _matrix(values: list[float]) -> np.ndarray:
    """A 3D Tiles ``transform`` (16 numbers, column-major) as a (4, 4) matrix."""
    assert len(values) == 16
    return np.asarray(values, np.float64).reshape(4, 4).T


def _box_frame(box: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """A 3D Tiles ``box`` as its centre (3,) and half-axes (3, 3), one per column."""
    assert len(box) == 12
    values = np.asarray(box, np.float64)
    return values[:3], values[3:].reshape(3, 3).T


def _inside(box: list[float], points: np.ndarray, tolerance: float = 1e-6) -> bool:
    centre, axes = _box_frame(box)
    # Coordinates along the half-axes in half-axis lengths (inside: within [-1, 1]), in metres.
    along = np.linalg.solve(axes, (points - centre).T).T
    lengths = np.linalg.norm(axes, axis=0)
    return bool(np.all(np.abs(along) * lengths <= lengths + tolerance))


def _corners(box: list[float]) -> np.ndarray:
    centre, axes = _box_frame(box)
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return centre + signs @ axes.T


def _accessor(gltf: pygltflib.GLTF2, blob: bytes, index: int) -> np.ndarray:
    accessor = gltf.accessors[index]
    view = gltf.bufferViews[accessor.bufferView]
    dtype = np.dtype(COMPONENTS[accessor.componentType])
    width = WIDTH[accessor.type]
    assert view.byteStride in (None, dtype.itemsize * width)
    start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
    data = np.frombuffer(blob, dtype, accessor.count * width, start)
    return data.reshape(accessor.count, width) if width > 1 else data


def _read_glb(path: Path) -> dict[str, Part]:
    """The mesh nodes of a GLB by name (the export writes no node transforms: checked)."""
    gltf = pygltflib.GLTF2().load_binary(str(path))
    assert gltf.asset.version == "2.0"
    blob = gltf.binary_blob()
    parts = {}
    for node in gltf.nodes:
        assert node.matrix is None and node.translation is None
        assert node.rotation is None and node.scale is None
        if node.mesh is None:
            continue
        (primitive,) = gltf.meshes[node.mesh].primitives
        assert primitive.mode == pygltflib.TRIANGLES
        attributes = primitive.attributes
        colors = gltf.accessors[attributes.COLOR_0]
        assert colors.normalized and colors.componentType == pygltflib.UNSIGNED_BYTE
        parts[node.name] = Part(
            positions=_accessor(gltf, blob, attributes.POSITION).astype(np.float64),
            normals=_accessor(gltf, blob, attributes.NORMAL).astype(np.float64),
            colors=_accessor(gltf, blob, attributes.COLOR_0),
            faces=_accessor(gltf, blob, primitive.indices).astype(np.int64).reshape(-1, 3),
        )
    return parts


def _apply(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ matrix[:3, :3].T + matrix[:3, 3]


def _ecef(source: ExportSource, local: np.ndarray) -> np.ndarray:
    """pyproj's ECEF (EPSG:4978) of local vertices: map coordinates = local + origin."""
    xyz = source.to_map(local)
    transformer = Transformer.from_crs(source.crs, "EPSG:4978", always_xy=True)
    return np.column_stack(transformer.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2]))


def _check_tileset(out: Path, tileset: dict, source: ExportSource, summary: TilesSummary) -> None:
    """Every glTF parses; every vertex lands at its ECEF position within 1 cm; every box holds
    its content, the root's every child's box."""
    root = tileset["root"]
    ecef_from_root = _matrix(root["transform"])
    runs = {run.run_id: run for run in source.runs}
    triangles = 0
    for child in root["children"]:
        run = runs[child["metadata"]["properties"]["run_id"]]
        root_from_tile = _matrix(child["transform"]) if "transform" in child else np.eye(4)
        tile_from_gltf = Y_UP_TO_Z_UP  # 3D Tiles 1.1: glTF content is y-up
        ecef_from_gltf = ecef_from_root @ root_from_tile @ tile_from_gltf
        meshes = {name: mesh for name, mesh in source.parts(run).items() if len(mesh.faces)}
        parts = _read_glb(out / child["content"]["uri"])
        assert set(parts) == set(meshes)
        for name, part in parts.items():
            mesh = meshes[name]
            np.testing.assert_array_equal(part.faces, mesh.faces)
            triangles += len(part.faces)
            error = np.linalg.norm(
                _apply(ecef_from_gltf, part.positions) - _ecef(source, mesh.vertices), axis=1
            )
            assert error.max() < CM, f"run {run.run_id} {name}: {error.max():.4f} m off"
            assert np.allclose(np.linalg.norm(part.normals, axis=1), 1, atol=1e-4)
            tile_points = _apply(tile_from_gltf, part.positions)
            assert _inside(child["boundingVolume"]["box"], tile_points)
        corners = _corners(child["boundingVolume"]["box"])
        assert _inside(root["boundingVolume"]["box"], _apply(root_from_tile, corners))
    assert triangles == summary.triangles


# --------------------------------------------------------------------------------- the tileset


def test_a_3d_tiles_1_1_tileset_with_a_tile_per_run(
    exported: tuple[TilesSummary, dict], source: ExportSource
) -> None:
    summary, tileset = exported
    assert tileset["asset"]["version"] == "1.1"
    assert tileset["asset"]["extras"]["crs"] == source.crs == summary.crs == "EPSG:6677"
    root = tileset["root"]
    assert root["refine"] == "ADD" and "content" not in root
    children = root["children"]
    assert len(children) == summary.tiles == len(source.runs) == 2
    assert summary.empty_runs == ()
    files = sorted(p.name for p in summary.out.iterdir())
    assert files == sorted([TILESET_FILE, *(c["content"]["uri"] for c in children)])
    assert all(c["content"]["uri"].endswith(".glb") for c in children)
    # A tile's error never exceeds its parent's; the leaves are the full meshes.
    assert tileset["geometricError"] >= root["geometricError"] > 0
    assert all(c["geometricError"] == 0 for c in children)
    assert not list(summary.out.parent.glob(".*"))  # no staging folder left behind


def test_every_gltf_parses_and_every_vertex_lands_at_its_ecef_position(
    exported: tuple[TilesSummary, dict], source: ExportSource
) -> None:
    summary, tileset = exported
    _check_tileset(summary.out, tileset, source, summary)


def test_the_root_frame_is_east_north_up_at_the_drive_origin(
    exported: tuple[TilesSummary, dict], source: ExportSource
) -> None:
    _, tileset = exported
    matrix = _matrix(tileset["root"]["transform"])
    to_ecef = Transformer.from_crs(source.crs, "EPSG:4978", always_xy=True)
    np.testing.assert_allclose(matrix[:3, 3], to_ecef.transform(*source.origin), atol=1e-3)
    to_geodetic = Transformer.from_crs(source.crs, "EPSG:4979", always_xy=True)
    lon, lat, _ = np.radians(to_geodetic.transform(*source.origin))
    up = [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]
    east = [-np.sin(lon), np.cos(lon), 0.0]
    np.testing.assert_allclose(matrix[:3, 2], up, atol=1e-9)
    np.testing.assert_allclose(matrix[:3, 0], east, atol=1e-9)
    np.testing.assert_allclose(matrix[:3, 1], np.cross(up, east), atol=1e-9)
    np.testing.assert_array_equal(matrix[3], [0, 0, 0, 1])


def test_run_metadata_follows_the_schema(
    exported: tuple[TilesSummary, dict], source: ExportSource
) -> None:
    _, tileset = exported
    schema = tileset["schema"]
    assert schema["id"] == "guardrail"
    definitions = schema["classes"]["guardrail"]["properties"]
    assert set(definitions) == {"run_id", "type", "signature", "height", "pole_count", "length"}
    rows = {row.run_id: row for row in source.rows}
    for child in tileset["root"]["children"]:
        metadata = child["metadata"]
        assert metadata["class"] == "guardrail"
        values = metadata["properties"]
        for name, definition in definitions.items():
            if definition.get("required"):
                assert name in values
            if name not in values:
                continue
            value = values[name]
            if definition["type"] == "STRING":
                assert isinstance(value, str)
            elif definition["componentType"] == "INT32":
                assert isinstance(value, int) and -(2**31) <= value < 2**31
            else:
                assert definition["componentType"] == "FLOAT64" and isinstance(value, float)
        row = rows[values["run_id"]]
        assert values == {
            "run_id": row.run_id,
            "type": row.type,
            "signature": row.signature,
            "height": row.height_m,
            "pole_count": row.pole_count,
            "length": row.length_m,
        }


def test_colours_are_linear_as_gltf_wants(
    exported: tuple[TilesSummary, dict], source: ExportSource
) -> None:
    summary, tileset = exported
    for child in tileset["root"]["children"]:
        for name, part in _read_glb(summary.out / child["content"]["uri"]).items():
            srgb = np.asarray(
                source.sweep.pole_color if name == "poles" else source.sweep.rail_color
            )
            c = srgb[:3] / 255
            linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4) * 255
            assert np.abs(part.colors[:, :3] - linear).max() <= 0.5 + 1e-9
            assert np.all(part.colors[:, 3] == srgb[3])


def test_format_tiles_summary(exported: tuple[TilesSummary, dict]) -> None:
    summary, _ = exported
    text = format_tiles_summary(summary)
    assert f"2 run tiles ({summary.triangles:,} triangles)" in text
    assert "EPSG:6677" in text and str(summary.out / TILESET_FILE) in text


def test_the_tileset_follows_the_official_schema(exported: tuple[TilesSummary, dict]) -> None:
    _, tileset = exported
    assert schema_errors(tileset, "3d-tiles-1.1/tileset.schema.json") == []
    broken = json.loads(json.dumps(tileset))
    broken["root"]["geometricError"] = -1  # the check can fail
    assert schema_errors(broken, "3d-tiles-1.1/tileset.schema.json") != []


# ------------------------------------------------------------------ far runs and empty runs


def _edited_run(run_path: Path, folder: Path, edit) -> Path:
    """A copy of the run's ``run.json`` and reconstruction (all the export reads of a run
    folder), its ``models.json`` changed by ``edit(document)``."""
    original = RunFolder(run_path)
    copy = RunFolder(folder)
    copy.reconstruction.models_file.parent.mkdir(parents=True)
    shutil.copy(original.run_file, copy.run_file)
    document = json.loads(original.reconstruction.models_file.read_text())
    edit(document)
    copy.reconstruction.models_file.write_text(json.dumps(document))
    return folder


def _shift(run: dict, offset: list[float]) -> None:
    for pole in run["poles"]:
        pole["position"] = list(np.add(pole["position"], offset))
    for unit in run["units"]:
        unit["origin"] = list(np.add(unit["origin"], offset))


EMPTY_RUN = {"run_id": 7, "n_points": 0, "notes": [], "poles": [], "units": [], "registered": []}


def test_a_run_5_km_away_is_placed_to_the_centimetre_and_an_empty_run_is_left_out(
    run_path: Path, drive_path: Path, tmp_path: Path
) -> None:
    def edit(document: dict) -> None:
        _shift(document["runs"][0], [3000.0, 4000.0, 0.0])  # 5 km: the Earth drops 2 m
        document["runs"].append({**EMPTY_RUN, "model": None})

    run = _edited_run(run_path, tmp_path / "run", edit)
    summary = export_run_3dtiles(run, tmp_path / "tiles", drive_dir=drive_path)
    assert summary.tiles == 2 and summary.empty_runs == (7,)
    assert "left out without geometry: run 7" in format_tiles_summary(summary)
    tileset = json.loads((summary.out / TILESET_FILE).read_text())
    _check_tileset(summary.out, tileset, load_export_source(run, drive_path), summary)


def test_no_run_with_geometry_is_an_error(run_path: Path, drive_path: Path, tmp_path: Path) -> None:
    def edit(document: dict) -> None:
        document["runs"] = [{**EMPTY_RUN, "model": None}]

    run = _edited_run(run_path, tmp_path / "run", edit)
    with pytest.raises(ExportError, match="no reconstructed run has geometry"):
        export_run_3dtiles(run, tmp_path / "tiles", drive_dir=drive_path)
    assert not (tmp_path / "tiles").exists()


# ------------------------------------------------------------------------------ the output


def test_an_existing_output_is_kept_without_overwrite(
    run_path: Path, drive_path: Path, tmp_path: Path
) -> None:
    out = tmp_path / "tiles"
    out.mkdir()
    (out / "mine.txt").write_text("keep me")
    with pytest.raises(OutputExistsError, match="--overwrite"):
        export_run_3dtiles(run_path, out, drive_dir=drive_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiles"]  # no staging folder left
    assert [p.name for p in out.iterdir()] == ["mine.txt"]
    assert (out / "mine.txt").read_text() == "keep me"

    export_run_3dtiles(run_path, out, drive_dir=drive_path, overwrite=True)
    assert (out / TILESET_FILE).is_file() and not (out / "mine.txt").exists()


def test_an_output_holding_an_input_is_refused_even_with_overwrite(
    run_path: Path, drive_path: Path
) -> None:
    models = RunFolder(run_path).reconstruction.models_file
    before = models.read_bytes()
    with pytest.raises(InputInsideOutputError):
        export_run_3dtiles(run_path, models.parent, drive_dir=drive_path, overwrite=True)
    assert models.read_bytes() == before
