"""Spinning multi-beam LiDARs: their beams' fixed elevations, and the ring of each point from them.

A spinning LiDAR fires R beams at fixed elevations as it turns; its scan lattice is ring x azimuth
(:mod:`guardrail_core.sensors.scanner`). A file that carries no ring field still carries each
point's elevation, and that names its beam: the beam of the nearest elevation in the sensor's
beam table (a preset below, a table the user gives), or, without a table, in the elevations
the frame's own points cluster at.

The presets are the makers' nominal geometry (datasheets); a unit's calibration moves each beam
by up to a few hundredths of a degree, far less than the spacing between beams.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import find_peaks

from guardrail_core.errors import SourceFormatError


@dataclass(frozen=True)
class LidarModel:
    """A spinning multi-beam LiDAR's geometry.

    Attributes
    ----------
    name : the preset's name (``--sensor``)
    elevations_deg : (R,) float64 beam elevations, degrees, highest first
    firings_per_rotation : azimuth steps per turn at ``rotation_hz``
    rotation_hz : turns per second
    source : where the geometry comes from
    """

    name: str
    elevations_deg: tuple[float, ...]
    firings_per_rotation: int
    rotation_hz: float
    source: str

    @property
    def rings(self) -> int:
        return len(self.elevations_deg)


def _hdl64e() -> tuple[float, ...]:
    # Upper block of 32 lasers from +2 deg in 1/3 deg steps, lower block from -8.83 in 1/2.
    return tuple(
        np.round(np.concatenate([2.0 - np.arange(32) / 3.0, -8.83 - 0.5 * np.arange(32)]), 4)
    )


def _pandar64() -> tuple[float, ...]:
    # +15 to -25 deg; 1/6 deg between +2 and -6 deg (49 beams), sparse beams above and below.
    fine = 2.0 - np.arange(49) / 6.0
    upper = [15.0, 11.0, 8.0, 5.0, 3.0]
    lower = [-7.0, -8.0, -9.0, -10.0, -11.0, -12.0, -13.0, -14.0, -19.0, -25.0]
    return tuple(np.round(np.concatenate([upper, fine, lower]), 4))


def _uniform(top_deg: float, bottom_deg: float, rings: int) -> tuple[float, ...]:
    return tuple(np.round(np.linspace(top_deg, bottom_deg, rings), 4))


#: The sensors known by name.
LIDAR_MODELS: dict[str, LidarModel] = {
    model.name: model
    for model in (
        LidarModel(
            "hdl64e",
            _hdl64e(),
            2083,
            10.0,
            "Velodyne HDL-64E S2 datasheet: 26.9 deg vertical field, +2 to -24.9 deg, 1/3 deg "
            "above -8.33 deg and 1/2 deg below (the KITTI car's sensor)",
        ),
        LidarModel(
            "pandar64",
            _pandar64(),
            1800,
            10.0,
            "Hesai Pandar64 user manual: 40 deg vertical field, +15 to -25 deg, 0.167 deg "
            "between +2 and -6 deg; 0.2 deg azimuth at 10 Hz",
        ),
        LidarModel(
            "os1-128",
            _uniform(22.5, -22.5, 128),
            1024,
            10.0,
            "Ouster OS1-128 datasheet: 45 deg vertical field (+22.5 to -22.5), uniform beams; "
            "1024 columns at 10 Hz",
        ),
        LidarModel(
            "os1-64",
            _uniform(22.5, -22.5, 64),
            1024,
            10.0,
            "Ouster OS1-64 datasheet: 45 deg vertical field, uniform beams; 1024 columns at 10 Hz",
        ),
        LidarModel(
            "vlp16",
            _uniform(15.0, -15.0, 16),
            1800,
            10.0,
            "Velodyne VLP-16 datasheet: +15 to -15 deg in 2 deg steps; 0.2 deg azimuth at 10 Hz",
        ),
        LidarModel(
            "hdl32e",
            _uniform(10.67, -30.67, 32),
            2170,
            10.0,
            "Velodyne HDL-32E datasheet: +10.67 to -30.67 deg in 1.33 deg steps",
        ),
    )
}


def lidar_model(name: str) -> LidarModel:
    """The preset ``name`` (case-insensitive); :class:`SourceFormatError` naming the known ones."""
    model = LIDAR_MODELS.get(name.strip().lower())
    if model is None:
        raise SourceFormatError(
            f"--sensor: unknown LiDAR {name!r}; known: {', '.join(sorted(LIDAR_MODELS))} (or "
            "give a beam table with --beams)"
        )
    return model


def read_beam_table(path: str | os.PathLike) -> np.ndarray:
    """A beam table: one elevation per beam, degrees, one per line or separated by commas or
    spaces (a CSV with one column; ``#`` starts a comment, a header line of words is skipped).

    Returns
    -------
    (R,) float64 elevations, highest first

    Raises
    ------
    SourceFormatError
        Not numbers, fewer than two beams, beyond +-90 degrees, or a beam given twice.
    """
    path = Path(path)
    if not path.is_file():
        raise SourceFormatError(f"{path}: no such beam table")
    values: list[float] = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        text = line.split("#", 1)[0].replace(",", " ").split()
        if not text:
            continue
        try:
            values.extend(float(v) for v in text)
        except ValueError as exc:
            if number == 1 and not values:
                continue  # a header
            raise SourceFormatError(
                f"{path}:{number}: not an elevation in degrees ({exc})"
            ) from exc
    return check_elevations(np.asarray(values, np.float64), str(path))


def check_elevations(elevations_deg: np.ndarray, where: str) -> np.ndarray:
    """``elevations_deg`` (R,) sorted highest first, after checking them (see
    :func:`read_beam_table`)."""
    elevations = np.asarray(elevations_deg, np.float64).ravel()
    if len(elevations) < 2 or not np.all(np.isfinite(elevations)):
        raise SourceFormatError(f"{where}: expected two or more finite beam elevations")
    if np.any(np.abs(elevations) > 90):
        raise SourceFormatError(f"{where}: beam elevations must lie within +-90 degrees")
    ordered = np.sort(elevations)[::-1]
    if np.any(np.diff(ordered) == 0):
        raise SourceFormatError(f"{where}: a beam elevation is given twice")
    return ordered


def point_elevations_deg(xyz: np.ndarray) -> np.ndarray:
    """(N,) float64 elevation of each point seen from the sensor's origin, degrees.

    Parameters
    ----------
    xyz : (N, 3) float, metres, sensor frame (z up)
    """
    xyz = np.asarray(xyz, np.float64)
    return np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))


def rows_by_elevation(group: np.ndarray, xyz: np.ndarray) -> tuple[np.ndarray, int]:
    """Lattice rows for groups of points (a file's ring numbers, a scan's sweeps), ordered by
    their median elevation, highest first: lattice rows that neighbour are beams that
    neighbour.

    Parameters
    ----------
    group : (N,) int, the group of every point, in any numbering
    xyz : (N, 3) float, metres, sensor frame

    Returns
    -------
    row : (N,) int64, 0 for the highest group
    rows : the number of groups
    """
    values, index = np.unique(group, return_inverse=True)
    elevation = point_elevations_deg(xyz)
    order = np.argsort(index, kind="stable")
    starts = np.searchsorted(index[order], np.arange(len(values)))
    stops = np.append(starts[1:], len(order))
    median = np.array(
        [np.median(elevation[order[a:b]]) for a, b in zip(starts, stops, strict=True)]
    )
    rank = np.empty(len(values), np.int64)
    rank[np.argsort(-median, kind="stable")] = np.arange(len(values))
    return rank[index], len(values)


def rings_from_elevation(xyz: np.ndarray, elevations_deg: np.ndarray) -> np.ndarray:
    """The beam of every point: the one of the nearest elevation in the table, the table first
    moved to where the frame's own beams lie (a unit's calibration moves each beam off the
    datasheet's angle, at times by half the spacing to the next).

    The beams the frame shows (:func:`beams_from_points`) are matched to the table in order
    (:func:`match_beams`); each matched beam takes its measured elevation, the others keep the
    datasheet's, moved as their nearest matched neighbours moved. Exact where the beams leave
    from one origin; a beam's vertical offset on the sensor's head (a centimetre or two) moves
    a point at 3 m by up to 0.4 degrees, so near points may land one row off.

    Parameters
    ----------
    xyz : (N, 3) float, metres, sensor frame
    elevations_deg : (R,) float, the beams' elevations, highest first

    Returns
    -------
    (N,) int64, 0 for the highest beam
    """
    xyz = np.asarray(xyz, np.float64)
    table = np.asarray(elevations_deg, np.float64)
    spacing = float(np.min(-np.diff(table)))
    try:
        found = beams_from_points(xyz, min_spacing_deg=spacing / 4)
    except SourceFormatError:
        return _nearest_beam(point_elevations_deg(xyz), table)
    matched = match_beams(table, found, tolerance_deg=0.75 * spacing)
    shift = np.full(len(table), np.nan)
    shift[matched >= 0] = found[matched[matched >= 0]] - table[matched >= 0]
    known = np.flatnonzero(np.isfinite(shift))
    if len(known):
        shift = np.interp(np.arange(len(table)), known, shift[known])
        moved = table + shift
        if np.all(np.diff(moved) < 0):  # still one beam below the other
            table = moved
    return _nearest_beam(point_elevations_deg(xyz), table)


def match_beams(table: np.ndarray, found: np.ndarray, tolerance_deg: float) -> np.ndarray:
    """Match the beams a frame shows to a beam table, in order (no two crossing), as many as
    possible within ``tolerance_deg`` and, among those, nearest in total.

    Parameters
    ----------
    table : (R,) float, degrees, highest first
    found : (M,) float, degrees, highest first
    tolerance_deg : the most a matched pair may differ

    Returns
    -------
    (R,) int64, the index into ``found`` matched to each beam of the table, -1 for none
    """
    r, m = len(table), len(found)
    # best[i, j]: (matches, -cost) of table[:i] against found[:j], as one score.
    big = 1e6
    score = np.zeros((r + 1, m + 1))
    step = np.zeros((r + 1, m + 1), np.int8)  # 0: skip a table beam, 1: skip found, 2: match
    for i in range(1, r + 1):
        for j in range(1, m + 1):
            gap = abs(table[i - 1] - found[j - 1])
            options = (
                score[i - 1, j],
                score[i, j - 1],
                score[i - 1, j - 1] + big - gap if gap <= tolerance_deg else -np.inf,
            )
            step[i, j] = int(np.argmax(options))
            score[i, j] = options[step[i, j]]
    matched = np.full(r, -1, np.int64)
    i, j = r, m
    while i > 0 and j > 0:
        if step[i, j] == 2:
            matched[i - 1] = j - 1
            i, j = i - 1, j - 1
        elif step[i, j] == 0:
            i -= 1
        else:
            j -= 1
    return matched


def _nearest_beam(el: np.ndarray, table: np.ndarray) -> np.ndarray:
    """(N,) int64 index into ``table`` (R,) highest first of the elevation nearest each of
    ``el`` (N,), degrees."""
    ascending = table[::-1]
    right = np.clip(np.searchsorted(ascending, el), 1, len(table) - 1)
    nearer_left = (el - ascending[right - 1]) < (ascending[right] - el)
    index_ascending = np.where(nearer_left, right - 1, right)
    return (len(table) - 1 - index_ascending).astype(np.int64)


#: Points nearer than this (metres, horizontally) are left out when beams are found from a
#: frame's own elevations: a beam's offset on the sensor's head blurs their elevation.
BEAM_SEARCH_MIN_RANGE_M = 8.0
#: Elevation bins of the histogram the beams are found in, degrees.
BEAM_SEARCH_BIN_DEG = 0.01


def beams_from_points(xyz: np.ndarray, min_spacing_deg: float = 0.1) -> np.ndarray:
    """The beams' elevations of one frame without a beam table: the peaks of the elevation
    histogram of its points beyond :data:`BEAM_SEARCH_MIN_RANGE_M`.

    Parameters
    ----------
    xyz : (N, 3) float, metres, sensor frame
    min_spacing_deg : two beams are at least this far apart

    Returns
    -------
    (R,) float64 elevations, highest first

    Raises
    ------
    SourceFormatError
        Fewer than two beams stand out (too few far points): give a sensor or a beam table.
    """
    xyz = np.asarray(xyz, np.float64)
    far = np.hypot(xyz[:, 0], xyz[:, 1]) >= BEAM_SEARCH_MIN_RANGE_M
    el = point_elevations_deg(xyz[far])
    if len(el) < 100:
        raise SourceFormatError(
            f"only {len(el)} points lie {BEAM_SEARCH_MIN_RANGE_M:g} m or more from the sensor: "
            "too few to find its beams; give --sensor or --beams"
        )
    edges = np.arange(
        el.min() - BEAM_SEARCH_BIN_DEG, el.max() + 2 * BEAM_SEARCH_BIN_DEG, BEAM_SEARCH_BIN_DEG
    )
    counts, _ = np.histogram(el, edges)
    smooth = np.convolve(counts, np.ones(3) / 3, mode="same")
    peaks, _ = find_peaks(
        smooth,
        distance=max(1, int(round(min_spacing_deg / BEAM_SEARCH_BIN_DEG))),
        prominence=max(2.0, 0.02 * float(smooth.max())),
    )
    if len(peaks) < 2:
        raise SourceFormatError(
            "no beams stand out in the points' elevations; give --sensor or --beams"
        )
    return (edges[peaks] + BEAM_SEARCH_BIN_DEG / 2)[::-1].copy()
