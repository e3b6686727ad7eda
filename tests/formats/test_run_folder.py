"""The run folder object: its paths, its format checks and run.json as typed values."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from guardrail_core.errors import (
    InvalidOptionError,
    NoReconstructionError,
    NotARunFolderError,
    ReconstructionFormatVersionError,
    RunFolderError,
    RunFormatVersionError,
)
from guardrail_core.formats.reconstruction_folder import RECONSTRUCTION_FORMAT_VERSION
from guardrail_core.formats.run_folder import RUN_FORMAT_VERSION, load_run
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.formats.run_info import RunInfo
from guardrail_core.reconstruct.run_models import load_run_models


def _run_json_only(run_path: Path, out: Path, **changes: object) -> Path:
    """A folder holding only a copy of the run's run.json, with ``changes`` applied."""
    out.mkdir()
    data = json.loads((run_path / "run.json").read_text())
    data.update(changes)
    (out / "run.json").write_text(json.dumps(data))
    return out


def _models_json_only(run_path: Path, out: Path, **changes: object) -> Path:
    """A run folder whose reconstruction holds only a copy of models.json, with ``changes``."""
    _run_json_only(run_path, out)
    (out / "reconstruction").mkdir()
    data = json.loads((run_path / "reconstruction" / "models.json").read_text())
    data.update(changes)
    (out / "reconstruction" / "models.json").write_text(json.dumps(data))
    return out


def test_a_folder_without_run_json_is_not_a_run_folder(tmp_path: Path, drive_path: Path) -> None:
    for folder in (tmp_path, drive_path, tmp_path / "missing"):
        with pytest.raises(NotARunFolderError, match="not a run folder .*guardrail process"):
            RunFolder.open(folder)
        with pytest.raises(NotARunFolderError):
            load_run(folder)
        assert not RunFolder(folder).exists()
    (tmp_path / "run.json").write_text("{not json")
    with pytest.raises(RunFolderError, match="not valid JSON"):
        RunFolder.open(tmp_path)


@pytest.mark.parametrize("version", [RUN_FORMAT_VERSION + 1, 3, 2, 1, None, "4", 4.0, True])
def test_another_run_format_version_is_refused_by_name(
    run_path: Path, tmp_path: Path, version: object
) -> None:
    folder = _run_json_only(run_path, tmp_path / "run", format_version=version)
    with pytest.raises(RunFormatVersionError, match=f"run format version {version!r}") as caught:
        RunFolder.open(folder)
    assert "reads 4 (written by guardrail 0.2.0 and later)" in str(caught.value)
    assert str(folder / "run.json") in str(caught.value)


def test_a_format_3_run_folder_is_refused_and_says_to_process_again(
    run_path: Path, tmp_path: Path
) -> None:
    """Format 3 (a JPEG of every crop in crops/) was written only before 0.2.0, the first
    release; it is not read."""
    assert RUN_FORMAT_VERSION == 4
    folder = tmp_path / "run3"
    shutil.copytree(run_path, folder)
    info = json.loads((folder / "run.json").read_text())
    (folder / "run.json").write_text(json.dumps({**info, "format_version": 3}))
    (folder / "crops").mkdir()
    with pytest.raises(RunFormatVersionError, match="run format version 3") as caught:
        load_run(folder)
    assert "process the drive again with `guardrail process" in str(caught.value)


@pytest.mark.parametrize("version", [RECONSTRUCTION_FORMAT_VERSION + 1, 0, None])
def test_another_reconstruction_format_version_is_refused_by_name(
    run_path: Path, tmp_path: Path, version: object
) -> None:
    folder = _models_json_only(run_path, tmp_path / "run", format_version=version)
    RunFolder.open(folder)  # the run itself is fine
    with pytest.raises(
        ReconstructionFormatVersionError, match=f"reconstruction format {version!r}"
    ):
        load_run_models(folder)
    with pytest.raises(ReconstructionFormatVersionError, match="guardrail reconstruct"):
        RunFolder(folder).reconstruction.read_models()


def test_a_run_without_reconstruction_says_so(run_path: Path, tmp_path: Path) -> None:
    folder = RunFolder.open(_run_json_only(run_path, tmp_path / "run"))
    assert not folder.reconstruction.exists()
    assert folder.reconstruction.mesh_files() == {} and folder.reconstruction.output_files() == {}
    with pytest.raises(NoReconstructionError, match="no reconstruction"):
        load_run_models(folder)


def test_damaged_models_json_is_a_run_folder_error(run_path: Path, tmp_path: Path) -> None:
    folder = _models_json_only(run_path, tmp_path / "run", runs=[{"run_id": 0}])
    with pytest.raises(RunFolderError, match="not a reconstructed run"):
        load_run_models(folder)
    folder = _models_json_only(run_path, tmp_path / "run2", params={"pipez": {}})
    with pytest.raises(RunFolderError, match="parameters this version cannot read"):
        load_run_models(folder)


def test_the_paths_of_a_run_folder(run_path: Path) -> None:
    folder = RunFolder.open(run_path)
    assert folder.run_file == run_path / "run.json"
    assert {p.name for p in folder.parts()} == {
        "run.json", "points", "segments.npz", "segments.csv", "timings.json",
        "embeddings.npy",
    }  # fmt: skip
    rec = folder.reconstruction
    assert rec.root == run_path / "reconstruction"
    assert rec.mesh_path(3, "ply") == run_path / "reconstruction" / "meshes" / "run_003.ply"
    with pytest.raises(InvalidOptionError, match="mesh format"):
        rec.mesh_path(3, "stl")
    models = load_run_models(folder)
    for fmt in ("glb", "ply", "obj"):
        meshes = rec.mesh_files(fmt)
        assert meshes == {r.run_id: rec.mesh_path(r.run_id, fmt) for r in models.runs}
        assert all(path.is_file() for path in meshes.values())
    names = set(rec.output_files())
    assert {"inventory.csv", "inventory.geojson", "meshes/guardrails.glb"} <= names
    assert {f"meshes/{p.name}" for p in rec.mesh_files("obj").values()} <= names
    assert "models.json" not in names and "superimposed.npz" not in names


def test_run_json_round_trips_through_run_info(run_path: Path, tmp_path: Path) -> None:
    document = json.loads((run_path / "run.json").read_text())
    info = RunFolder.open(run_path).info()
    assert info.to_json() == document and list(info.to_json()) == list(document)
    assert RunInfo.from_json(document) == info == load_run(run_path).info
    assert info.counts.crops.ok + info.counts.crops.no_image + info.counts.crops.too_small == (
        info.counts.segments
    )
    broken = {k: v for k, v in document.items() if k != "counts"}
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "run.json").write_text(json.dumps(broken))
    with pytest.raises(RunFolderError, match="expected a member 'counts'"):
        RunFolder.open(folder).info()


def test_a_missing_table_is_named(run_path: Path, tmp_path: Path) -> None:
    folder = tmp_path / "run"
    shutil.copytree(run_path, folder, ignore=shutil.ignore_patterns("reconstruction"))
    (folder / "segments.npz").unlink()
    with pytest.raises(RunFolderError, match="segments.npz"):
        load_run(folder)
