"""A run's guardrails as an ASAM OpenDRIVE 1.8 road (``.xodr``), for driving simulators.

One ``<road>`` whose reference line follows the vehicle's trajectory: lines and arcs within
:data:`~guardrail_core.export.reference_line.FIT_TOLERANCE_M` of it
(:mod:`guardrail_core.export.reference_line`), at the road's height (the trajectory's height
less the vehicle reference point's height above the road, ``drive.json``) in its elevation
profile. Where a pole lies beyond an end of the trajectory, the road goes on straight to
:data:`END_MARGIN_M` past it. Its one lane section has a driving lane of :data:`LANE_WIDTH_M`
each side: nominal, as the export knows the vehicle's path, not the road's lanes; nor does it
know the traffic side, so the road has no ``rule`` (readers take right-hand traffic).

Coordinates are the drive's local frame, metres; the header's ``<offset>`` is the drive's
origin, so map coordinates (in the drive's CRS, named in ``<geoReference>``) are the file's plus
the offset, as OpenDRIVE 1.8 §8.5 applies it (no rotation: ``hdg`` 0); a drive in a local
frame (``local: ...``, a KITTI odometry frame) gets no ``<geoReference>`` and stays in that
frame. The header's north,
south, east and west hold the lanes and every pole. Objects are placed by s (metres along the
reference line), t (metres to its left, negative on its right) and zOffset (metres above the
road's elevation at s), all measured on the fitted line, so a pole's position is exact whatever
the fit's tolerance.

Each guardrail run with at least two poles is an ``<object type="barrier" subtype="guardRail"
name="guardRail">``, and each pole an ``<object type="pole" name="guardRailPost">``:

* barrier: s, t, zOffset of its pole of least s (the ground at its foot); ``validLength`` the
  s from that pole to the one of greatest s; ``height`` the rails' top above the ground (the
  inventory's ``rail_top_m``; a run without a model: its ``height_m``, the poles' median
  height); ``width``, for a reconstructed run, twice the rails' reach from the poles' axes (the
  pipes' or the beam's farthest point, or the posts' radius), so the box centred on the poles'
  line holds the rails. One ``<repeat distance="0">`` per two consecutive poles of the run, in
  order of s: from the one pole's s to the other's, ``tStart``/``tEnd`` and
  ``zOffsetStart``/``zOffsetEnd`` those of their ground points, and the run's height and width
  at both ends; between two poles a reader interpolates t and zOffset linearly. A span more
  than :data:`SAME_PASS_RATIO` times longer along s than between its poles is left out: its
  poles lie by two passes of the road past the same place (a drive there and back).
* pole: its ground point's s, t, zOffset; ``radius`` and ``height`` (ground to top) of the
  reconstructed pole; ``validLength`` 0.

Both carry ``<userData code="guardrail:run_id">`` with the run's id (the inventory's
``run_id``). Object ids are unique in the file (1, 2, ... in run order, each barrier before its
poles).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pyproj
from pyproj.exceptions import CRSError

from guardrail_core.errors import ExportError
from guardrail_core.export.reference_line import (
    Elevation,
    Projection,
    ReferenceLine,
    fit_elevation,
    fit_reference_line,
)
from guardrail_core.export.run_export import ExportSource, load_export_source
from guardrail_core.formats.atomic import atomic_write, check_output
from guardrail_core.reconstruct.model import RunModel, UnitModel

REV_MAJOR, REV_MINOR = 1, 8
VENDOR = "guardrail export"
#: Metres: the nominal width of the one driving lane written each side of the reference line.
LANE_WIDTH_M = 3.5
#: Metres of straight road added beyond an object that lies past the trajectory's end, so that
#: every object has an s on the road.
END_MARGIN_M = 1.0
#: Fewer poles than this make no barrier (a lone pole is still written).
MIN_POLES = 2
#: A span between two consecutive poles longer along s than this many times their distance
#: apart is left out of the barrier: the poles lie on two passes of the road by the same place.
#: Along a curve the ratio stays near 1 (1.2 for poles 4 m out on a 25 m radius).
SAME_PASS_RATIO = 2.0
RUN_ID_CODE = "guardrail:run_id"


@dataclass(frozen=True)
class OpenDriveDocument:
    """An OpenDRIVE file's text and what it holds (see :class:`OpenDriveSummary`)."""

    xml: bytes
    road_length_m: float
    geometries: int
    barriers: int
    poles: int
    fit_error_m: float
    elevation_error_m: float


