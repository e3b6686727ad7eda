"""The inventory rows, their GeoJSON (map coordinates, CRS named) and CSV."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from guardrail_core.errors import InvalidOptionError
from guardrail_core.reconstruct.inventory import (
    ROW_KEYS,
    inventory_rows,
    write_inventory_csv,
    write_inventory_geojson,
)
from guardrail_core.reconstruct.model import Pipe, Pole, RunModel, UnitModel
from guardrail_core.reconstruct.unit_frame import UnitFrame

ORIGIN = np.array([-35123.4567, 120456.789, 42.125])
CRS = "EPSG:6677"


def _run(run_id, positions, model, notes=(), height=1.0) -> RunModel:
    positions = np.asarray(positions, np.float64).reshape(-1, 3)
    poles = [Pole(p, 0.03, height, 20) for p in positions]
    units = [UnitFrame.between(a, b) for a, b in zip(positions[:-1], positions[1:], strict=True)]
    registered = np.arange(len(units)) % 2 == 0
    return RunModel(run_id, poles, units, model, registered, 500, list(notes))


def _runs() -> list[RunModel]:
    line = np.c_[[0.0, 2.0, 4.1, 6.0], [0.0, 0.0, 0.1, 0.3], [1.0, 1.1, 1.2, 1.2]]
    pipes = (
        Pipe(np.array([[0.0, 0.95, 0.0], [2.0, 0.95, 0.0]]), 0.0243, "horizontal", 80),
        Pipe(np.array([[0.0, 0.62, 0.0], [2.0, 0.62, 0.0]]), 0.017, "horizontal", 60),
        Pipe(np.array([[1.0, 0.1, 0.0], [1.0, 0.9, 0.0]]), 0.017, "vertical", 30),
    )
    pipe_model = UnitModel("pipe", 2.0, pipes, n_units=3, notes=("pipe 4 too short",))
    y = np.linspace(0.35, 0.70, 9)
    beam_model = UnitModel("beam", 2.0, section=np.c_[0.05 * np.sin(np.pi * (y - 0.35) / 0.35), y])
    return [
        _run(1, line, pipe_model, notes=["one unit not registered"], height=1.1),
        _run(2, line[:3] + [0.0, 10.0, 0.0], beam_model, height=0.8),
        _run(3, line[:2] + [0.0, 20.0, 0.0], None, notes=["one unit only"]),
        _run(4, np.zeros((0, 3)), None, notes=["no poles found"]),
    ]


def test_rows_summarise_each_run():
    runs = _runs()
    rows = inventory_rows(runs, ORIGIN)
    assert [r["run_id"] for r in rows] == [1, 2, 3, 4]
    assert all(tuple(r) == ROW_KEYS for r in rows)
    assert [r["status"] for r in rows] == [
        "reconstructed",
        "reconstructed",
        "poles only",
        "not reconstructed",
    ]
    assert [r["type"] for r in rows] == ["pipe", "beam", "unknown", "unknown"]
    pipe, beam, poles_only, none = rows
    assert pipe["signature"] == (
        "3 pipes: horizontal r24.3 y0.95, vertical r17 y0.10-0.90, horizontal r17 y0.62"
    )
    assert [p["kind"] for p in pipe["design"]] == ["horizontal", "vertical", "horizontal"]
    assert pipe["design"][1]["y_min_m"] == pytest.approx(0.1)
    positions = np.array([p.position for p in runs[0].poles])
    spacing = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    assert pipe["length_m"] == pytest.approx(spacing.sum(), abs=1e-3)
    assert pipe["pole_spacing_m"] == pytest.approx(np.median(spacing), abs=1e-3)
    assert pipe["pole_spacing_min_m"] <= pipe["pole_spacing_m"] <= pipe["pole_spacing_max_m"]
    assert pipe["height_m"] == pytest.approx(1.1)  # the poles top the rails (0.95 + 0.024)
    assert pipe["rail_top_m"] == pytest.approx(0.974)
    start = [pipe["start_x"], pipe["start_y"], pipe["start_z"]]
    end = [pipe["end_x"], pipe["end_y"], pipe["end_z"]]
    np.testing.assert_allclose(start, positions[0] + ORIGIN, rtol=0, atol=1e-9)
    np.testing.assert_allclose(end, positions[-1] + ORIGIN, rtol=0, atol=1e-9)
    assert (pipe["pole_count"], pipe["units"], pipe["units_registered"]) == (4, 3, 2)
    assert pipe["poles_seen"] == 4
    assert pipe["notes"] == "one unit not registered; pipe 4 too short"
    assert beam["design"]["height_m"] == pytest.approx(0.35)
    assert beam["design"]["depth_m"] == pytest.approx(0.05, abs=1e-3)
    assert len(beam["design"]["section"]) == 9
    assert beam["signature"].startswith("beam h0.35")
    assert poles_only["length_m"] == pytest.approx(np.hypot(2.0, 0.1), abs=1e-3)  # 3-D
    assert none["notes"] == "no poles found"
    assert none["length_m"] is None and none["start_x"] is None and none["pole_count"] == 0
    json.dumps(rows, allow_nan=False)  # plain JSON


def test_geojson_has_one_feature_per_run_in_map_coordinates(tmp_path):
    runs = _runs()
    rows = inventory_rows(runs, ORIGIN)
    path = tmp_path / "inventory.geojson"
    write_inventory_geojson(path, rows, runs, ORIGIN, CRS)
    doc = json.loads(path.read_text())
    assert doc["type"] == "FeatureCollection"
    assert doc["crs"] == {"type": "name", "properties": {"name": CRS}}
    assert len(doc["features"]) == len(runs)
    for feature, run, row in zip(doc["features"], runs, rows, strict=True):
        assert feature["properties"] == row
        local = np.array([p.position for p in run.poles]).reshape(-1, 3)
        geometry = feature["geometry"]
        if len(local) >= 2:
            assert geometry["type"] == "LineString"
            np.testing.assert_allclose(geometry["coordinates"], local + ORIGIN, rtol=0, atol=1e-6)
        elif len(local) == 1:
            assert geometry["type"] == "Point"
        else:
            assert geometry is None


def test_csv_has_a_header_and_a_line_per_run(tmp_path):
    runs = _runs()
    rows = inventory_rows(runs, ORIGIN)
    path = tmp_path / "inventory.csv"
    write_inventory_csv(path, rows)
    with path.open(newline="") as f:
        table = list(csv.reader(f))
    assert tuple(table[0]) == ROW_KEYS
    assert len(table) == 1 + len(runs)
    parsed = [dict(zip(table[0], line, strict=True)) for line in table[1:]]
    assert float(parsed[0]["start_x"]) == pytest.approx(rows[0]["start_x"], abs=1e-6)
    assert json.loads(parsed[0]["design"]) == rows[0]["design"]
    assert parsed[3]["status"] == "not reconstructed" and parsed[3]["start_x"] == ""
    write_inventory_csv(tmp_path / "empty.csv", [])
    assert (tmp_path / "empty.csv").read_text().strip() == ",".join(ROW_KEYS)


def test_bad_inputs_raise(tmp_path):
    runs = _runs()
    rows = inventory_rows(runs, ORIGIN)
    with pytest.raises(InvalidOptionError):
        inventory_rows(runs, np.array([1.0, 2.0]))
    with pytest.raises(InvalidOptionError):
        inventory_rows(runs, np.array([1.0, np.nan, 0.0]))
    with pytest.raises(InvalidOptionError):
        write_inventory_geojson(tmp_path / "x.geojson", rows[:2], runs, ORIGIN, CRS)
    with pytest.raises(InvalidOptionError):
        write_inventory_geojson(tmp_path / "x.geojson", rows[::-1], runs, ORIGIN, CRS)
    with pytest.raises(InvalidOptionError):
        write_inventory_geojson(tmp_path / "x.geojson", rows, runs, ORIGIN, "")
