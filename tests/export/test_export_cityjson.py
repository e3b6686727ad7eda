"""``export_run_cityjson``: a run's guardrails as CityJSON 2.0, one CityFurniture per run.

The file must validate against the official CityJSON 2.0.2 schema (``tests/data/schemas``) and
cjio (``cjio FILE info``) must read it. cjio's ``validate`` cannot serve: it needs cjvalpy,
which has no Linux wheel for Python 3.11, and cjio 0.10.1 hands cjvalpy an empty document
instead of the file. So :func:`_check_cjval_rules` checks what cjval checks beyond the schema
(vertex indices, unused and duplicate vertices) and what a valid surface and line need.
"""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh

from guardrail_core.errors import ExportError, OutputExistsError
from guardrail_core.export import cityjson
from guardrail_core.export.cityjson import (
    CityJsonSummary,
    export_run_cityjson,
    format_cityjson_summary,
    ogc_crs_url,
)
from guardrail_core.export.run_export import ExportSource, load_export_source
from guardrail_core.reconstruct.inventory import inventory_rows
from tests.file_tree import file_tree
from tests.json_schemas import schema_errors

CJIO = Path(sys.executable).parent / "cjio"
SCHEMA = "cityjson-2.0.2/cityjson.min.schema.json"


@pytest.fixture(scope="module")
def source(run_path: Path, drive_path: Path) -> ExportSource:
    return load_export_source(run_path, drive_path)


