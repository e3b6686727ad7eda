"""``export_run_opendrive``: a run's guardrails on a road along its drive, as ASAM OpenDRIVE 1.8.

Every file is read back with an independent reader: pyxodr evaluates the reference line (its
lines and arcs, sampled every 0.1 m) and the elevation profile; pyxodr reads no objects, so
their records are parsed with lxml and placed by their s, t and zOffset on pyxodr's line.
"""

from __future__ import annotations

import dataclasses
import itertools
import shutil
from pathlib import Path

import numpy as np
import pyproj
import pytest
import shapely
from lxml import etree
from pyxodr.road_objects.network import RoadNetwork
from scipy.integrate import cumulative_trapezoid
from scipy.spatial import cKDTree

from guardrail_core.errors import ExportError, InputInsideOutputError, OutputExistsError
from guardrail_core.export.opendrive import (
    LANE_WIDTH_M,
    OpenDriveSummary,
    export_run_opendrive,
    format_opendrive_summary,
    opendrive_document,
)
from guardrail_core.export.reference_line import (
    FIT_TOLERANCE_M,
    ReferenceLine,
    fit_reference_line,
    worst_deviation,
)
from guardrail_core.export.run_export import ExportSource, load_export_source
from guardrail_core.reconstruct.inventory import inventory_rows
from guardrail_core.reconstruct.model import Pole, RunModel
from guardrail_core.reconstruct.sweep import SweepParams
from tests.file_tree import file_tree

#: Metres: how far pyxodr's reading of an object's place may lie from the point it stands for
#: (its line is a polyline of 0.1 m chords: well under a millimetre here).
PLACE_M = 0.005


class Reader:
    """An ``.xodr`` file as pyxodr and lxml read it: one road, its objects, the header."""

    def __init__(self, path: Path) -> None:
        (self.road,) = RoadNetwork(str(path)).get_roads()
        self.line = np.asarray(self.road.reference_line)  # (M, 2), file coordinates
        self.z = np.asarray(self.road.z_coordinates)  # (M,)
        self.along = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(self.line, axis=0), axis=1))]
        self.root = etree.parse(str(path)).getroot()
        offset = self.root.find("header/offset")
        self.offset = np.array([float(offset.get(k)) for k in "xyz"])

    def place(self, s: np.ndarray, t: np.ndarray, z_offset: np.ndarray) -> np.ndarray:
        """(N, 3) file coordinates of (N,) s, t, zOffset: t along the left normal of pyxodr's
        line (its direction from the points 0.1 m either side)."""
        s = np.asarray(s, np.float64)
        step = self.road.resolution
        direction = self._at(s + step) - self._at(s - step)
        direction /= np.linalg.norm(direction, axis=1)[:, None]
        xy = self._at(s) + np.asarray(t)[:, None] * np.stack(
            [-direction[:, 1], direction[:, 0]], -1
        )
        return np.column_stack([xy, np.interp(s, self.along, self.z) + np.asarray(z_offset)])

    def _at(self, s: np.ndarray) -> np.ndarray:
        """(N, 2) points of pyxodr's line at (N,) s, interpolated between its samples."""
        return np.column_stack([np.interp(s, self.along, self.line[:, k]) for k in (0, 1)])

    def objects(self, kind: str) -> list[etree._Element]:
        return self.root.findall(f"road/objects/object[@type='{kind}']")


def _numbers(element: etree._Element, *names: str) -> np.ndarray:
    return np.array([float(element.get(name)) for name in names])


def _run_id(element: etree._Element) -> int:
    (data,) = element.findall("userData[@code='guardrail:run_id']")
    return int(data.get("value"))


def _trajectory_errors(reader: Reader, source: ExportSource) -> tuple[np.ndarray, np.ndarray]:
    """Each pose's horizontal distance to pyxodr's reference line, and the difference between
    pyxodr's road elevation there and the pose's height less the reference height."""
    line = shapely.LineString(reader.line)
    poses = shapely.points(source.trajectory_xyz[:, :2])
    s = shapely.line_locate_point(line, poses)
    road = source.trajectory_xyz[:, 2] - source.reference_height_m
    return shapely.distance(line, poses), np.interp(s, reader.along, reader.z) - road


