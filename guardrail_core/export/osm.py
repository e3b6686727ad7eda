"""A run's guardrails as OpenStreetMap XML (``.osm``, API 0.6), for review in JOSM.

One way per run with at least two poles, through its poles' ground points in run order, so the
road lies on the way's right: the side OSM's ``barrier=guard_rail`` calls inner. Nodes are the
ground points in WGS84 (EPSG:4326), converted from the drive's CRS with pyproj and written with
7 decimals (1e-7 degree is 1.1 cm of latitude at most, OSM's own precision); heights and the
drive's vertical datum are not written (OSM nodes have no z). Nodes are untagged. Every object
is new: negative ids, one counter for nodes then ways as JOSM numbers new objects, and no
``version``, as an upload-style file has none (osmium reads it as version 0). pyosmium's node
location index (``with_locations``) holds no negative ids: a reader that needs the ways'
geometry takes it from the file's nodes.

Tags of a way:

* ``barrier=guard_rail``
* ``height``: metres above the ground, the inventory row's ``height_m`` (the higher of the
  poles' median height and the rails' top) rounded to the centimetre
* ``guard_rail:type`` and ``material=metal``: only for a reconstructed run (a pipe model with
  pipes or a beam model with a section). The key and its values are **ours**: we found no OSM
  wiki page documenting them. ``pipe`` for a pipe model, ``beam`` for a beam model (the
  reconstruction does not tell a W-beam from a thrie beam). ``material=metal`` holds
  for every design the project knows: steel pipes and posts, steel W- and thrie-beams.
* ``source=mobile mapping (guardrail)``
* ``guardrail:run_id``: the run's id in the run folder (the inventory's ``run_id``)

The root element carries JOSM's ``upload="false"``: JOSM warns before uploading the layer. The
file is a proposal to check against imagery and the existing map, never an upload as it is.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj
from pyproj.exceptions import ProjError

from guardrail_core.errors import ExportError
from guardrail_core.export.run_export import load_export_source
from guardrail_core.formats.atomic import atomic_write, check_output
from guardrail_core.reconstruct.inventory_row import InventoryRow

OSM_API_VERSION = "0.6"
GENERATOR = "guardrail export"
WGS84 = "EPSG:4326"
#: Decimals of latitude and longitude: 1e-7 degree (1.1 cm at most), as the OSM database stores.
DEGREE_DECIMALS = 7
#: Decimals of ``height`` (metres).
HEIGHT_DECIMALS = 2
SOURCE = "mobile mapping (guardrail)"
RUN_ID_KEY = "guardrail:run_id"
#: Our ``guard_rail:type`` value of each inventory ``type`` (not values the OSM wiki documents).
GUARD_RAIL_TYPE = {"pipe": "pipe", "beam": "beam"}
#: ``material`` of a reconstructed run: true of every design of the project (steel).
MATERIAL = "metal"
#: Fewer poles than this make no line: such runs are skipped.
MIN_POLES = 2


@dataclass(frozen=True)
class OsmSummary:
    """What :func:`export_run_osm` wrote.

    Attributes
    ----------
    out : the ``.osm`` file
    ways : guardrail ways written (one per run with at least two poles)
    nodes : nodes written (one per pole of those runs)
    skipped_runs : runs with fewer than two poles, not written
    crs : the drive's CRS the coordinates were converted from
    """

    out: Path
    ways: int
    nodes: int
    skipped_runs: int
    crs: str


def export_run_osm(
    run_dir: str | Path,
    out: str | Path,
    *,
    drive_dir: str | Path | None = None,
    overwrite: bool = False,
) -> OsmSummary:
    """Write a run's guardrails as an OpenStreetMap XML file (see the module docstring).

    Parameters
    ----------
    run_dir : a run folder with a reconstruction (``guardrail process`` or ``reconstruct``)
    out : the ``.osm`` file to write
    drive_dir : the run's drive (default: ``run.json``'s ``drive.path``)
    overwrite : replace ``out`` if it exists

    Returns
    -------
    An :class:`OsmSummary`.

    Raises
    ------
    OutputExistsError
        ``out`` exists and ``overwrite`` is false.
    InputInsideOutputError, OutputKindError, OutputSymlinkError
        ``out`` would replace what the export reads, is a folder or a symbolic link.
    ExportError
        The drive names no CRS, or one pyproj cannot read or convert to WGS84; nothing is
        written.
    NoReconstructionError, RunFolderError, DriveError
        As :func:`guardrail_core.export.run_export.load_export_source`.
    """
    out = Path(out)
    source = load_export_source(run_dir, drive_dir)
    check_output(out, folder=False, overwrite=overwrite, inputs=source.inputs)
    transformer = _to_wgs84(source.crs)

    nodes: list[ET.Element] = []
    ways: list[ET.Element] = []
    lats: list[str] = []
    lons: list[str] = []
    skipped = 0
    for run, row in zip(source.runs, source.rows, strict=True):
        if len(run.poles) < MIN_POLES:
            skipped += 1
            continue
        ground = source.to_map(np.array([p.position for p in run.poles], np.float64))
        lon, lat = _lon_lat(transformer, ground, source.crs)
        way = ET.Element("way")
        for lat_text, lon_text in zip(lat, lon, strict=True):
            node_id = str(-(len(nodes) + 1))
            nodes.append(ET.Element("node", {"id": node_id, "lat": lat_text, "lon": lon_text}))
            ET.SubElement(way, "nd", {"ref": node_id})
        for key, value in _way_tags(row).items():
            ET.SubElement(way, "tag", {"k": key, "v": value})
        ways.append(way)
        lats += lat
        lons += lon
    for k, way in enumerate(ways):
        way.set("id", str(-(len(nodes) + k + 1)))  # after the nodes: ids unique across types

    root = ET.Element(
        "osm", {"version": OSM_API_VERSION, "generator": GENERATOR, "upload": "false"}
    )
    if nodes:
        # From the written text, so every node lies inside the bounds to the last digit.
        bounds = {
            "minlat": min(lats, key=float),
            "minlon": min(lons, key=float),
            "maxlat": max(lats, key=float),
            "maxlon": max(lons, key=float),
        }
        ET.SubElement(root, "bounds", bounds)
    root.extend(nodes + ways)
    ET.indent(root)
    data = ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"
    atomic_write(out, data, overwrite=overwrite, inputs=source.inputs)
    return OsmSummary(
        out=out, ways=len(ways), nodes=len(nodes), skipped_runs=skipped, crs=source.crs
    )


def format_osm_summary(summary: OsmSummary) -> str:
    """The summary as the CLI prints it."""
    skipped = (
        f"; {summary.skipped_runs} run{'s' if summary.skipped_runs != 1 else ''} with fewer "
        "than two poles skipped"
        if summary.skipped_runs
        else ""
    )
    return (
        f"{summary.ways} guardrail way{'s' if summary.ways != 1 else ''} through "
        f"{summary.nodes} pole{'s' if summary.nodes != 1 else ''}, {summary.crs} to WGS84"
        f"{skipped}\n"
        f"wrote {summary.out} (review it in JOSM before any upload)"
    )


# ------------------------------------------------------------------------------------ helpers


def _to_wgs84(crs: str) -> pyproj.Transformer:
    """The conversion from the drive's CRS to WGS84 longitude, latitude (degrees)."""
    try:
        return pyproj.Transformer.from_crs(crs, WGS84, always_xy=True)
    except ProjError as exc:  # CRSError among them
        raise ExportError(
            f"the drive's CRS {crs!r} cannot be converted to WGS84 by pyproj ({exc}); "
            "give the drive a CRS pyproj knows (an EPSG code) in drive.json"
        ) from exc