@pytest.fixture(scope="module")
def exported(
    run_path: Path, drive_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> tuple[CityJsonSummary, dict[str, Any]]:
    out = tmp_path_factory.mktemp("cityjson") / "guardrails.city.json"
    summary = export_run_cityjson(run_path, out, drive_dir=drive_path)
    return summary, json.loads(out.read_text())


def _decoded(document: dict[str, Any]) -> np.ndarray:
    """(V, 3) float64 map coordinates of the document's vertices."""
    transform = document["transform"]
    return np.asarray(document["vertices"], np.int64) * np.asarray(transform["scale"]) + np.asarray(
        transform["translate"]
    )


def _geometry(city_object: dict[str, Any], lod: str) -> dict[str, Any]:
    (geometry,) = [g for g in city_object["geometry"] if g["lod"] == lod]
    return geometry


def _check_cjval_rules(document: dict[str, Any]) -> None:
    """What cjval checks besides the schema, and what valid surfaces and lines need."""
    assert document["type"] == "CityJSON" and document["version"] == "2.0"
    vertices = np.asarray(document["vertices"])
    assert vertices.dtype == np.int64 and vertices.shape[1:] == (3,)
    assert len(np.unique(vertices, axis=0)) == len(vertices)  # no duplicate vertices
    used = np.zeros(len(vertices), bool)
    for city_object in document["CityObjects"].values():
        assert city_object["type"] == "CityFurniture"
        assert city_object["geometry"]
        for geometry in city_object["geometry"]:
            assert set(geometry) == {"type", "lod", "boundaries"}
            if geometry["type"] == "MultiSurface":
                rings = [ring for surface in geometry["boundaries"] for ring in surface]
                assert all(len(surface) == 1 for surface in geometry["boundaries"])
                triangles = vertices[np.asarray(rings)]  # (T, 3, 3)
                area = np.cross(
                    triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
                )
                assert area.any(axis=1).all()  # three distinct, not collinear corners
                used[np.asarray(rings)] = True
            else:
                assert geometry["type"] == "MultiLineString"
                for line in geometry["boundaries"]:
                    points = vertices[np.asarray(line)]
                    assert len(line) >= 2 and np.diff(points, axis=0).any(axis=1).all()
                    used[line] = True
    assert used.all()  # every index is in range (else indexing raised) and every vertex used


# ------------------------------------------------------------------------- the exported file


def test_cjio_reads_it(exported: tuple[CityJsonSummary, dict[str, Any]], drive_path: Path) -> None:
    summary, _ = exported
    epsg = json.loads((drive_path / "drive.json").read_text())["crs"].split(":")[1]
    result = subprocess.run(
        [str(CJIO), str(summary.out), "info", "--long"], capture_output=True, text=True, check=False
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert "CityJSON version = 2.0" in lines
    assert f"EPSG = {epsg}" in lines
    assert f"|-- CityFurniture ({summary.objects})" in lines
    assert f"vertices_total = {summary.vertices}" in lines
    assert "LoD = ['1', '2']" in lines


def test_it_follows_the_official_schema(
    exported: tuple[CityJsonSummary, dict[str, Any]],
) -> None:
    _, document = exported
    assert schema_errors(document, SCHEMA) == []
    broken = json.loads(json.dumps(document))
    broken["CityObjects"]["guardrail-run-000"]["type"] = "Guardrail"  # the check can fail
    assert schema_errors(broken, SCHEMA) != []


def test_it_follows_the_cjval_rules(exported: tuple[CityJsonSummary, dict[str, Any]]) -> None:
    _, document = exported
    _check_cjval_rules(document)


def test_one_cityfurniture_per_run_with_a_model_or_poles(
    exported: tuple[CityJsonSummary, dict[str, Any]], source: ExportSource
) -> None:
    summary, document = exported
    drawn = [r for r in source.runs if r.model is not None or r.poles]
    assert len(drawn) == len(source.runs) == 2  # the beam and the pipe guardrail
    assert set(document["CityObjects"]) == {f"guardrail-run-{r.run_id:03d}" for r in drawn}
    assert summary.objects == summary.lod2_objects == 2
    assert summary.lod1_only_objects == summary.skipped_runs == summary.degenerate_triangles == 0
    assert summary.vertices == len(document["vertices"])
    assert summary.crs == source.crs


def test_lod2_surfaces_are_the_meshes_within_half_a_millimetre(
    exported: tuple[CityJsonSummary, dict[str, Any]], source: ExportSource
) -> None:
    _, document = exported
    vertices = _decoded(document)
    for run in source.runs:
        geometry = _geometry(document["CityObjects"][f"guardrail-run-{run.run_id:03d}"], "2")
        assert geometry["type"] == "MultiSurface"
        rings = np.array([surface[0] for surface in geometry["boundaries"]])  # (T, 3)
        parts = source.parts(run)
        assert list(parts)[-1] == "poles" and len(parts) == 2  # rails first, then the poles
        expected = np.concatenate(
            [np.asarray(m.vertices)[np.asarray(m.faces)] for m in parts.values()]
        )
        assert rings.shape == expected.shape[:2]  # every triangle, in order
        # 1 mm integers: within half of it per axis (< 1 mm apart).
        assert np.abs(vertices[rings] - source.to_map(expected)).max() <= 0.0005 + 1e-9


def test_lod1_lines_are_the_poles(
    exported: tuple[CityJsonSummary, dict[str, Any]], source: ExportSource
) -> None:
    _, document = exported
    vertices = _decoded(document)
    for run in source.runs:
        geometry = _geometry(document["CityObjects"][f"guardrail-run-{run.run_id:03d}"], "1")
        assert geometry["type"] == "MultiLineString"
        ground = source.to_map(np.array([p.position for p in run.poles]))
        top = ground + np.array([[0.0, 0.0, p.height] for p in run.poles])
        line, *axes = [vertices[np.asarray(b)] for b in geometry["boundaries"]]
        assert np.abs(line - ground).max() <= 0.0005 + 1e-9
        assert np.abs(np.stack(axes) - np.stack([ground, top], axis=1)).max() <= 0.0005 + 1e-9


def test_attributes_are_the_inventory_rows(
    exported: tuple[CityJsonSummary, dict[str, Any]], source: ExportSource, drive_path: Path
) -> None:
    _, document = exported
    for row in source.rows:
        expected = {
            "function": "guardrail",
            "status": row.status,
            "guardrail_type": row.type,
            "signature": row.signature,
            "height_m": row.height_m,
            "rail_top_m": row.rail_top_m,
            "pole_count": row.pole_count,
            "pole_spacing_m": row.pole_spacing_m,
            "length_m": row.length_m,
            "run_id": row.run_id,
            "source_drive": drive_path.name,
        }
        assert None not in expected.values()  # a reconstructed run has them all
        attributes = document["CityObjects"][f"guardrail-run-{row.run_id:03d}"]["attributes"]
        assert attributes == expected
    assert {r.type for r in source.rows} == {"beam", "pipe"}


def test_the_reference_system_transform_and_extent(
    exported: tuple[CityJsonSummary, dict[str, Any]], drive_path: Path, source: ExportSource
) -> None:
    _, document = exported
    meta = json.loads((drive_path / "drive.json").read_text())
    epsg = meta["crs"].removeprefix("EPSG:")
    assert document["metadata"]["referenceSystem"] == (
        f"https://www.opengis.net/def/crs/EPSG/0/{epsg}"
    )
    assert document["transform"] == {"scale": [0.001] * 3, "translate": meta["origin"]}
    vertices = np.asarray(document["vertices"])
    assert np.abs(vertices).max() < 100_000  # small integers: within 100 m of the origin
    decoded = _decoded(document)
    np.testing.assert_allclose(
        document["metadata"]["geographicalExtent"],
        [*decoded.min(axis=0), *decoded.max(axis=0)],
        rtol=0,
        atol=1e-9,
    )


def test_the_summary_line(exported: tuple[CityJsonSummary, dict[str, Any]]) -> None:
    summary, _ = exported
    text = format_cityjson_summary(summary)
    assert text.startswith("2 CityFurniture objects (2 with LOD2 surfaces, 0 with LOD1 lines")
    assert f"{summary.vertices:,} vertices" in text and "CRS EPSG:6677" in text
    assert "left out" not in text and "skipped" not in text
    assert text.endswith(f"wrote {summary.out}")


# ------------------------------------------------------------------- what the runs may lack


def test_poles_only_runs_get_lines_and_empty_runs_are_skipped(
    run_path: Path, drive_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def stripped(run_dir: Path, drive_dir: Path) -> ExportSource:
        source = load_export_source(run_dir, drive_dir)
        beam, pipe = source.runs
        runs = (
            dataclasses.replace(beam, model=None),  # poles only
            dataclasses.replace(pipe, model=None, poles=[]),  # nothing to draw
        )
        rows = inventory_rows(runs, source.origin)
        return dataclasses.replace(source, runs=runs, rows=rows)

    monkeypatch.setattr(cityjson, "load_export_source", stripped)
    out = tmp_path / "poles.city.json"
    summary = export_run_cityjson(run_path, out, drive_dir=drive_path)
    assert (summary.objects, summary.lod2_objects, summary.lod1_only_objects) == (1, 0, 1)
    assert summary.skipped_runs == 1
    assert "runs skipped (no model, no poles): 1" in format_cityjson_summary(summary)
    document = json.loads(out.read_text())
    _check_cjval_rules(document)
    (only,) = document["CityObjects"].values()
    assert [g["lod"] for g in only["geometry"]] == ["1"]
    assert only["attributes"]["status"] == "poles only"
    assert "signature" not in only["attributes"]  # None in the row: left out, not null


def test_collinear_triangles_are_left_out(
    run_path: Path, drive_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Corners 0.4 mm off a straight line are on it at 1 mm: no area, no valid polygon.
    sliver = trimesh.Trimesh(
        [[0.0, 0.0, 1.0], [0.010, 0.0, 1.0], [0.020, 0.0004, 1.0], [0.0, 0.01, 1.0]],
        [[0, 1, 2], [0, 1, 3]],
        process=False,
    )
    parts = ExportSource.parts
    monkeypatch.setattr(ExportSource, "parts", lambda self, run: {**parts(self, run), "x": sliver})
    out = tmp_path / "slivers.city.json"
    summary = export_run_cityjson(run_path, out, drive_dir=drive_path)
    assert summary.degenerate_triangles == 2  # one per run
    assert "triangles left out (collinear at 1 mm): 2" in format_cityjson_summary(summary)
    _check_cjval_rules(json.loads(out.read_text()))


# ------------------------------------------------------------------------------ refusals


@pytest.mark.parametrize(
    ("crs", "url"),
    [
        ("EPSG:6677", "https://www.opengis.net/def/crs/EPSG/0/6677"),
        ("epsg:4326", "https://www.opengis.net/def/crs/EPSG/0/4326"),
    ],
)
def test_an_epsg_code_as_an_ogc_url(crs: str, url: str) -> None:
    assert ogc_crs_url(crs) == url


@pytest.mark.parametrize(
    "crs",
    ["EPSG:6677+6695", "unknown", 'PROJCS["JGD2011 / Japan Plane Rectangular CS IX"]', "EPSG:"],
)
def test_a_crs_other_than_an_epsg_code_is_refused(crs: str) -> None:
    with pytest.raises(ExportError, match=re.escape(repr(crs))):
        ogc_crs_url(crs)


def test_a_drive_without_an_epsg_crs_writes_nothing(
    run_path: Path, drive_path: Path, tmp_path: Path
) -> None:
    drive = tmp_path / "drive"
    shutil.copytree(drive_path, drive)
    meta = json.loads((drive / "drive.json").read_text())
    meta["crs"] = "EPSG:6677+6695"
    (drive / "drive.json").write_text(json.dumps(meta))
    out = tmp_path / "out" / "guardrails.city.json"
    with pytest.raises(ExportError, match=r"'EPSG:6677\+6695'"):
        export_run_cityjson(run_path, out, drive_dir=drive)
    assert not out.parent.exists()


def test_an_existing_output_is_kept_without_overwrite(
    run_path: Path, drive_path: Path, tmp_path: Path
) -> None:
    out = tmp_path / "guardrails.city.json"
    out.write_text("old")
    with pytest.raises(OutputExistsError):
        export_run_cityjson(run_path, out, drive_dir=drive_path)
    assert file_tree(tmp_path) == {"guardrails.city.json": b"old"}
    export_run_cityjson(run_path, out, drive_dir=drive_path, overwrite=True)
    assert list(file_tree(tmp_path)) == ["guardrails.city.json"]
    assert json.loads(out.read_text())["type"] == "CityJSON"


def test_the_output_must_be_json(run_path: Path, drive_path: Path, tmp_path: Path) -> None:
    with pytest.raises(ExportError, match=r"\.json"):
        export_run_cityjson(run_path, tmp_path / "guardrails.las", drive_dir=drive_path)
    assert not list(tmp_path.iterdir())
