"""Run meshes written as GLB, PLY and OBJ and read back with trimesh."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from guardrail_core.errors import InvalidOptionError
from guardrail_core.io.meshes import SCENE_FILE, write_meshes
from guardrail_core.reconstruct.assemble import run_mesh
from guardrail_core.reconstruct.model import Pipe, Pole, RunModel, UnitModel
from guardrail_core.reconstruct.sweep import empty_mesh
from guardrail_core.reconstruct.unit_frame import UnitFrame


def _mesh(offset: float) -> trimesh.Trimesh:
    positions = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.1], [4.1, 0.2, 0.2]]) + [offset, 50.0, 0]
    poles = [Pole(p, 0.03, 1.0, 9) for p in positions]
    units = [UnitFrame.between(a, b) for a, b in zip(positions[:-1], positions[1:], strict=True)]
    pipe = Pipe(np.array([[0.0, 0.8, 0.0], [2.0, 0.8, 0.0]]), 0.024, "horizontal", 9)
    model = UnitModel("pipe", 2.0, (pipe,))
    return run_mesh(RunModel(1, poles, units, model, np.ones(2, bool), 100))


def _geometry(path) -> trimesh.Trimesh:
    loaded = trimesh.load(path, process=False)
    geometry = loaded.to_geometry() if isinstance(loaded, trimesh.Scene) else loaded
    assert isinstance(geometry, trimesh.Trimesh)
    return geometry


def test_round_trip_of_every_format(tmp_path):
    meshes = {3: _mesh(0.0), 12: _mesh(-300.0), 7: empty_mesh()}
    written = write_meshes(tmp_path / "meshes", meshes)
    expected = [f"run_{i:03d}.{fmt}" for i in (3, 12) for fmt in ("glb", "ply", "obj")]
    assert written == [*expected, SCENE_FILE]
    assert sorted(p.name for p in (tmp_path / "meshes").iterdir()) == sorted(written)
    for run_id in (3, 12):
        mesh = meshes[run_id]
        for fmt in ("glb", "ply", "obj"):
            back = _geometry(tmp_path / "meshes" / f"run_{run_id:03d}.{fmt}")
            assert len(back.faces) == len(mesh.faces), fmt
            np.testing.assert_allclose(back.bounds, mesh.bounds, atol=1e-5)  # GLB is float32
            if fmt != "obj":  # the OBJ reader may re-index vertices
                assert len(back.vertices) == len(mesh.vertices), fmt
    scene = trimesh.load(tmp_path / "meshes" / SCENE_FILE)
    assert set(scene.graph.nodes_geometry) == {"run_003", "run_012"}
    total = scene.to_geometry()
    assert len(total.faces) == len(meshes[3].faces) + len(meshes[12].faces)


def test_formats_are_chosen_and_checked(tmp_path):
    assert write_meshes(tmp_path, {1: _mesh(0.0)}, formats=("ply",)) == ["run_001.ply"]
    with pytest.raises(InvalidOptionError):
        write_meshes(tmp_path, {1: _mesh(0.0)}, formats=("stl",))


def test_no_runs_still_give_a_loadable_scene(tmp_path):
    assert write_meshes(tmp_path, {}) == [SCENE_FILE]
    scene = trimesh.load(tmp_path / SCENE_FILE)
    assert isinstance(scene, trimesh.Scene) and len(scene.geometry) == 0