def _lon_lat(
    transformer: pyproj.Transformer, ground: np.ndarray, crs: str
) -> tuple[list[str], list[str]]:
    """Longitudes and latitudes of (P, 3) map points (the drive's CRS, metres), as the
    ``DEGREE_DECIMALS`` text written to the file."""
    try:
        lon, lat = transformer.transform(ground[:, 0], ground[:, 1], errcheck=True)
    except ProjError as exc:
        raise ExportError(f"pole positions cannot be converted from {crs} to WGS84: {exc}") from exc
    return (
        [f"{v:.{DEGREE_DECIMALS}f}" for v in np.asarray(lon, np.float64)],
        [f"{v:.{DEGREE_DECIMALS}f}" for v in np.asarray(lat, np.float64)],
    )


def _way_tags(row: InventoryRow) -> dict[str, str]:
    """The tags of a run's way from its inventory row (see the module docstring)."""
    assert row.height_m is not None  # a run with poles (a way) has a height
    tags = {
        "barrier": "guard_rail",
        "height": f"{round(row.height_m, HEIGHT_DECIMALS):g}",
    }
    if row.status == "reconstructed":
        # A run of poles only has no rails to tell its type or material by.
        tags["material"] = MATERIAL
        tags["guard_rail:type"] = GUARD_RAIL_TYPE[row.type]
    tags["source"] = SOURCE
    tags[RUN_ID_KEY] = str(row.run_id)
    return tags
