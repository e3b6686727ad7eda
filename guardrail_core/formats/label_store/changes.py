"""The label store's change log: batches and their changes, recorded and walked back for an undo.

A batch's changes are one ``changes`` row per (old, new) pair, with the point indices and the
batches that had set each point's old value as little-endian int32 BLOBs (sorted by point), so
relabelling 100k points is a few rows. Every function here runs inside the caller's transaction.
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np

from guardrail_core.errors import LabelStoreError
from guardrail_core.formats.label_store.schema import (
    LABEL_GUARDRAIL,
    LABEL_OTHER,
    UNLABELLED,
    now,
)

_BLOB_DTYPE = np.dtype("<i4")  # point indices and batch ids in the changes' BLOBs


def to_blob(values: np.ndarray) -> bytes:
    """(K,) integers as a little-endian int32 BLOB."""
    return np.ascontiguousarray(values, _BLOB_DTYPE).tobytes()


def from_blob(data: bytes) -> np.ndarray:
    """(K,) int64 from a little-endian int32 BLOB."""
    return np.frombuffer(data, _BLOB_DTYPE).astype(np.int64)


def insert_batch(
    conn: sqlite3.Connection,
    *,
    who: str,
    model_version: str | None,
    kind: str,
    label: int | None,
    segments: str,
    note: str,
    n_points: int,
    undoes: int | None = None,
) -> int:
    """Record one operator action (``kind`` 'label' or 'undo'); returns its batch id."""
    cursor = conn.execute(
        "INSERT INTO batches (at, who, model_version, kind, label, segments, note, n_points, "
        "undoes) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
        (now(), who, model_version, kind, label, segments, note, n_points, undoes),
    )
    assert cursor.lastrowid is not None  # always set after an INSERT
    return int(cursor.lastrowid)


def insert_changes(
    conn: sqlite3.Connection,
    batch: int,
    points: np.ndarray,
    old: np.ndarray,
    new: np.ndarray,
    prev: np.ndarray,
) -> None:
    """One changes row per (old, new) pair; ``points`` (K,) sorted, the others (K,) aligned."""
    rows = []
    for o in (UNLABELLED, LABEL_OTHER, LABEL_GUARDRAIL):
        for n in (UNLABELLED, LABEL_OTHER, LABEL_GUARDRAIL):
            sel = (old == o) & (new == n)
            if sel.any():
                rows.append((batch, o, n, int(sel.sum()), to_blob(points[sel]), to_blob(prev[sel])))
    conn.executemany(
        "INSERT INTO changes (batch, old, new, n, points, prev) VALUES (?, ?, ?, ?, ?, ?)", rows
    )


def batch_changes(
    conn: sqlite3.Connection, batch: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K,) int64 each: the points a batch changed (sorted), their old values and the batches
    that had set them (0: none)."""
    rows = conn.execute(
        "SELECT old, points, prev FROM changes WHERE batch = ?", (batch,)
    ).fetchall()
    pts = [from_blob(p) for _, p, _ in rows]
    old = [np.full(len(p), o, np.int64) for (o, _, _), p in zip(rows, pts, strict=True)]
    prev = [from_blob(p) for _, _, p in rows]
    if not rows:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    all_pts = np.concatenate(pts)
    order = np.argsort(all_pts, kind="stable")
    return all_pts[order], np.concatenate(old)[order], np.concatenate(prev)[order]


def current_batch(
    conn: sqlite3.Connection, points: np.ndarray, *, missing_ok: bool = False
) -> np.ndarray:
    """(K,) int64 batch that set each point's current label (0 for unlabelled points).

    Parameters
    ----------
    points : (K,) int64, sorted
    missing_ok : unlabelled points are expected; else a point without a labels row is damage

    Raises
    ------
    LabelStoreError
        A point lacks its labels row and ``missing_ok`` is False.
    """
    out = np.zeros(len(points), np.int64)
    if len(points) == 0:
        return out
    rows = conn.execute(
        "SELECT point, batch FROM labels WHERE point IN (SELECT value FROM json_each(?)) "
        "ORDER BY point",
        (json.dumps(points.tolist()),),
    ).fetchall()
    found = np.array(rows, np.int64).reshape(-1, 2)
    idx = np.searchsorted(points, found[:, 0])
    if not missing_ok and len(found) != len(points):
        raise LabelStoreError("damaged label store: labelled points lack their labels row")
    out[idx] = found[:, 1]
    return out


def skip_undone(
    conn: sqlite3.Connection,
    path: Path,
    points: np.ndarray,
    old: np.ndarray,
    prev: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Old labels and their batches, walked back past batches that have been undone.

    Parameters
    ----------
    path : the store file, for the error message
    points, old, prev : (K,) int64, as :func:`batch_changes` gives them

    Returns
    -------
    old, prev : (K,) int64, new arrays: the label each point gets back and the batch that set it
    """
    old, prev = old.copy(), prev.copy()
    while True:
        candidates = np.unique(prev[prev > 0])
        if len(candidates) == 0:
            return old, prev
        rows = conn.execute(
            "SELECT id FROM batches WHERE undone_by IS NOT NULL AND id IN "
            "(SELECT value FROM json_each(?))",
            (json.dumps(candidates.tolist()),),
        ).fetchall()
        if not rows:
            return old, prev
        for (undone,) in rows:  # prev strictly decreases: the walk ends
            sel = np.flatnonzero(prev == undone)
            b_pts, b_old, b_prev = batch_changes(conn, undone)
            idx = np.searchsorted(b_pts, points[sel])
            if np.any(idx >= len(b_pts)) or np.any(
                b_pts[np.minimum(idx, len(b_pts) - 1)] != points[sel]
            ):
                raise LabelStoreError(
                    f"{path}: damaged label store: batch {undone} lacks points it set"
                )
            old[sel], prev[sel] = b_old[idx], b_prev[idx]
