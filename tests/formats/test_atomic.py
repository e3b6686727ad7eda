"""The one atomic writer (``formats.atomic``): outputs whole or not at all, never over an input.

The per-command cases (each command with its input inside its output) live in the commands'
own test files; these are the writer's rules on small files and folders."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from guardrail_core.errors import (
    InputInsideOutputError,
    OutputExistsError,
    OutputKindError,
    OutputSymlinkError,
)
from guardrail_core.formats.atomic import (
    FILE_MODE,
    FOLDER_MODE,
    FSYNC_EACH_MAX_FILES,
    atomic_file,
    atomic_write,
    check_output,
    staged_folder,
)
from tests.file_tree import file_tree


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


# --------------------------------------------------------------------------------- one file


def test_atomic_write_writes_whole_files_with_mode_0644(tmp_path: Path) -> None:
    out = tmp_path / "sub" / "table.csv"
    atomic_write(out, "a,b\r\n1,2\r\n")  # text goes as UTF-8 with its newlines untouched
    assert out.read_bytes() == b"a,b\r\n1,2\r\n"
    assert _mode(out) == FILE_MODE == 0o644
    with pytest.raises(OutputExistsError, match="--overwrite"):
        atomic_write(out, b"other")
    assert out.read_bytes() == b"a,b\r\n1,2\r\n"
    atomic_write(out, b"\x00\x01", overwrite=True)
    assert out.read_bytes() == b"\x00\x01"
    assert [p.name for p in out.parent.iterdir()] == ["table.csv"]
    with pytest.raises(TypeError, match="dict"):
        atomic_write(out, {"not": "bytes"}, overwrite=True)  # type: ignore[arg-type]
    assert out.read_bytes() == b"\x00\x01"


def test_an_error_while_writing_a_file_keeps_the_old_one_and_no_temporary(tmp_path: Path) -> None:
    out = tmp_path / "result.laz"
    out.write_bytes(b"the previous result")
    with pytest.raises(OSError, match="disk full"), atomic_file(out, overwrite=True) as f:
        f.write(b"LASF half a file")
        raise OSError("disk full")
    assert out.read_bytes() == b"the previous result"
    assert [p.name for p in tmp_path.iterdir()] == ["result.laz"]


def test_a_file_output_must_not_be_a_folder_or_a_link(tmp_path: Path) -> None:
    (tmp_path / "folder.laz").mkdir()
    with pytest.raises(OutputKindError, match="is a folder"):
        atomic_write(tmp_path / "folder.laz", b"x", overwrite=True)
    (tmp_path / "real.txt").write_text("kept")
    (tmp_path / "link.txt").symlink_to(tmp_path / "real.txt")
    with pytest.raises(OutputSymlinkError, match="symbolic link"):
        atomic_write(tmp_path / "link.txt", b"x", overwrite=True)
    assert (tmp_path / "real.txt").read_text() == "kept"
    assert (tmp_path / "link.txt").is_symlink()


def test_a_file_output_that_is_an_input_is_refused(tmp_path: Path) -> None:
    source = tmp_path / "points.laz"
    source.write_bytes(b"the drive's points")
    with pytest.raises(InputInsideOutputError, match="is the input"):
        atomic_write(source, b"x", overwrite=True, inputs=[source])
    # The same file reached through a link to its folder is still the input.
    (tmp_path / "alias").symlink_to(tmp_path)
    with pytest.raises(InputInsideOutputError, match="is the input"):
        atomic_write(tmp_path / "alias" / "points.laz", b"x", overwrite=True, inputs=[source])
    assert source.read_bytes() == b"the drive's points"


# ------------------------------------------------------------------------------ the folder


def test_a_staged_folder_appears_whole_with_mode_0755(tmp_path: Path) -> None:
    out = tmp_path / "parent" / "drive"
    with staged_folder(out) as staging:
        assert staging.parent == out.parent and staging.name.startswith(".drive.partial-")
        assert not out.exists()  # nothing at the target while the work goes on
        (staging / "images").mkdir()
        (staging / "images" / "0.jpg").write_bytes(b"jpeg")
        (staging / "drive.json").write_text("{}")
    assert file_tree(out) == {"drive.json": b"{}", "images": None, "images/0.jpg": b"jpeg"}
    assert _mode(out) == FOLDER_MODE == 0o755
    assert [p.name for p in out.parent.iterdir()] == ["drive"]


def test_a_staged_folder_of_many_files_is_flushed_with_one_sync(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    synced: list[str] = []
    monkeypatch.setattr(os, "sync", lambda: synced.append("sync"))
    with staged_folder(tmp_path / "run") as staging:
        for i in range(FSYNC_EACH_MAX_FILES + 1):
            (staging / f"{i:06d}.jpg").write_bytes(b"jpeg")
    assert synced == ["sync"]
    assert len(list((tmp_path / "run").iterdir())) == FSYNC_EACH_MAX_FILES + 1


def test_an_existing_folder_needs_overwrite_and_is_replaced_whole(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("operator notes")
    with pytest.raises(OutputExistsError, match="--overwrite"), staged_folder(out):
        pytest.fail("the block must not run")  # refused before any work
    assert file_tree(out) == {"notes.txt": b"operator notes"}
    with staged_folder(out, overwrite=True) as staging:
        (staging / "run.json").write_text("new")
    assert file_tree(out) == {"run.json": b"new"}
    assert [p.name for p in tmp_path.iterdir()] == ["run"]  # the old one moved aside and gone
    empty = tmp_path / "empty"
    empty.mkdir()
    with staged_folder(empty) as staging:  # an empty folder is no one's work: no overwrite needed
        (staging / "a").write_text("a")
    assert file_tree(empty) == {"a": b"a"}


def test_an_error_in_the_middle_leaves_the_old_folder_and_no_staging(tmp_path: Path) -> None:
    out = tmp_path / "model"
    out.mkdir()
    (out / "weights.npz").write_bytes(b"old weights")
    with pytest.raises(RuntimeError, match="half way"):
        with staged_folder(out, overwrite=True) as staging:
            (staging / "weights.npz").write_bytes(b"half")
            raise RuntimeError("half way")
    assert file_tree(out) == {"weights.npz": b"old weights"}
    assert [p.name for p in tmp_path.iterdir()] == ["model"]
    with pytest.raises(KeyboardInterrupt), staged_folder(tmp_path / "new") as staging:
        (staging / "x").write_text("x")
        raise KeyboardInterrupt
    assert [p.name for p in tmp_path.iterdir()] == ["model"]


def test_a_failed_rename_puts_the_old_folder_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "drive"
    out.mkdir()
    (out / "drive.json").write_text("old")
    rename = os.rename

    def failing(src: str | os.PathLike, dst: str | os.PathLike) -> None:
        if Path(src).name.startswith(".drive.partial-"):
            raise OSError("no space left")
        rename(src, dst)

    monkeypatch.setattr(os, "rename", failing)
    with pytest.raises(OSError, match="no space"), staged_folder(out, overwrite=True) as staging:
        (staging / "drive.json").write_text("new")
    assert file_tree(out) == {"drive.json": b"old"}
    assert [p.name for p in tmp_path.iterdir()] == ["drive"]


def test_an_output_written_meanwhile_is_not_replaced_without_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "drive"
    with pytest.raises(OutputExistsError), staged_folder(out) as staging:
        (staging / "drive.json").write_text("mine")
        out.mkdir()  # another command wrote the output while this one worked
        (out / "drive.json").write_text("theirs")
    assert file_tree(out) == {"drive.json": b"theirs"}
    assert [p.name for p in tmp_path.iterdir()] == ["drive"]


def test_a_folder_output_must_not_be_a_file_or_a_link(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("kept")
    with (
        pytest.raises(OutputKindError, match="not a folder"),
        staged_folder(tmp_path / "file", overwrite=True),
    ):
        pytest.fail("the block must not run")
    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real")
    with pytest.raises(OutputSymlinkError), staged_folder(tmp_path / "link", overwrite=True):
        pytest.fail("the block must not run")
    assert (tmp_path / "file").read_text() == "kept" and (tmp_path / "link").is_symlink()


# ------------------------------------------------------------------------------ the inputs


@pytest.fixture
def sequence(tmp_path: Path) -> Path:
    """An input folder with a file and a sub-folder, inside the would-be output ``tmp/out``."""
    root = tmp_path / "out" / "seq"
    (root / "velodyne").mkdir(parents=True)
    (root / "calib.txt").write_text("Tr: 1 0 0 0 0 1 0 0 0 0 1 0")
    (root / "velodyne" / "000000.bin").write_bytes(b"\x00" * 16)
    return root


def test_an_output_holding_an_input_is_refused_and_the_input_survives(
    sequence: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    before = file_tree(out)
    for inputs in ([sequence], [sequence / "calib.txt"], [sequence / "velodyne"]):
        with pytest.raises(InputInsideOutputError, match="would delete the input"):
            with staged_folder(out, overwrite=True, inputs=inputs):
                pytest.fail("the block must not run")
    # The output is the input folder itself, or one of its folders.
    for target in (sequence, sequence / "velodyne"):
        with pytest.raises(InputInsideOutputError, match="is the input"):
            check_output(target, folder=True, overwrite=True, inputs=[target])
    # An input named through a link is resolved first.
    (tmp_path / "alias").symlink_to(sequence)
    with pytest.raises(InputInsideOutputError):
        check_output(out, folder=True, overwrite=True, inputs=[tmp_path / "alias"])
    assert file_tree(out) == before
    assert isinstance(InputInsideOutputError("x"), OutputExistsError)


def test_an_output_inside_an_input_folder_may_be_written_but_not_replaced(
    sequence: Path,
) -> None:
    inside = sequence / "drive"
    with staged_folder(inside, inputs=[sequence]) as staging:  # new: deletes nothing
        (staging / "drive.json").write_text("{}")
    with pytest.raises(InputInsideOutputError, match="inside the input folder"):
        check_output(inside, folder=True, overwrite=True, inputs=[sequence])
    # Named by its parts instead, the folder's other content is no input: replacing is fine.
    parts = [sequence / "calib.txt", sequence / "velodyne"]
    with staged_folder(inside, overwrite=True, inputs=parts) as staging:
        (staging / "drive.json").write_text("again")
    assert (inside / "drive.json").read_text() == "again"
    assert (sequence / "calib.txt").is_file() and (sequence / "velodyne" / "000000.bin").is_file()
