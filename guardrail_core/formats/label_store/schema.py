"""The label store's SQLite tables: the label values, the schema, and opening a store file.

Opening creates the tables of a new store, or checks an existing one (schema version, tables,
point count) without writing to a file that is not a label store.
"""

from __future__ import annotations

import sqlite3
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from guardrail_core.errors import LabelStoreError

if TYPE_CHECKING:
    from guardrail_core.formats.label_store.sparse import SparseLabels

LABEL_OTHER = 0
LABEL_GUARDRAIL = 1
UNLABELLED = -1
LABEL_NAMES = {LABEL_OTHER: "other", LABEL_GUARDRAIL: "guardrail"}
#: A drive's label store is ``DRIVE/review/labels.sqlite`` unless told otherwise.
REVIEW_DIR = "review"
LABELS_FILE = "labels.sqlite"
#: Version of the tables; a store of a newer version is refused.
SCHEMA_VERSION = 1

SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL) WITHOUT ROWID;
CREATE TABLE batches (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    at TEXT NOT NULL,
    who TEXT NOT NULL,
    model_version TEXT,
    kind TEXT NOT NULL CHECK (kind IN ('label', 'undo')),
    label INTEGER CHECK (label IN (0, 1)),
    segments TEXT NOT NULL,
    note TEXT NOT NULL,
    n_points INTEGER NOT NULL,
    undoes INTEGER REFERENCES batches (id),
    undone_by INTEGER REFERENCES batches (id)
);
CREATE INDEX batches_by_who ON batches (who, id);
CREATE TABLE changes (
    batch INTEGER NOT NULL REFERENCES batches (id),
    old INTEGER NOT NULL CHECK (old IN (-1, 0, 1)),
    new INTEGER NOT NULL CHECK (new IN (-1, 0, 1)),
    n INTEGER NOT NULL,
    points BLOB NOT NULL,
    prev BLOB NOT NULL,
    PRIMARY KEY (batch, old, new)
) WITHOUT ROWID;
CREATE TABLE labels (
    point INTEGER PRIMARY KEY,
    label INTEGER NOT NULL CHECK (label IN (0, 1)),
    batch INTEGER NOT NULL
) WITHOUT ROWID;
"""
TABLES = {"meta", "batches", "changes", "labels"}


def default_store_path(drive_root: str | Path) -> Path:
    """Where the review app keeps a drive's labels: ``DRIVE/review/labels.sqlite``."""
    return Path(drive_root) / REVIEW_DIR / LABELS_FILE


def now() -> str:
    """Current UTC time, ISO 8601 with milliseconds."""
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def table_names(conn: sqlite3.Connection) -> set[str]:
    """The tables of the database, SQLite's own left out."""
    rows = conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'").fetchall()
    return {name for (name,) in rows if not name.startswith("sqlite_")}


def open_tables(conn: sqlite3.Connection, path: Path, *, n_points: int, drive_name: str) -> str:
    """Check an existing store or create the tables of a new one; returns the stored drive name.

    Parameters
    ----------
    conn : an autocommit connection (``isolation_level=None``) to the store file ``path``
    n_points : the drive's point count, recorded in a new store and checked in an existing one
    drive_name : recorded in a new store

    Raises
    ------
    LabelStoreError
        A SQLite database that is not a label store, of another schema version, with tables
        missing, or made for another number of points.
    sqlite3.DatabaseError
        The file is not a SQLite database (the caller names the error).
    """
    tables = table_names(conn)  # reads the header first: a foreign file is refused unchanged
    if not tables:
        conn.execute("PRAGMA journal_mode=WAL")  # persistent in the file
        conn.execute("BEGIN IMMEDIATE")
        try:
            if not table_names(conn):  # nobody created it meanwhile
                for statement in SCHEMA.split(";"):  # not executescript: it would COMMIT
                    if statement.strip():
                        conn.execute(statement)
                meta = {
                    "schema_version": str(SCHEMA_VERSION),
                    "n_points": str(n_points),
                    "drive_name": drive_name,
                    "created": now(),
                }
                conn.executemany("INSERT INTO meta (key, value) VALUES (?, ?)", meta.items())
            conn.execute("COMMIT")
        except BaseException:
            conn.execute("ROLLBACK")
            raise
        tables = table_names(conn)
    if "meta" not in tables:
        raise LabelStoreError(
            f"{path}: expected a label store, got a SQLite database with the tables "
            f"{sorted(tables)} (no meta table)"
        )
    meta = dict(conn.execute("SELECT key, value FROM meta").fetchall())
    version = meta.get("schema_version")
    if version is None or not version.isdigit():
        raise LabelStoreError(
            f"{path}: expected a label store, got a meta table without a schema_version "
            f"(got {version!r})"
        )
    if int(version) != SCHEMA_VERSION:
        newer = int(version) > SCHEMA_VERSION
        raise LabelStoreError(
            f"{path}: label store schema version {version}, this version of guardrail "
            f"reads {SCHEMA_VERSION}"
            + ("; written by a newer version, update guardrail" if newer else "")
        )
    missing = TABLES - tables
    if missing:
        raise LabelStoreError(f"{path}: damaged label store, tables missing: {sorted(missing)}")
    stored = meta.get("n_points", "")
    if not stored.isdigit() or int(stored) != n_points:
        raise LabelStoreError(
            f"{path}: the label store was made for a drive of {stored} points, "
            f"got a drive of {n_points} points (another drive?)"
        )
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute("PRAGMA synchronous=FULL")
    return meta.get("drive_name", "")


def read_labels(conn: sqlite3.Connection, path: Path, n_points: int) -> SparseLabels:
    """The labels table: every labelled point and its label.

    Raises
    ------
    LabelStoreError
        The table names points outside ``[0, n_points)``.
    """
    from guardrail_core.formats.label_store.sparse import SparseLabels  # it builds on this module

    rows = np.array(conn.execute("SELECT point, label FROM labels").fetchall(), np.int64)
    if len(rows) == 0:
        return SparseLabels(np.zeros(0, np.int64), np.zeros(0, np.int8))
    if rows[:, 0].min() < 0 or rows[:, 0].max() >= n_points:
        raise LabelStoreError(f"{path}: damaged label store: points outside [0, {n_points})")
    return SparseLabels(rows[:, 0], rows[:, 1])
