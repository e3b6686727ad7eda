"""The inventory rows (:class:`InventoryRow`), their GeoJSON (map coordinates, CRS named) and CSV,
and reading both back."""

from __future__ import annotations

import csv
import dataclasses
import json
import re

import numpy as np
import pytest

from guardrail_core.errors import InvalidOptionError, RunFolderError
from guardrail_core.reconstruct.inventory import (
    ROW_KEYS,
    inventory_rows,
    read_inventory_csv,
    read_inventory_geojson,
    write_inventory_csv,
    write_inventory_geojson,
)
from guardrail_core.reconstruct.inventory_row import InventoryRow
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
    assert [r.run_id for r in rows] == [1, 2, 3, 4]
    assert all(tuple(r.to_record()) == ROW_KEYS for r in rows)
    assert [r.status for r in rows] == [
        "reconstructed",
        "reconstructed",
        "poles only",
        "not reconstructed",
    ]
    assert [r.type for r in rows] == ["pipe", "beam", "unknown", "unknown"]
    pipe, beam, poles_only, none = rows
    assert pipe.signature == (
        "3 pipes: horizontal r24.3 y0.95, vertical r17 y0.10-0.90, horizontal r17 y0.62"
    )
    assert [p["kind"] for p in pipe.design] == ["horizontal", "vertical", "horizontal"]
    assert pipe.design[1]["y_min_m"] == pytest.approx(0.1)
    positions = np.array([p.position for p in runs[0].poles])
    spacing = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    assert pipe.length_m == pytest.approx(spacing.sum(), abs=1e-3)
    assert pipe.pole_spacing_m == pytest.approx(np.median(spacing), abs=1e-3)
    assert pipe.pole_spacing_min_m <= pipe.pole_spacing_m <= pipe.pole_spacing_max_m
    assert pipe.height_m == pytest.approx(1.1)  # the poles top the rails (0.95 + 0.024)
    assert pipe.rail_top_m == pytest.approx(0.974)
    start = [pipe.start_x, pipe.start_y, pipe.start_z]
    end = [pipe.end_x, pipe.end_y, pipe.end_z]
    np.testing.assert_allclose(start, positions[0] + ORIGIN, rtol=0, atol=1e-9)
    np.testing.assert_allclose(end, positions[-1] + ORIGIN, rtol=0, atol=1e-9)
    assert (pipe.pole_count, pipe.units, pipe.units_registered) == (4, 3, 2)
    assert pipe.poles_seen == 4
    assert pipe.notes == "one unit not registered; pipe 4 too short"
    assert beam.design["height_m"] == pytest.approx(0.35)
    assert beam.design["depth_m"] == pytest.approx(0.05, abs=1e-3)
    assert len(beam.design["section"]) == 9
    assert beam.signature.startswith("beam h0.35")
    assert poles_only.length_m == pytest.approx(np.hypot(2.0, 0.1), abs=1e-3)  # 3-D
    assert none.notes == "no poles found"
    assert none.length_m is None and none.start_x is None and none.pole_count == 0
    json.dumps([r.to_record() for r in rows], allow_nan=False)  # plain JSON


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
        assert feature["properties"] == row.to_record()
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
    assert float(parsed[0]["start_x"]) == rows[0].start_x  # full float64 precision
    assert json.loads(parsed[0]["design"]) == rows[0].design
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


# ------------------------------------------------------------------- InventoryRow and its records

#: The run-folder format: the CSV's columns and the GeoJSON's properties, in this order.
FORMAT_KEYS = (
    "run_id", "status", "type", "signature", "design", "length_m", "height_m", "rail_top_m",
    "pole_count", "poles_seen", "pole_radius_m", "pole_spacing_m", "pole_spacing_min_m",
    "pole_spacing_max_m", "start_x", "start_y", "start_z", "end_x", "end_y", "end_z",
    "units", "units_registered", "units_superimposed", "n_points", "notes",
)  # fmt: skip
#: Lines 3-5 of ``inventory.csv`` for :func:`_runs`, as written before rows were InventoryRow.
CSV_LINES = (
    '2,reconstructed,beam,beam h0.35 d0.050 y0.35-0.70,"{""height_m"":0.35,""depth_m"":0.05,'
    '""y_min_m"":0.35,""y_max_m"":0.7,""section"":[[0.0,0.35],[0.0191,0.3937],[0.0354,0.4375],'
    '[0.0462,0.4812],[0.05,0.525],[0.0462,0.5687],[0.0354,0.6125],[0.0191,0.6562],[0.0,0.7]]}",'
    "4.107,0.8,0.7,3,3,0.03,2.054,2.002,2.105,-35123.4567,120466.789,43.125,"
    "-35119.356700000004,120466.88900000001,43.325,2,1,0,500,",
    "3,poles only,unknown,,,2.002,1.0,,2,2,0.03,2.002,2.002,2.002,-35123.4567,120476.789,43.125,"
    "-35121.4567,120476.789,43.225,1,1,0,500,one unit only",
    "4,not reconstructed,unknown,,,,,,0,0,,,,,,,,,,,0,0,0,500,no poles found",
)


def test_the_row_keys_are_the_run_folder_format():
    assert ROW_KEYS == FORMAT_KEYS
    assert [f.name for f in dataclasses.fields(InventoryRow)] == list(FORMAT_KEYS)


