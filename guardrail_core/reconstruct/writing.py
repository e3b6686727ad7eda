"""Writes a reconstruction (:mod:`guardrail_core.reconstruct.pipeline`) into a run folder,
whole or not at all.

What it writes::

    RUN_DIR/reconstruction/
      models.json         format version, parameters, every run: poles, unit frames, unit model
      superimposed.npz    per run the superimposed unit points (unit coordinates), for re-runs
      inventory.geojson   one LineString per run along its poles, properties = the inventory row
      inventory.csv       the same rows for spreadsheets
      meshes/run_NNN.{glb,ply,obj}, meshes/guardrails.glb
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.errors import OutputExistsError
from guardrail_core.formats.atomic import staged_folder
from guardrail_core.formats.reconstruction_folder import (
    RECONSTRUCTION_FORMAT_VERSION,
    ReconstructionFolder,
    superimposed_points_key,
    superimposed_unit_key,
)
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.formats.run_info import ReconstructionSummary
from guardrail_core.io.meshes import write_meshes
from guardrail_core.reconstruct.assemble import run_mesh
from guardrail_core.reconstruct.inventory import (
    inventory_rows,
    write_inventory_csv,
    write_inventory_geojson,
)
from guardrail_core.reconstruct.model_json import run_model_to_json
from guardrail_core.reconstruct.pipeline import (
    Reconstruction,
    ReconstructionParams,
    guardrail_mask,
    reconstruct_guardrails,
)


def write_reconstruction(
    folder: Path,
    reconstruction: Reconstruction,
    *,
    params: ReconstructionParams,
    origin: np.ndarray,
    crs: str,
    seconds: float | None = None,
) -> ReconstructionSummary:
    """Write models, superimposed points, inventory and meshes into ``folder`` (a new or empty
    folder: a staging folder of :func:`guardrail_core.formats.atomic.staged_folder`).

    Returns
    -------
    A summary: counts of runs by status, the files written and ``seconds``.
    """
    folder = Path(folder)
    layout = ReconstructionFolder(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if any(folder.iterdir()):
        raise OutputExistsError(f"{folder}: is not empty; a reconstruction is written whole")
    runs = reconstruction.runs
    layout.models_file.write_text(
        json.dumps(
            {
                "format_version": RECONSTRUCTION_FORMAT_VERSION,
                "params": params.to_json(),
                "seconds": seconds,
                "runs": [run_model_to_json(r) for r in runs],
            },
            indent=1,
        )
        + "\n"
    )
    arrays: dict[str, Any] = {}
    for run, sup in zip(runs, reconstruction.superimposed, strict=True):
        if sup is not None:
            arrays[superimposed_points_key(run.run_id)] = sup.points.astype(np.float32)
            arrays[superimposed_unit_key(run.run_id)] = sup.unit_of_point.astype(np.int16)
    np.savez_compressed(layout.superimposed_file, **arrays)
    rows = inventory_rows(runs, origin)
    write_inventory_geojson(layout.inventory_geojson, rows, runs, origin, crs)
    write_inventory_csv(layout.inventory_csv, rows)
    made = reconstruction.meshes
    if made is None:
        meshes = {run.run_id: run_mesh(run, params.sweep) for run in runs if run.poles}
        mesh_files = write_meshes(layout.meshes_dir, meshes)
    else:
        meshes = {run_id: mesh for run_id, (mesh, _) in made.items()}
        exported = {run_id: files for run_id, (_, files) in made.items()}
        mesh_files = write_meshes(layout.meshes_dir, meshes, exported=exported)
    status = [row.status for row in rows]
    written = [layout.models_file, layout.superimposed_file, layout.inventory_geojson]
    written += [layout.inventory_csv, *(layout.meshes_dir / f for f in mesh_files)]
    return ReconstructionSummary(
        runs=len(runs),
        reconstructed=status.count("reconstructed"),
        poles_only=status.count("poles only"),
        not_reconstructed=status.count("not reconstructed"),
        files=tuple(path.relative_to(folder).as_posix() for path in written),
        seconds=seconds,
    )


def reconstruct_into(
    run_dir: Path,
    xyz: np.ndarray,
    point_segment: np.ndarray,
    label: np.ndarray,
    trajectory: np.ndarray,
    *,
    origin: np.ndarray,
    crs: str,
    params: ReconstructionParams = ReconstructionParams(),
    inputs: Iterable[str | os.PathLike] = (),
    progress: bool = False,
    on_run: Callable[[int, int], None] | None = None,
) -> ReconstructionSummary:
    """Reconstruct a run's guardrails and (re)place ``run_dir/reconstruction`` whole.

    The new reconstruction is written into a staging folder beside the old one and swapped in
    only when complete (:func:`guardrail_core.formats.atomic.staged_folder`), so a failure leaves
    the previous reconstruction as it was. ``inputs`` are the files the arrays came from (the
    drive's parts, :func:`guardrail_core.formats.drive.drive_parts`); they and the run's own
    tables must lie outside ``reconstruction/``, else
    :class:`~guardrail_core.errors.InputInsideOutputError` is raised before any work. ``on_run``:
    see :func:`reconstruct_guardrails`.
    """
    from guardrail_core.formats.run_folder import POINT_ROAD

    run_folder = RunFolder(run_dir)
    sources = [*run_folder.parts(), *inputs]
    target = run_folder.reconstruction.root
    with staged_folder(target, overwrite=True, inputs=sources) as staging:
        start = time.perf_counter()
        reconstruction = reconstruct_guardrails(
            xyz,
            guardrail_mask(point_segment, label),
            np.asarray(point_segment) == POINT_ROAD,
            trajectory,
            params=params,
            progress=progress,
            on_run=on_run,
        )
        seconds = round(time.perf_counter() - start, 4)
        summary = write_reconstruction(
            staging, reconstruction, params=params, origin=origin, crs=crs, seconds=seconds
        )
    return summary
