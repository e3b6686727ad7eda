"""The points a reconstruction needs, gathered from a drive's tiles one tile at a time.

The reconstruction uses a run's guardrail points and the road-surface points within
``runs.ground_reach_m`` (horizontally) of one of them
(:func:`guardrail_core.reconstruct.pipeline.split_runs`); no other point. A survey's drive does
not fit in memory whole, so :func:`gather_reconstruction_points` reads the tiles twice, one at a
time: first for the guardrail points, then for the road points near any of them. Memory holds
one tile, the guardrail points and the road points near them.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from scipy.spatial import cKDTree

from guardrail_core.errors import RunFolderError
from guardrail_core.formats.drive import DriveSource
from guardrail_core.formats.run_folder import POINT_ROAD
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.reconstruct.pipeline import guardrail_mask


def gather_reconstruction_points(
    source: DriveSource, run: RunFolder, label: np.ndarray, reach_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Every guardrail point of ``run`` and every road point within ``reach_m`` of one.

    Parameters
    ----------
    source : the run's drive, opened (:func:`guardrail_core.formats.drive.open_drive`)
    run : the run folder (its per-tile point segments)
    label : (S,) bool, the segments' labels (True: guardrail)
    reach_m : metres, horizontally (``runs.ground_reach_m``)

    Returns
    -------
    xyz : (K, 3) float64, local frame, in drive order
    point_segment : (K,) int32, each point's segment (``POINT_ROAD`` for the road points), as
        :func:`guardrail_core.reconstruct.writing.reconstruct_into` takes them

    Raises
    ------
    RunFolderError
        A tile of the run holds another number of points than the drive's tile (another drive).
    """
    if run.point_tiles() != len(source.tiles):
        raise RunFolderError(
            f"{run.root}: made from a drive of {run.point_tiles()} tiles, but {source.root} has "
            f"{len(source.tiles)}; give the run's drive with --drive"
        )
    guardrail_xyz = np.concatenate(
        [xyz[guardrail_mask(segment, label)] for xyz, segment in _tiles(source, run)]
        or [np.zeros((0, 3))]
    )
    tree = cKDTree(guardrail_xyz[:, :2]) if len(guardrail_xyz) else None
    kept_xyz, kept_segment = [], []
    for xyz, segment in _tiles(source, run):
        keep = guardrail_mask(segment, label)
        road = np.flatnonzero(segment == POINT_ROAD)
        if tree is not None and len(road):
            # distance_upper_bound excludes its own value: nextafter keeps reach_m itself.
            distance, _ = tree.query(
                xyz[road, :2], distance_upper_bound=np.nextafter(reach_m, np.inf)
            )
            keep[road[distance <= reach_m]] = True
        kept_xyz.append(xyz[keep])
        kept_segment.append(segment[keep])
    return (
        np.concatenate(kept_xyz or [np.zeros((0, 3))]),
        np.concatenate(kept_segment or [np.zeros(0, np.int32)]).astype(np.int32),
    )


def _tiles(source: DriveSource, run: RunFolder) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(n, 3) xyz and (n,) point segments of each drive tile in turn."""
    for tile in range(len(source.tiles)):
        points, _ = source.read_tiles([tile])
        segment = run.point_segment_tile(tile)
        if len(segment) != len(points):
            raise RunFolderError(
                f"{run.root}: its tile {tile} holds {len(segment)} points, but the drive "
                f"{source.root} has {len(points)} there; give the run's drive with --drive"
            )
        yield points.xyz, segment