def _check_objects(reader: Reader, source: ExportSource) -> None:
    """Every pole object at its pole's ground point (map coordinates less the header offset),
    and one barrier per run of two poles or more through its poles' ground points."""
    poles = {run.run_id: run.poles for run in source.runs}
    placed: dict[int, list[etree._Element]] = {run_id: [] for run_id in poles}
    for element in reader.objects("pole"):
        assert element.get("name") == "guardRailPost"
        placed[_run_id(element)].append(element)
    for run_id, elements in placed.items():
        assert len(elements) == len(poles[run_id])
        if not elements:
            continue
        where = reader.place(*np.array([_numbers(e, "s", "t", "zOffset") for e in elements]).T)
        ground = source.to_map(np.array([p.position for p in poles[run_id]]))
        np.testing.assert_allclose(where + reader.offset, ground, rtol=0, atol=PLACE_M)
        for element, pole in zip(elements, poles[run_id], strict=True):
            assert float(element.get("radius")) == pole.radius
            assert float(element.get("height")) == pole.height

    barriers = {_run_id(e): e for e in reader.objects("barrier")}
    assert len(barriers) == len(reader.objects("barrier"))  # one per run
    assert set(barriers) == {run_id for run_id, p in poles.items() if len(p) >= 2}
    rows = {row.run_id: row for row in source.rows}
    for run_id, barrier in barriers.items():
        row = rows[run_id]
        assert (barrier.get("subtype"), barrier.get("name")) == ("guardRail", "guardRail")
        height = row.rail_top_m if row.rail_top_m is not None else row.height_m
        assert float(barrier.get("height")) == height
        repeats = barrier.findall("repeat")
        s, length = (np.array([float(r.get(k)) for r in repeats]) for k in ("s", "length"))
        assert np.all(np.array([float(r.get("distance")) for r in repeats]) == 0)
        assert s[0] == float(barrier.get("s")) and np.all(length > 0)
        np.testing.assert_allclose(s[1:], s[:-1] + length[:-1], rtol=0, atol=1e-9)
        assert length.sum() == pytest.approx(float(barrier.get("validLength")), abs=1e-9)
        for r in repeats:
            assert float(r.get("heightStart")) == float(r.get("heightEnd")) == height
        # The repeats' ends, in order along s, are the run's poles.
        ends = np.array(
            [_numbers(r, "s", "tStart", "zOffsetStart") for r in repeats]
            + [_numbers(repeats[-1], "s", "tEnd", "zOffsetEnd") + [length[-1], 0, 0]]
        )
        ground = source.to_map(np.array([p.position for p in poles[run_id]]))
        mine = reader.place(*ends.T) + reader.offset
        nearest = np.linalg.norm(mine[:, None] - ground[None], axis=2)
        assert nearest.min(axis=1).max() < PLACE_M
        assert sorted(nearest.argmin(axis=1)) == list(range(len(ground)))
        # Inner ends meet: each repeat starts where the last ended.
        for before, after in itertools.pairwise(repeats):
            assert (before.get("tEnd"), before.get("zOffsetEnd")) == (
                after.get("tStart"),
                after.get("zOffsetStart"),
            )
        # The object stands at the inventory's first or last pole (map coordinates).
        start = reader.place(*_numbers(barrier, "s", "t", "zOffset")[:, None])[0] + reader.offset
        first = np.array([row.start_x, row.start_y, row.start_z])
        last = np.array([row.end_x, row.end_y, row.end_z])
        assert min(np.abs(start - first).max(), np.abs(start - last).max()) < PLACE_M


# ------------------------------------------------------------------------------ the test drive


@pytest.fixture(scope="module")
def source(run_path: Path, drive_path: Path) -> ExportSource:
    return load_export_source(run_path, drive_path)


