"""Snapshots of a folder's content, to assert that a refused or failed write changed nothing."""

from __future__ import annotations

from pathlib import Path


def file_tree(root: Path) -> dict[str, bytes | None]:
    """Every path under ``root`` (relative, POSIX) -> its bytes; None for a folder."""
    return {
        p.relative_to(root).as_posix(): None if p.is_dir() else p.read_bytes()
        for p in sorted(root.rglob("*"))
    }
