"""``export_run_osm``: a run's guardrails as OpenStreetMap XML, read back with osmium."""

from __future__ import annotations

import dataclasses
import json
import shutil
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import osmium
import pyproj
import pytest

from guardrail_core.errors import ExportError, OutputExistsError
from guardrail_core.export import osm as osm_export
from guardrail_core.export.osm import (
    OsmSummary,
    export_run_osm,
    format_osm_summary,
)
from guardrail_core.export.run_export import ExportSource, load_export_source
from guardrail_core.reconstruct.inventory import inventory_rows
from guardrail_core.reconstruct.inventory_row import InventoryRow

#: Metres: how far a node, converted back to the drive's CRS, may lie from its pole (x/y).
#: 7 decimals of a degree round by at most 0.56 cm in latitude and less in longitude.
POSITION_TOLERANCE_M = 0.02


@dataclass(frozen=True)
class _Way:
    """A way as osmium read it: its id, tags, and its nodes' ids and (lon, lat) degrees."""

    id: int
    tags: dict[str, str]
    node_ids: list[int]
    lon_lat: np.ndarray  # (P, 2) float64


@dataclass(frozen=True)
class _OsmFile:
    """What osmium read from an ``.osm`` file."""

    box: osmium.osm.Box
    nodes: dict[int, tuple[float, float]]  # id -> (lon, lat) degrees
    node_versions: set[int]
    node_tags: list[dict[str, str]]
    ways: list[_Way]


def _read(path: Path) -> _OsmFile:
    """Read ``path`` with osmium. Way nodes are located from the file's own nodes: osmium's
    location index (``with_locations``) holds positive ids only, and new objects are negative."""
    nodes: dict[int, tuple[float, float]] = {}
    versions: set[int] = set()
    node_tags: list[dict[str, str]] = []
    raw_ways: list[tuple[int, dict[str, str], list[int]]] = []
    for obj in osmium.FileProcessor(str(path)):
        if isinstance(obj, osmium.osm.Node):
            nodes[obj.id] = (obj.location.lon, obj.location.lat)
            versions.add(obj.version)
            node_tags.append({tag.k: tag.v for tag in obj.tags})
        elif isinstance(obj, osmium.osm.Way):
            raw_ways.append(
                (obj.id, {tag.k: tag.v for tag in obj.tags}, [n.ref for n in obj.nodes])
            )
        else:
            raise AssertionError(f"unexpected {type(obj).__name__} {obj.id}")
    ways = [
        _Way(id=i, tags=tags, node_ids=refs, lon_lat=np.array([nodes[r] for r in refs]))
        for i, tags, refs in raw_ways
    ]
    box = osmium.io.Reader(str(path)).header().box()
    return _OsmFile(box=box, nodes=nodes, node_versions=versions, node_tags=node_tags, ways=ways)


@pytest.fixture(scope="module")
def source(run_path: Path, drive_path: Path) -> ExportSource:
    return load_export_source(run_path, drive_path)