@dataclass(frozen=True)
class OpenDriveSummary:
    """What :func:`export_run_opendrive` wrote.

    Attributes
    ----------
    out : the ``.xodr`` file
    road_length_m : metres, the road's reference line
    geometries : its plan-view records (lines and arcs)
    barriers : guardrail barrier objects (one per run with at least two poles)
    poles : pole objects (every pole of every run)
    fit_error_m : metres, the largest horizontal distance of a trajectory pose from the
        reference line
    elevation_error_m : metres, the largest difference between the road's elevation and a
        pose's height less the reference point's height above the road
    crs : the drive's CRS, written as the ``<geoReference>``
    """

    out: Path
    road_length_m: float
    geometries: int
    barriers: int
    poles: int
    fit_error_m: float
    elevation_error_m: float
    crs: str


def export_run_opendrive(
    run_dir: str | Path,
    out: str | Path,
    *,
    drive_dir: str | Path | None = None,
    overwrite: bool = False,
) -> OpenDriveSummary:
    """Write a run's guardrails on a road along its drive as ASAM OpenDRIVE 1.8 (see the module
    docstring).

    Parameters
    ----------
    run_dir : a run folder with a reconstruction (``guardrail process`` or ``reconstruct``)
    out : the ``.xodr`` file to write
    drive_dir : the run's drive (default: ``run.json``'s ``drive.path``)
    overwrite : replace ``out`` if it exists

    Returns
    -------
    An :class:`OpenDriveSummary`.

    Raises
    ------
    OutputExistsError
        ``out`` exists and ``overwrite`` is false.
    InputInsideOutputError, OutputKindError, OutputSymlinkError
        ``out`` would replace what the export reads, is a folder or a symbolic link.
    ExportError
        ``out`` is not an ``.xodr`` path, the drive names no CRS or one PROJ cannot read, or
        its trajectory never moves; nothing is written.
    NoReconstructionError, RunFolderError, DriveError
        As :func:`guardrail_core.export.run_export.load_export_source`.
    """
    out = Path(out)
    if out.suffix.lower() != ".xodr":
        raise ExportError(f"{out}: give an .xodr file name")
    source = load_export_source(run_dir, drive_dir)
    check_output(out, folder=False, overwrite=overwrite, inputs=source.inputs)
    document = opendrive_document(source)
    atomic_write(out, document.xml, overwrite=overwrite, inputs=source.inputs)
    return OpenDriveSummary(
        out=out,
        road_length_m=document.road_length_m,
        geometries=document.geometries,
        barriers=document.barriers,
        poles=document.poles,
        fit_error_m=document.fit_error_m,
        elevation_error_m=document.elevation_error_m,
        crs=source.crs,
    )


def format_opendrive_summary(summary: OpenDriveSummary) -> str:
    """The summary as the CLI prints it."""
    return (
        f"OpenDRIVE {REV_MAJOR}.{REV_MINOR} road of {summary.road_length_m:.1f} m "
        f"({summary.geometries} line and arc record{'s' if summary.geometries != 1 else ''}, "
        f"within {summary.fit_error_m * 100:.1f} cm of the trajectory), "
        f"{summary.barriers} guardrail{'s' if summary.barriers != 1 else ''} with "
        f"{summary.poles} pole{'s' if summary.poles != 1 else ''}, CRS {summary.crs}\n"
        f"wrote {summary.out}"
    )


def opendrive_document(source: ExportSource) -> OpenDriveDocument:
    """The OpenDRIVE file of a run's guardrails along its drive (see the module docstring).

    Raises
    ------
    ExportError
        The drive's CRS is not one PROJ reads, or its trajectory never moves.
    """
    if source.georeferenced:
        _check_crs(source.crs)
    trajectory = np.asarray(source.trajectory_xyz, np.float64)
    ground = [
        np.array([p.position for p in run.poles], np.float64).reshape(-1, 3) for run in source.runs
    ]
    line = _covering(
        fit_reference_line(trajectory[:, :2]), np.concatenate([*ground, np.zeros((0, 3))])
    )
    on_line = line.project(trajectory[:, :2])
    road_height = trajectory[:, 2] - source.reference_height_m
    elevation = fit_elevation(on_line.s, road_height, line.total_length)

    root = ET.Element("OpenDRIVE")
    root.append(_header(source, line, ground))
    road = ET.SubElement(
        root,
        "road",
        {
            "id": "1",
            "name": source.drive_name,
            "length": _num(line.total_length),
            "junction": "-1",
        },
    )
    road.append(_plan_view(line))
    road.append(_elevation_profile(elevation))
    road.append(_lanes())
    objects = ET.SubElement(road, "objects")
    barriers = 0
    for run, row, points in zip(source.runs, source.rows, ground, strict=True):
        placed = line.project(points[:, :2])
        z_offset = points[:, 2] - elevation(placed.s)
        if len(points) >= MIN_POLES:
            height = row.rail_top_m if row.rail_top_m is not None else row.height_m
            assert height is not None  # a run with poles has a height
            objects.append(_barrier(len(objects) + 1, run, placed, z_offset, height))
            barriers += 1
        for k, pole in enumerate(run.poles):
            pole_attributes = {
                "type": "pole",
                "name": "guardRailPost",
                "s": placed.s[k],
                "t": placed.t[k],
                "zOffset": z_offset[k],
                "validLength": 0.0,
                "orientation": "none",
                "radius": pole.radius,
                "height": pole.height,
            }
            objects.append(_object(len(objects) + 1, run.run_id, pole_attributes))
    ET.indent(root)
    return OpenDriveDocument(
        xml=_serialise(root, source.crs),
        road_length_m=line.total_length,
        geometries=len(line.s),
        barriers=barriers,
        poles=sum(len(points) for points in ground),
        fit_error_m=float(on_line.distance.max()),
        elevation_error_m=float(np.abs(elevation(on_line.s) - road_height).max()),
    )


