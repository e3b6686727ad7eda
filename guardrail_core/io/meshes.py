"""Reconstructed guardrail meshes as GLB, PLY and OBJ files (trimesh's exporters).

One file per run and format, ``run_NNN.<format>`` (NNN the run id, zero-padded to 3 digits),
and ``guardrails.glb``: one glTF scene with a node per run, named ``run_NNN``.

Coordinates are the drive's local frame in metres, exactly as the meshes came: add the drive's
origin (``drive.json``, float64) to a vertex to get map coordinates in the drive's CRS. The
origin is not applied here because GLB stores vertices as float32, which keeps about 7 digits:
map coordinates of 10^5-10^6 m would lose centimetres, local ones within a few km keep
sub-millimetre precision.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterable, Mapping
from pathlib import Path

import trimesh

from guardrail_core.errors import InvalidOptionError

MESH_FORMATS = ("glb", "ply", "obj")
SCENE_FILE = "guardrails.glb"


def run_file_stem(run_id: int) -> str:
    """``run_NNN``: the file stem and scene node name of run ``run_id``."""
    return f"run_{int(run_id):03d}"


def empty_glb() -> bytes:
    """A valid GLB (glTF 2.0 binary) holding one scene with no nodes (trimesh will not export it)."""
    doc = {"asset": {"version": "2.0", "generator": "guardrail_core"}, "scene": 0, "scenes": [{}]}
    chunk = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    chunk += b" " * (-len(chunk) % 4)  # JSON chunks are padded with spaces to 4 bytes
    total = 12 + 8 + len(chunk)
    return (
        struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<I4s", len(chunk), b"JSON") + chunk
    )


def _as_bytes(data: object) -> bytes:
    """What a trimesh exporter returned (bytes, or text as UTF-8), as bytes."""
    if isinstance(data, str):
        data = data.encode("utf-8")
    if not isinstance(data, bytes):
        raise TypeError(f"an exporter returned {type(data).__name__}, not bytes or text")
    return data


def _write(path: Path, data: object) -> None:
    """Write what a trimesh exporter returned."""
    path.write_bytes(_as_bytes(data))


def export_mesh_files(
    mesh: trimesh.Trimesh, formats: Iterable[str] = MESH_FORMATS
) -> dict[str, bytes]:
    """A run's mesh file in each format, as :func:`write_meshes` writes it: {format: bytes}
    (made where the mesh is made: a worker of ``guardrail process``)."""
    return {fmt: _as_bytes(mesh.export(file_type=fmt)) for fmt in formats}


def write_meshes(
    folder: Path,
    meshes: Mapping[int, trimesh.Trimesh],
    formats: Iterable[str] = MESH_FORMATS,
    exported: Mapping[int, Mapping[str, bytes]] | None = None,
) -> list[str]:
    """Write each run's mesh in every format, and all runs as one GLB scene.

    Parameters
    ----------
    folder : Path
        Created if missing; existing files of the same names are replaced. The files are
        written plainly: the caller writes into a staging folder
        (:func:`guardrail_core.formats.atomic.staged_folder`, as the reconstruction does), which
        makes the whole appear at once.
    meshes : {run id: trimesh.Trimesh}
        World-frame meshes, local coordinates in metres
        (:func:`guardrail_core.reconstruct.assemble.run_mesh`). Runs with an empty mesh are
        skipped (no file, no scene node).
    formats : iterable of "glb", "ply", "obj"
    exported : {run id: {format: bytes}}, files already made by :func:`export_mesh_files`
        (the others are exported here)

    Returns
    -------
    list of str
        The written files' paths relative to ``folder`` (POSIX), per-run files in run-id order,
        then ``guardrails.glb`` (written whenever "glb" is among the formats, even with no runs).
    """
    formats = tuple(formats)
    unknown = sorted(set(formats) - set(MESH_FORMATS))
    if unknown:
        raise InvalidOptionError(f"unknown mesh formats {unknown}; expected some of {MESH_FORMATS}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written: list[str] = []
    scene = trimesh.Scene()
    for run_id in sorted(meshes):
        mesh = meshes[run_id]
        if len(mesh.faces) == 0:
            continue
        stem = run_file_stem(run_id)
        for fmt in formats:
            name = f"{stem}.{fmt}"
            ready = (exported or {}).get(run_id, {}).get(fmt)
            _write(folder / name, ready if ready is not None else mesh.export(file_type=fmt))
            written.append(name)
        scene.add_geometry(mesh, node_name=stem, geom_name=stem)
    if "glb" in formats:
        data = scene.export(file_type="glb") if scene.geometry else empty_glb()
        _write(folder / SCENE_FILE, data)
        written.append(SCENE_FILE)
    return written