@pytest.fixture(scope="module")
def exported(
    run_path: Path, drive_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> tuple[OpenDriveSummary, Reader]:
    out = tmp_path_factory.mktemp("opendrive") / "road.xodr"
    summary = export_run_opendrive(run_path, out, drive_dir=drive_path)
    return summary, Reader(out)


def test_the_reference_line_follows_the_trajectory(
    exported: tuple[OpenDriveSummary, Reader], source: ExportSource
) -> None:
    summary, reader = exported
    distance, height = _trajectory_errors(reader, source)
    assert distance.max() <= FIT_TOLERANCE_M
    assert distance.max() == pytest.approx(summary.fit_error_m, abs=1e-3)
    assert np.abs(height).max() <= FIT_TOLERANCE_M
    assert np.abs(height).max() == pytest.approx(summary.elevation_error_m, abs=1e-3)
    assert reader.along[-1] == pytest.approx(summary.road_length_m, abs=1e-3)
    assert float(reader.root.find("road").get("length")) == summary.road_length_m
    geometries = reader.root.findall("road/planView/geometry")
    assert len(geometries) == summary.geometries
    assert all(len(g) == 1 and g[0].tag in ("line", "arc") for g in geometries)
    # One lane section with a driving lane each side.
    (section,) = reader.road.lane_sections
    assert [lane.type for lane in section.lanes] == ["driving", "driving"]
    widths = reader.root.findall("road/lanes/laneSection/*/lane/width")
    assert [float(w.get("a")) for w in widths] == [LANE_WIDTH_M, LANE_WIDTH_M]


def test_the_header_places_the_local_coordinates_on_the_map(
    exported: tuple[OpenDriveSummary, Reader], source: ExportSource
) -> None:
    summary, reader = exported
    header = reader.root.find("header")
    assert (header.get("revMajor"), header.get("revMinor")) == ("1", "8")
    assert b"<geoReference><![CDATA[EPSG:6677]]></geoReference>" in summary.out.read_bytes()
    crs = pyproj.CRS.from_user_input(header.find("geoReference").text)
    assert crs.to_epsg() == 6677 and summary.crs == source.crs == "EPSG:6677"
    # OpenDRIVE 1.8 §8.5: map = file + offset; the drive's origin is not (0, 0, 0).
    np.testing.assert_array_equal(reader.offset, source.origin)
    assert np.any(source.origin != 0)
    assert float(header.find("offset").get("hdg")) == 0
    west, east, south, north = (float(header.get(k)) for k in ("west", "east", "south", "north"))
    # The extent holds the lanes each side of the trajectory and every pole.
    poles = np.array([p.position[:2] for r in source.runs for p in r.poles])
    for x, y in (source.trajectory_xyz[:, :2].T, poles.T):
        assert np.all((west <= x) & (x <= east) & (south <= y) & (y <= north))


def test_poles_and_barriers_stand_at_the_inventory_s_ground_points(
    exported: tuple[OpenDriveSummary, Reader], source: ExportSource
) -> None:
    summary, reader = exported
    _check_objects(reader, source)
    assert summary.barriers == len(reader.objects("barrier")) == 2
    assert summary.poles == len(reader.objects("pole")) == sum(len(r.poles) for r in source.runs)
    ids = [o.get("id") for o in reader.root.iter("object")]
    assert len(set(ids)) == len(ids)
    for barrier in reader.objects("barrier"):  # both runs are reconstructed: a width
        run = next(r for r in source.runs if r.run_id == _run_id(barrier))
        assert float(barrier.get("width")) >= 2 * max(p.radius for p in run.poles)


def test_the_summary_line(exported: tuple[OpenDriveSummary, Reader]) -> None:
    summary, _ = exported
    text = format_opendrive_summary(summary)
    assert "OpenDRIVE 1.8" in text and "EPSG:6677" in text and f"wrote {summary.out}" in text
    assert f"{summary.barriers} guardrails with {summary.poles} poles" in text


def test_an_existing_output_is_kept_without_overwrite(
    run_path: Path, drive_path: Path, tmp_path: Path
) -> None:
    out = tmp_path / "road.xodr"
    out.write_bytes(b"an earlier export")
    with pytest.raises(OutputExistsError, match="--overwrite"):
        export_run_opendrive(run_path, out, drive_dir=drive_path)
    assert out.read_bytes() == b"an earlier export"
    export_run_opendrive(run_path, out, drive_dir=drive_path, overwrite=True)
    assert etree.parse(str(out)).getroot().tag == "OpenDRIVE"
    assert [p.name for p in tmp_path.iterdir()] == ["road.xodr"]  # no partial file left


def test_outputs_that_cannot_be_written_are_refused(
    run_path: Path, drive_path: Path, tmp_path: Path
) -> None:
    with pytest.raises(ExportError, match=r"\.xodr"):
        export_run_opendrive(run_path, tmp_path / "road.xml", drive_dir=drive_path)
    drive = tmp_path / "drive"
    shutil.copytree(drive_path, drive)
    (drive / "points" / "old.xodr").write_bytes(b"not the drive's, but in its points folder")
    before = file_tree(tmp_path)
    with pytest.raises(InputInsideOutputError, match="inside the input folder"):
        export_run_opendrive(
            run_path, drive / "points" / "old.xodr", drive_dir=drive, overwrite=True
        )
    assert file_tree(tmp_path) == before


# ----------------------------------------------------------------------- a curved, sloping drive


def _curve(step: float = 0.1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A road's centreline through a straight, a clothoid-like transition (curvature rising
    linearly), an arc of 40 m radius, a transition back, a straight and a reverse arc of 25 m:
    (N, 2) points ``step`` metres apart, (N,) their s and (N,) headings, radians."""
    stretches = [(40, 0, 0), (30, 0, 1 / 40), (40, 1 / 40, 1 / 40), (30, 1 / 40, 0), (30, 0, 0)]
    stretches += [(25, 0, -1 / 25), (20, -1 / 25, -1 / 25)]
    fine = 0.001  # integrated finely, then taken every `step`
    s = np.arange(0, sum(length for length, _, _ in stretches) + fine / 2, fine)
    ends = np.cumsum([0] + [length for length, _, _ in stretches])
    k = np.zeros_like(s)
    for (length, k0, k1), start in zip(stretches, ends, strict=False):
        inside = (s >= start) & (s <= start + length)
        k[inside] = k0 + (k1 - k0) * (s[inside] - start) / length
    heading = cumulative_trapezoid(k, s, initial=0) + 0.3
    xy = np.column_stack(
        [cumulative_trapezoid(np.cos(heading), s, initial=0) + 120.0,
         cumulative_trapezoid(np.sin(heading), s, initial=0) - 40.0]
    )  # fmt: skip
    every = int(round(step / fine))
    return xy[::every], s[::every], heading[::every]


def test_lines_and_arcs_fit_a_straight_a_transition_and_an_arc_within_the_tolerance() -> None:
    xy, s, _ = _curve()
    noisy = xy + np.random.default_rng(3).normal(0, 0.005, xy.shape)  # 5 mm of GNSS noise
    for points in (xy, noisy):
        line = fit_reference_line(points)
        assert isinstance(line, ReferenceLine)
        assert worst_deviation(line, points) <= FIT_TOLERANCE_M
        # Measured apart from the fit's own projection: the line sampled every 5 mm.
        dense, _ = line.evaluate(np.arange(0.0, line.total_length, 0.005))
        distance, _ = cKDTree(dense).query(points)
        assert distance.max() <= FIT_TOLERANCE_M + 0.0025
        assert line.total_length == pytest.approx(s[-1], rel=2e-3)
        # Continuous in position and heading from record to record.
        end, heading = line.evaluate(line.s[1:] - 1e-9)
        np.testing.assert_allclose(end, np.column_stack([line.x[1:], line.y[1:]]), atol=1e-6)
        np.testing.assert_allclose(np.angle(np.exp(1j * (heading - line.hdg[1:]))), 0, atol=1e-6)
        assert (line.curvature != 0).any() and len(line.s) < len(points) / 20
    # The 40 m arc comes out as arcs of about its curvature; the straights as lines.
    exact = fit_reference_line(xy)
    middle, _ = exact.evaluate(np.array([90.0]))
    on_arc = np.searchsorted(exact.s, 90.0) - 1
    assert exact.curvature[on_arc] == pytest.approx(1 / 40, rel=0.05)
    assert np.linalg.norm(middle - xy[900]) < FIT_TOLERANCE_M
    assert (exact.curvature == 0).any()


def _source(
    tmp_path: Path, trajectory: np.ndarray, pole_runs: list[list[Pole]], name: str
) -> ExportSource:
    """A drive of (T, 3) vehicle positions 1.8 m above the road with runs of poles (no models),
    its map coordinates local + a Japanese plane-rectangular origin."""
    runs = tuple(
        RunModel(run_id=i, poles=p, units=[], model=None, registered=np.zeros(0, bool), n_points=0)
        for i, p in enumerate(pole_runs)
    )
    origin = np.array([-7400.0, -34700.0, 40.0])
    return ExportSource(
        run_dir=tmp_path,
        drive_dir=tmp_path,
        drive_name=name,
        crs="EPSG:6677",
        origin=origin,
        runs=runs,
        rows=inventory_rows(runs, origin),
        trajectory_time=np.arange(len(trajectory)) * 0.01,
        trajectory_xyz=trajectory,
        reference_height_m=1.8,
        sweep=SweepParams(),
        inputs=[],
    )


def _curved_source(tmp_path: Path) -> ExportSource:
    """A drive along :func:`_curve` climbing 2 % with a crest; one run of poles 4 m left of the
    road, one 3 m right that starts 6 m before the drive, a lone pole and a run of none."""
    xy, s, heading = _curve()
    height = 0.02 * s + 0.4 * np.sin(s / 40)
    normal = np.column_stack([-np.sin(heading), np.cos(heading)])

    def poles(at: np.ndarray, t: float) -> list[Pole]:
        index = np.searchsorted(s, at)
        ground = np.column_stack([xy[index] + t * normal[index], height[index] + 0.15])
        return [Pole(g, 0.05, 0.9, 10) for g in ground]

    # Poles ahead of the first pose, on the road's straight continuation (it starts straight).
    ahead = xy[0] - np.outer([6.0, 4.0, 2.0], [np.cos(0.3), np.sin(0.3)]) - 3.0 * normal[0]
    right = [Pole(np.r_[p, 0.15], 0.05, 0.9, 10) for p in ahead]
    right += poles(np.arange(10.0, 120.0, 2.0), -3.0)
    left = poles(np.arange(20.0, 150.0, 4.0), 4.0)
    trajectory = np.column_stack([xy, height + 1.8])
    lone = poles(np.array([60.0]), 5.0)
    return _source(tmp_path, trajectory, [left, right, lone, []], "curve")


def test_a_curved_sloping_road_reads_back_with_its_poles(tmp_path: Path) -> None:
    source = _curved_source(tmp_path)
    document = opendrive_document(source)
    path = tmp_path / "curve.xodr"
    path.write_bytes(document.xml)
    reader = Reader(path)

    distance, height = _trajectory_errors(reader, source)
    assert distance.max() <= FIT_TOLERANCE_M
    assert np.abs(height).max() <= 0.01
    assert document.fit_error_m <= FIT_TOLERANCE_M and document.elevation_error_m <= 0.01
    kinds = {g[0].tag for g in reader.root.findall("road/planView/geometry")}
    assert kinds == {"line", "arc"}
    # The road was continued straight past the drive's start to hold the poles ahead of it.
    assert (
        reader.along[-1]
        > np.linalg.norm(np.diff(source.trajectory_xyz[:, :2], axis=0), axis=1).sum() + 6
    )
    everything = reader.root.findall("road/objects/object")
    assert all(0 <= float(o.get("s")) <= reader.along[-1] for o in everything)
    _check_objects(reader, source)
    assert len(reader.objects("barrier")) == document.barriers == 2  # the lone pole makes none
    assert len(reader.objects("pole")) == document.poles == sum(len(r.poles) for r in source.runs)
    for barrier in reader.objects("barrier"):  # no model: the poles' height, no width
        assert float(barrier.get("height")) == 0.9 and barrier.get("width") is None
    # The left run's t is positive, the right run's negative.
    t = {_run_id(b): float(b.get("t")) for b in reader.objects("barrier")}
    assert t[0] == pytest.approx(4.0, abs=0.06) and t[1] == pytest.approx(-3.0, abs=0.06)


def test_a_crs_proj_cannot_read_is_refused(tmp_path: Path) -> None:
    source = dataclasses.replace(_curved_source(tmp_path), crs="EPSG:999999")
    with pytest.raises(ExportError, match="'EPSG:999999'"):
        opendrive_document(source)


def test_a_local_frame_is_written_without_a_georeference(tmp_path: Path) -> None:
    """A KITTI odometry frame's drive is in its velodyne frame: the road stays local."""
    source = dataclasses.replace(_curved_source(tmp_path), crs="local: the velodyne frame")
    out = tmp_path / "local.xodr"
    out.write_bytes(opendrive_document(source).xml)
    reader = Reader(out)
    assert reader.root.find("header/geoReference") is None
    _check_objects(reader, source)


def test_a_span_between_two_passes_of_the_road_is_left_out(tmp_path: Path) -> None:
    # There along y = 0, a U-turn of 6 m radius, back along y = 12; a median guardrail at
    # y = 5.5 (nearer the way there), then at y = 6.5 (nearer the way back).
    there = np.column_stack([np.arange(0.0, 60.0, 0.1), np.zeros(600)])
    turn = np.linspace(-np.pi / 2, np.pi / 2, 189)[:-1]
    around = np.column_stack([60 + 6 * np.cos(turn), 6 + 6 * np.sin(turn)])
    back = np.column_stack([np.arange(60.0, 0.0, -0.1), np.full(600, 12.0)])
    xy = np.concatenate([there, around, back])
    ground = [(x, 5.5) for x in range(10, 31, 4)] + [(x, 6.5) for x in range(34, 51, 4)]
    run = [Pole(np.array([x, y, 0.1]), 0.05, 0.9, 10) for x, y in ground]
    source = _source(tmp_path, np.column_stack([xy, np.full(len(xy), 1.8)]), [run], "there_back")
    path = tmp_path / "there_back.xodr"
    path.write_bytes(opendrive_document(source).xml)
    reader = Reader(path)
    (barrier,) = reader.objects("barrier")
    repeats = barrier.findall("repeat")
    assert len(repeats) == len(run) - 2  # all but the span from (30, 5.5) to (34, 6.5)
    poles = source.to_map(np.array([p.position for p in run]))
    for r in repeats:
        ends = np.array(
            [_numbers(r, "s", "tStart", "zOffsetStart"), _numbers(r, "s", "tEnd", "zOffsetEnd")]
        )
        ends[1, 0] += float(r.get("length"))
        where = reader.place(*ends.T) + reader.offset
        k = np.linalg.norm(where[:, None] - poles[None], axis=2).argmin(axis=1)
        assert abs(k[0] - k[1]) == 1  # consecutive poles of the run
        np.testing.assert_allclose(where, poles[k], rtol=0, atol=PLACE_M)
        assert float(r.get("length")) < 4.5
    # Every pole, on either pass, stands where it is.
    placed = [_numbers(e, "s", "t", "zOffset") for e in reader.objects("pole")]
    np.testing.assert_allclose(
        reader.place(*np.array(placed).T) + reader.offset, poles, rtol=0, atol=PLACE_M
    )