# ------------------------------------------------------------------------------------ helpers


def _check_crs(crs: str) -> None:
    """Refuse a CRS PROJ cannot read: ``<geoReference>`` is read by PROJ."""
    try:
        pyproj.CRS.from_user_input(crs)
    except CRSError as exc:
        raise ExportError(
            f"the drive's CRS {crs!r} is not one PROJ reads ({exc}); give the drive a CRS "
            "pyproj knows (an EPSG code) in drive.json"
        ) from exc


def _covering(line: ReferenceLine, points: np.ndarray) -> ReferenceLine:
    """``line`` continued straight past either end by :data:`END_MARGIN_M` beyond the farthest
    of (N, 3) points that lie past that end, if any."""
    placed = line.project(points[:, :2]).s
    before = -placed.min(initial=0.0)
    after = placed.max(initial=line.total_length) - line.total_length
    return line.extended(
        before + END_MARGIN_M if before > 0 else 0.0, after + END_MARGIN_M if after > 0 else 0.0
    )


def _num(value: float) -> str:
    """A number as the shortest text that reads back as the same float64."""
    return repr(float(value))


def _header(source: ExportSource, line: ReferenceLine, ground: list[np.ndarray]) -> ET.Element:
    """``<header>``: the revision, the extent of the lanes and the poles (local, metres), the
    CRS and the drive's origin as offset."""
    along = np.linspace(0.0, line.total_length, max(2, int(np.ceil(line.total_length)) + 1))
    along = np.r_[along, line.s]
    borders = [line.to_xy(along, np.full_like(along, t)) for t in (-LANE_WIDTH_M, LANE_WIDTH_M)]
    xy = np.concatenate([*borders, *(points[:, :2] for points in ground)])
    header = ET.Element(
        "header",
        {
            "revMajor": str(REV_MAJOR),
            "revMinor": str(REV_MINOR),
            "name": source.drive_name,
            "date": datetime.now(UTC).replace(microsecond=0).isoformat(),
            "north": _num(xy[:, 1].max()),
            "south": _num(xy[:, 1].min()),
            "east": _num(xy[:, 0].max()),
            "west": _num(xy[:, 0].min()),
            "vendor": VENDOR,
        },
    )
    if source.georeferenced:  # a local frame (KITTI odometry) has none: the file stays local
        ET.SubElement(header, "geoReference")  # its CDATA text is written by _serialise
    x, y, z = source.origin
    ET.SubElement(header, "offset", {"x": _num(x), "y": _num(y), "z": _num(z), "hdg": "0.0"})
    return header


def _plan_view(line: ReferenceLine) -> ET.Element:
    plan_view = ET.Element("planView")
    for s, x, y, hdg, length, curvature in zip(
        line.s, line.x, line.y, line.hdg, line.length, line.curvature, strict=True
    ):
        geometry = ET.SubElement(
            plan_view,
            "geometry",
            {"s": _num(s), "x": _num(x), "y": _num(y), "hdg": _num(hdg), "length": _num(length)},
        )
        if curvature == 0:
            ET.SubElement(geometry, "line")
        else:
            ET.SubElement(geometry, "arc", {"curvature": _num(curvature)})
    return plan_view


def _elevation_profile(elevation: Elevation) -> ET.Element:
    profile = ET.Element("elevationProfile")
    for s, a, b, c, d in zip(
        elevation.s, elevation.a, elevation.b, elevation.c, elevation.d, strict=True
    ):
        ET.SubElement(
            profile,
            "elevation",
            {"s": _num(s), "a": _num(a), "b": _num(b), "c": _num(c), "d": _num(d)},
        )
    return profile