def test_the_csv_is_written_as_before(tmp_path):
    path = tmp_path / "inventory.csv"
    write_inventory_csv(path, inventory_rows(_runs(), ORIGIN))
    lines = path.read_text().split("\n")
    assert lines[0] == ",".join(FORMAT_KEYS)
    assert tuple(lines[2:5]) == CSV_LINES and lines[5:] == [""]


def test_a_row_round_trips_through_its_records():
    for row in inventory_rows(_runs(), ORIGIN):
        record = row.to_record()
        assert InventoryRow.from_record(record) == row
        assert InventoryRow.from_record(json.loads(json.dumps(record))) == row
        cells = dict(zip(ROW_KEYS, row.to_csv_cells(), strict=True))
        assert InventoryRow.from_csv_record(cells) == row
        record["notes"] += "!"  # the record is a copy: the frozen row does not change
        if isinstance(record["design"], dict):
            record["design"]["height_m"] = -1.0
        assert InventoryRow.from_record(row.to_record()) == row


def test_the_written_files_read_back_as_the_rows(tmp_path):
    runs = _runs()
    rows = inventory_rows(runs, ORIGIN)
    write_inventory_csv(tmp_path / "inventory.csv", rows)
    write_inventory_geojson(tmp_path / "inventory.geojson", rows, runs, ORIGIN, CRS)
    assert read_inventory_csv(tmp_path / "inventory.csv") == rows
    assert read_inventory_geojson(tmp_path / "inventory.geojson") == rows
    write_inventory_csv(tmp_path / "empty.csv", [])
    assert read_inventory_csv(tmp_path / "empty.csv") == []


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("pole_count", None, "'pole_count' is None: expected an integer"),
        ("run_id", True, "'run_id' is True: expected an integer"),
        ("run_id", 1.0, "'run_id' is 1.0: expected an integer"),
        ("length_m", "4.1", "'length_m' is '4.1': expected a finite number or null"),
        ("height_m", float("nan"), "'height_m' is nan: expected a finite number or null"),
        ("start_x", 10**400, "'start_x' is"),
        ("notes", None, "'notes' is None: expected a string"),
        ("signature", 3, "'signature' is 3: expected a string"),
        ("design", [1, 2], "'design' is [1, 2]: expected a list of pipe objects"),
        ("design", "{}", "'design' is '{}': expected a list of pipe objects"),
        ("status", "done", "'status' is 'done', expected one of ("),
        ("type", "fence", "'type' is 'fence', expected one of ("),
    ],
)
def test_a_malformed_record_raises_a_run_folder_error(key, value, message):
    record = inventory_rows(_runs(), ORIGIN)[0].to_record()
    record[key] = value
    with pytest.raises(RunFolderError, match=re.escape(f"feature 0: {message}")):
        InventoryRow.from_record(record, "feature 0")
    del record[key]
    with pytest.raises(RunFolderError, match=f"inventory row: no '{key}'"):
        InventoryRow.from_record(record)
    with pytest.raises(RunFolderError, match="expected an object, got list"):
        InventoryRow.from_record([record])


@pytest.mark.parametrize(
    ("key", "cell"),
    [
        ("pole_count", ""),
        ("pole_count", "1_000"),
        ("pole_count", "2.0"),
        ("length_m", "four"),
        ("length_m", "inf"),
        ("design", "[{"),
        ("design", "7"),
        ("status", ""),
    ],
)
def test_a_malformed_csv_line_raises_a_run_folder_error(tmp_path, key, cell):
    rows = inventory_rows(_runs(), ORIGIN)
    cells = dict(zip(ROW_KEYS, rows[1].to_csv_cells(), strict=True))
    cells[key] = cell
    with pytest.raises(RunFolderError, match=f"line 3: '{key}' is {re.escape(repr(cell))}"):
        InventoryRow.from_csv_record(cells, "line 3")
    path = tmp_path / "inventory.csv"
    write_inventory_csv(path, rows)
    lines = path.read_text().split("\n")
    with path.open("w", newline="") as handle:
        handle.write("\n".join(lines[:2]) + "\n")
        csv.writer(handle, lineterminator="\n").writerow(cells.values())
    with pytest.raises(RunFolderError, match=f"inventory.csv: line 3: '{key}'"):
        read_inventory_csv(path)


def test_unreadable_inventory_files_raise_a_run_folder_error(tmp_path):
    path = tmp_path / "inventory.csv"
    path.write_text("run_id,status\n1,reconstructed\n")
    with pytest.raises(RunFolderError, match="the header lacks type, signature"):
        read_inventory_csv(path)
    with pytest.raises(RunFolderError, match="cannot be read as CSV"):
        read_inventory_csv(tmp_path / "absent.csv")
    geojson = tmp_path / "inventory.geojson"
    geojson.write_text('{"type": "FeatureCollection"}')
    with pytest.raises(RunFolderError, match="expected a FeatureCollection"):
        read_inventory_geojson(geojson)
    geojson.write_text('{"features": [{"properties": {"run_id": 1}}]}')
    with pytest.raises(RunFolderError, match="feature 0: no 'status'"):
        read_inventory_geojson(geojson)
    geojson.write_text("{")
    with pytest.raises(RunFolderError, match="cannot be read as JSON"):
        read_inventory_geojson(geojson)