@pytest.fixture(scope="module")
def exported(
    run_path: Path, drive_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> tuple[OsmSummary, _OsmFile]:
    out = tmp_path_factory.mktemp("osm") / "guardrails.osm"
    summary = export_run_osm(run_path, out, drive_dir=drive_path)
    return summary, _read(out)


def _expected_tags(row: InventoryRow) -> dict[str, str]:
    """The tags the module docstring promises for an inventory row, written out again."""
    tags = {
        "barrier": "guard_rail",
        "height": f"{round(row.height_m, 2):g}",
        "source": "mobile mapping (guardrail)",
        "guardrail:run_id": str(row.run_id),
    }
    if row.status == "reconstructed":
        tags["material"] = "metal"
        tags["guard_rail:type"] = {"pipe": "pipe", "beam": "beam"}[row.type]
    return tags


def _to_map_xy(lon_lat: np.ndarray, crs: str) -> np.ndarray:
    """(P, 2) x, y in ``crs`` of (P, 2) WGS84 longitudes and latitudes."""
    back = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    x, y = back.transform(lon_lat[:, 0], lon_lat[:, 1])
    return np.column_stack([x, y])


def test_one_way_per_run_with_the_promised_tags(exported, source):
    summary, osm = exported
    with_poles = [
        (r, row) for r, row in zip(source.runs, source.rows, strict=True) if len(r.poles) >= 2
    ]
    assert {row.type for _, row in with_poles} == {"pipe", "beam"}  # both designs are seen
    assert [w.tags["guardrail:run_id"] for w in osm.ways] == [str(r.run_id) for r, _ in with_poles]
    for way, (run, row) in zip(osm.ways, with_poles, strict=True):
        assert way.tags == _expected_tags(row)
        assert len(way.node_ids) == len(run.poles)
    assert (summary.ways, summary.nodes, summary.skipped_runs, summary.crs) == (
        len(with_poles),
        sum(len(r.poles) for r, _ in with_poles),
        len(source.runs) - len(with_poles),
        source.crs,
    )


def test_nodes_stand_on_the_poles_in_run_order(exported, source):
    _, osm = exported
    runs = {r.run_id: r for r in source.runs}
    for way in osm.ways:
        run = runs[int(way.tags["guardrail:run_id"])]
        poles = source.to_map(np.array([p.position for p in run.poles]))[:, :2]
        error = np.linalg.norm(_to_map_xy(way.lon_lat, source.crs) - poles, axis=1)
        assert error.max() < POSITION_TOLERANCE_M


def test_ways_keep_the_road_on_their_right(exported, source):
    """OSM's guard_rail: the right side is the inner one, toward the road."""
    _, osm = exported
    trajectory = source.to_map(source.trajectory_xyz)[:, :2]
    for way in osm.ways:
        xy = _to_map_xy(way.lon_lat, source.crs)
        middle = xy.mean(axis=0)
        direction = xy[-1] - xy[0]
        road = trajectory[np.argmin(np.linalg.norm(trajectory - middle, axis=1))] - middle
        assert direction[0] * road[1] - direction[1] * road[0] < 0  # clockwise: on the right


def test_new_untagged_nodes_inside_the_bounds(exported):
    _, osm = exported
    ids = [*osm.nodes, *(w.id for w in osm.ways)]
    assert all(i < 0 for i in ids) and len(set(ids)) == len(ids)
    assert sorted(osm.nodes) == sorted(i for w in osm.ways for i in w.node_ids)  # none shared
    assert osm.node_versions == {0}  # no version attribute: new objects
    assert all(tags == {} for tags in osm.node_tags)
    assert osm.box.valid()
    for lon, lat in osm.nodes.values():
        assert osm.box.contains(osmium.osm.Location(lon, lat))
    lon_lat = np.array(list(osm.nodes.values()))
    # The bounds are the nodes' own extremes, not a padded box.
    assert osm.box.bottom_left.lon == pytest.approx(lon_lat[:, 0].min(), abs=1e-9)
    assert osm.box.top_right.lat == pytest.approx(lon_lat[:, 1].max(), abs=1e-9)


def test_the_file_is_osm_0_6_with_7_decimals_and_upload_discouraged(run_path, drive_path, tmp_path):
    out = tmp_path / "guardrails.osm"
    export_run_osm(run_path, out, drive_dir=drive_path)
    root = ET.parse(out).getroot()
    assert (root.tag, root.get("version"), root.get("upload")) == ("osm", "0.6", "false")
    assert [child.tag for child in root][0] == "bounds"
    for node in root.iter("node"):
        assert len(node.get("lat", "").split(".")[1]) == 7
        assert len(node.get("lon", "").split(".")[1]) == 7
        assert node.get("version") is None


def test_runs_without_two_poles_are_skipped_and_poles_only_runs_untyped(
    run_path, drive_path, source, tmp_path, monkeypatch
):
    """One run cut to a single pole (skipped), the other stripped of its model (no type or
    material: nothing tells them)."""
    first, second = source.runs
    runs = (
        dataclasses.replace(first, poles=first.poles[:1]),
        dataclasses.replace(second, model=None),
    )
    changed = dataclasses.replace(source, runs=runs, rows=inventory_rows(runs, source.origin))
    monkeypatch.setattr(osm_export, "load_export_source", lambda *_: changed)
    out = tmp_path / "guardrails.osm"
    summary = export_run_osm(run_path, out, drive_dir=drive_path)
    osm = _read(out)
    assert (summary.ways, summary.nodes, summary.skipped_runs) == (1, len(second.poles), 1)
    (way,) = osm.ways
    assert changed.rows[1].status == "poles only"
    assert way.tags == _expected_tags(changed.rows[1])
    assert "material" not in way.tags and "guard_rail:type" not in way.tags
    assert "1 run with fewer than two poles skipped" in format_osm_summary(summary)


def test_an_unreadable_crs_is_refused_and_nothing_written(run_path, drive_path, tmp_path):
    drive = tmp_path / "drive"
    shutil.copytree(drive_path, drive, ignore=shutil.ignore_patterns("truth", "review"))
    meta = json.loads((drive / "drive.json").read_text())
    meta["crs"] = "EPSG:999999"
    (drive / "drive.json").write_text(json.dumps(meta))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    with pytest.raises(ExportError, match="EPSG:999999"):
        export_run_osm(run_path, out_dir / "guardrails.osm", drive_dir=drive)
    assert list(out_dir.iterdir()) == []  # not even a partial file


def test_an_existing_output_is_kept_without_overwrite(run_path, drive_path, tmp_path):
    out = tmp_path / "guardrails.osm"
    out.write_text("mine")
    with pytest.raises(OutputExistsError):
        export_run_osm(run_path, out, drive_dir=drive_path)
    assert out.read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["guardrails.osm"]
    summary = export_run_osm(run_path, out, drive_dir=drive_path, overwrite=True)
    assert len(_read(out).ways) == summary.ways


def test_format_osm_summary(exported):
    summary, _ = exported
    text = format_osm_summary(summary)
    assert (
        f"{summary.ways} guardrail ways through {summary.nodes} poles, EPSG:6677 to WGS84" in text
    )
    assert "skipped" not in text
    assert text.splitlines()[1] == f"wrote {summary.out} (review it in JOSM before any upload)"