def _lanes() -> ET.Element:
    """One lane section: a driving lane of :data:`LANE_WIDTH_M` each side."""
    lanes = ET.Element("lanes")
    section = ET.SubElement(lanes, "laneSection", {"s": "0.0"})
    for side, lane_id in (("left", "1"), ("center", "0"), ("right", "-1")):
        lane = ET.SubElement(
            ET.SubElement(section, side),
            "lane",
            {"id": lane_id, "type": "driving" if lane_id != "0" else "none", "level": "false"},
        )
        if lane_id != "0":
            ET.SubElement(
                lane,
                "width",
                {"sOffset": "0.0", "a": _num(LANE_WIDTH_M), "b": "0.0", "c": "0.0", "d": "0.0"},
            )
    return lanes


def _object(
    object_id: int,
    run_id: int,
    attributes: dict[str, str | float],
    repeats: Sequence[dict[str, float]] = (),
) -> ET.Element:
    """An ``<object>`` (numbers written exactly), its repeats, and the run's id as user data
    (after the repeats, as the schema orders an object's children)."""
    element = ET.Element(
        "object",
        {"id": str(object_id)}
        | {k: v if isinstance(v, str) else _num(v) for k, v in attributes.items()},
    )
    for repeat in repeats:
        ET.SubElement(element, "repeat", {k: _num(v) for k, v in repeat.items()})
    ET.SubElement(element, "userData", {"code": RUN_ID_CODE, "value": str(run_id)})
    return element


def _barrier(
    object_id: int,
    run: RunModel,
    placed: Projection,
    z_offset: np.ndarray,
    height: float,
) -> ET.Element:
    """The barrier object of a run from its (P,) poles (P >= 2) placed on the line, their
    (P,) zOffset, metres, and the rails' height above the ground, metres: one continuous repeat
    between each two consecutive poles of the run, in order along s."""
    s, t = placed.s, placed.t
    size = {"height": height}
    width = _rail_width(run.model, float(np.median([p.radius for p in run.poles])))
    if width is not None:
        size["width"] = width
    apart = np.linalg.norm(np.diff([p.position[:2] for p in run.poles], axis=0), axis=1)
    spans = []
    for k in range(len(s) - 1):
        a, b = sorted((k, k + 1), key=lambda i: s[i])
        # Poles abreast have no length between them; a span much longer along s than between
        # its poles joins two passes of the road by the same place (a drive there and back).
        if 0 < s[b] - s[a] <= SAME_PASS_RATIO * apart[k]:
            spans.append((a, b))
    repeats = [
        {
            "s": s[a],
            "length": s[b] - s[a],
            "distance": 0.0,
            "tStart": t[a],
            "tEnd": t[b],
            "zOffsetStart": z_offset[a],
            "zOffsetEnd": z_offset[b],
        }
        | {f"{name}{end}": value for name, value in size.items() for end in ("Start", "End")}
        for a, b in sorted(spans, key=lambda span: s[span[0]])
    ]
    first = int(np.argmin(s))
    attributes = {
        "type": "barrier",
        "subtype": "guardRail",
        "name": "guardRail",
        "s": s[first],
        "t": t[first],
        "zOffset": z_offset[first],
        "validLength": s.max() - s.min(),
        "orientation": "none",
    } | size
    return _object(object_id, run.run_id, attributes, repeats)


def _rail_width(model: UnitModel | None, pole_radius: float) -> float | None:
    """Metres: twice the farthest reach of the rails from the plane of the poles' axes (unit
    z), at least the posts' radius; None without a model."""
    if model is None:
        return None
    reach = [pole_radius]
    reach += [float(np.abs(np.asarray(p.axis)[:, 2]).max()) + p.radius for p in model.pipes]
    if model.section is not None and len(model.section):
        reach.append(float(np.abs(np.asarray(model.section)[:, 0]).max()))
    return 2 * max(reach)


def _serialise(root: ET.Element, crs: str) -> bytes:
    """The document as UTF-8 XML, the CRS in a CDATA section as OpenDRIVE asks."""
    text = ET.tostring(root, encoding="unicode")
    # ElementTree writes no CDATA: fill the empty element (unique: no attribute holds a "<").
    # A "]]>" in the CRS would end the section early, so it is split across two.
    cdata = "<![CDATA[" + crs.replace("]]>", "]]]]><![CDATA[>") + "]]>"
    text = text.replace("<geoReference />", f"<geoReference>{cdata}</geoReference>", 1)
    return ('<?xml version="1.0" encoding="UTF-8"?>\n' + text + "\n").encode("utf-8")
