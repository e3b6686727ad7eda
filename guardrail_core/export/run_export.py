"""What every map export (CityJSON, OpenDRIVE, 3D Tiles, OpenStreetMap) reads from a run.

A run folder's reconstruction (its run models and the parameters they came from), the
inventory's rows, each run's meshes by part, and from the run's drive its CRS, local origin and
trajectory. Coordinates here are the drive's **local** frame in metres unless a name says
``map``: map coordinates are local + :attr:`ExportSource.origin` (float64), in the drive's CRS.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from guardrail_core.errors import ExportError
from guardrail_core.formats.drive import drive_parts, open_drive
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.reconstruct.assemble import run_parts
from guardrail_core.reconstruct.inventory import inventory_rows
from guardrail_core.reconstruct.inventory_row import InventoryRow
from guardrail_core.reconstruct.model import RunModel
from guardrail_core.reconstruct.run_models import load_run_models
from guardrail_core.reconstruct.sweep import SweepParams


@dataclass(frozen=True)
class ExportSource:
    """A run's reconstruction with its drive's frame, ready to be written in a map format.

    Attributes
    ----------
    run_dir, drive_dir : the run folder and its drive folder
    drive_name : the drive folder's name (a source attribute in the exports)
    crs : the drive's CRS as ``drive.json`` names it (e.g. ``EPSG:6677``)
    origin : (3,) float64, map coordinates of the local frame's origin
    runs : every reconstructed run, in run id order
    rows : the inventory row of each run, in the same order
        (:func:`guardrail_core.reconstruct.inventory.inventory_rows`: map coordinates)
    trajectory_time : (T,) float64 GPS seconds of the vehicle's poses
    trajectory_xyz : (T, 3) float64 local positions of the vehicle's reference point
    reference_height_m : height of that reference point above the road (``drive.json``)
    sweep : the sweep parameters the meshes were made with (colours, pole caps)
    inputs : every file and folder the export reads (for
        :func:`guardrail_core.formats.atomic.check_output`)
    """

    run_dir: Path
    drive_dir: Path
    drive_name: str
    crs: str
    origin: np.ndarray
    runs: tuple[RunModel, ...]
    rows: list[InventoryRow]
    trajectory_time: np.ndarray
    trajectory_xyz: np.ndarray
    reference_height_m: float
    sweep: SweepParams
    inputs: list[Path]

    def parts(self, run: RunModel) -> dict[str, trimesh.Trimesh]:
        """A run's meshes by part (``"pipes"`` or ``"beam"``, and ``"poles"``), local frame,
        as :func:`guardrail_core.reconstruct.assemble.run_parts` builds them."""
        return run_parts(run, self.sweep)

    @property
    def georeferenced(self) -> bool:
        """Whether the CRS places the drive on the Earth: not a ``local: ...`` frame, as a KITTI
        odometry frame's velodyne frame is (``guardrail import kitti``)."""
        return not self.crs.lower().startswith("local")

    def to_map(self, local: np.ndarray) -> np.ndarray:
        """(..., 3) float64 map coordinates of (..., 3) local ones."""
        return np.asarray(local, np.float64) + self.origin


def load_export_source(run_dir: str | Path, drive_dir: str | Path | None = None) -> ExportSource:
    """Read what the map exports need from ``run_dir`` and its drive.

    Parameters
    ----------
    run_dir : a run folder with a reconstruction (``guardrail process`` or ``reconstruct``)
    drive_dir : the run's drive (default: ``run.json``'s ``drive.path``)

    Raises
    ------
    NoReconstructionError
        The run folder has no reconstruction.
    RunFolderError
        The run folder or its reconstruction cannot be read.
    DriveError
        The drive's ``drive.json`` or trajectory cannot be read.
    ExportError
        The drive names no CRS (map formats need one).
    """
    folder = RunFolder(Path(run_dir))
    models = load_run_models(folder)
    if drive_dir is None:
        drive_dir = Path(folder.info().drive.path)
    drive = open_drive(Path(drive_dir), with_truth=False)
    if not drive.crs:
        raise ExportError(f"{drive_dir}: drive.json names no CRS; map formats need one")
    origin = np.asarray(drive.origin, np.float64)
    runs = tuple(sorted(models.runs, key=lambda r: r.run_id))
    return ExportSource(
        run_dir=folder.root,
        drive_dir=Path(drive_dir),
        drive_name=Path(drive_dir).resolve().name,
        crs=str(drive.crs),
        origin=origin,
        runs=runs,
        rows=inventory_rows(runs, origin),
        trajectory_time=np.asarray(drive.trajectory.time, np.float64),
        trajectory_xyz=np.asarray(drive.trajectory.position, np.float64),
        reference_height_m=float(drive.trajectory.reference_height_m),
        sweep=models.params.sweep,
        inputs=[*folder.parts(), models.folder.models_file, *drive_parts(drive_dir)],
    )
