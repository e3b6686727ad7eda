"""The :class:`LabelStore`: the operators' labels of one drive's points, set, undone and read.

See :mod:`guardrail_core.formats.label_store` for the tables, the durability and the threads.
"""

from __future__ import annotations

import json
import sqlite3
import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from guardrail_core.errors import InvalidOptionError, LabelStoreError
from guardrail_core.formats.label_store.changes import (
    batch_changes,
    current_batch,
    insert_batch,
    insert_changes,
    skip_undone,
)
from guardrail_core.formats.label_store.history import read_history
from guardrail_core.formats.label_store.schema import (
    LABEL_GUARDRAIL,
    LABEL_NAMES,
    LABEL_OTHER,
    UNLABELLED,
    open_tables,
    read_labels,
)


@dataclass(frozen=True)
class LabelChange:
    """What one :meth:`LabelStore.set_labels` or :meth:`LabelStore.undo` recorded.

    Attributes
    ----------
    batch : id of the batch recorded
    n_points : points whose label changed (points already carrying the label are not counted)
    points : (K,) int64, sorted: for a labelling every point given (changed or not), for an undo
        the points it restored (K == n_points)
    undone_batch : for an undo, the batch it reverted; else None
    """

    batch: int
    n_points: int
    points: np.ndarray
    undone_batch: int | None


def _is_int(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


class LabelStore:
    """The operators' labels of one drive's points (the tables: see the package docstring).

    Parameters
    ----------
    path : the store file (``.sqlite``); created with its parent folders when missing
    n_points : number of points of the drive; a store made for another number is refused
    drive_name : recorded in a new store (an existing store keeps its own)

    Raises
    ------
    LabelStoreError
        The file is not a SQLite database, is a SQLite database but not a label store, was written
        with a newer schema version, or was made for another number of points. Nothing is written
        to it then.
    InvalidOptionError
        ``n_points`` is not a whole number >= 0.
    """

    def __init__(self, path: str | Path, *, n_points: int, drive_name: str = "") -> None:
        if not _is_int(n_points) or n_points < 0:
            raise InvalidOptionError(f"n_points: expected a whole number >= 0, got {n_points!r}")
        if not isinstance(drive_name, str):
            raise InvalidOptionError(f"drive_name: expected a str, got {type(drive_name).__name__}")
        self.path = Path(path)
        self.n_points = int(n_points)
        self._lock = threading.Lock()
        if self.path.exists() and not self.path.is_file():
            raise LabelStoreError(f"{self.path}: expected a label store file, got a folder")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            conn = sqlite3.connect(
                str(self.path), timeout=30.0, isolation_level=None, check_same_thread=False
            )
        except sqlite3.Error as exc:
            raise LabelStoreError(f"{self.path}: cannot open the label store ({exc})") from exc
        try:
            self.drive_name = open_tables(
                conn, self.path, n_points=self.n_points, drive_name=drive_name
            )
            self._labels = read_labels(conn, self.path, self.n_points)
            self._data_version = conn.execute("PRAGMA data_version").fetchone()[0]
        except sqlite3.DatabaseError as exc:
            conn.close()
            raise LabelStoreError(
                f"{self.path}: expected a label store (SQLite database), got a file SQLite cannot "
                f"read ({exc})"
            ) from exc
        except BaseException:
            conn.close()
            raise
        self._conn: sqlite3.Connection | None = conn

    # -- connection -----------------------------------------------------------------------------

    def _connection(self) -> sqlite3.Connection:
        """The open connection, the labels re-read if another connection committed (lock held)."""
        if self._conn is None:
            raise LabelStoreError(f"{self.path}: the label store is closed")
        version = self._conn.execute("PRAGMA data_version").fetchone()[0]
        if version != self._data_version:
            self._labels = read_labels(self._conn, self.path, self.n_points)
            self._data_version = version
        return self._conn

    # -- input checks ---------------------------------------------------------------------------

    def _check_points(self, points: object, *, allow_empty: bool = False) -> np.ndarray:
        """Unique sorted (K,) int64 point indices, each in [0, n_points)."""
        array = np.asarray(points)
        if array.ndim != 1 or (array.dtype.kind not in "iu" and not (array.size == 0)):
            raise InvalidOptionError(
                f"points: expected a 1-D array of point indices (integers), got shape "
                f"{array.shape} dtype {array.dtype}"
            )
        if array.size == 0:
            if allow_empty:
                return np.zeros(0, np.int64)
            raise InvalidOptionError("points: expected at least one point index, got none")
        low, high = array.min(), array.max()
        if low < 0 or high >= self.n_points:
            raise InvalidOptionError(
                f"points: expected indices in [0, {self.n_points}), got values from {low} to {high}"
            )
        return np.unique(array.astype(np.int64))

    # -- changes --------------------------------------------------------------------------------

    def point_labels(self) -> np.ndarray:
        """(n_points,) int8: :data:`UNLABELLED` where no operator label, else 0 (other) or 1
        (guardrail).

        A dense array of the whole drive, made on each call (a consistent snapshot the caller may
        keep or change); a survey-scale reader asks :meth:`labels_at` or :meth:`labelled`.
        """
        with self._lock:
            self._connection()
            return self._labels.dense(self.n_points)

    def labels_at(self, points: np.ndarray) -> np.ndarray:
        """(K,) int8 label of each of ``points`` (K,) int: :data:`UNLABELLED` where none."""
        with self._lock:
            self._connection()
            return self._labels.at(points)

    def labelled(self) -> tuple[np.ndarray, np.ndarray]:
        """Every labelled point: (L,) int64 sorted point indices and their (L,) int8 labels."""
        with self._lock:
            self._connection()
            return self._labels.points.copy(), self._labels.labels.copy()

    def set_labels(
        self,
        points: Iterable[int] | np.ndarray,
        label: int,
        *,
        who: str,
        model_version: str | None = None,
        segments: Sequence[int] = (),
        note: str = "",
    ) -> LabelChange:
        """Label ``points`` as ``label``, in one transaction.

        Parameters
        ----------
        points : (K,) int, point indices in [0, n_points); duplicates are ignored
        label : :data:`LABEL_GUARDRAIL` or :data:`LABEL_OTHER`
        who : the operator
        model_version : the model whose proposal the operator reviewed, if any
        segments : the segments the operator selected (recorded for the history only)
        note : free text

        Returns
        -------
        LabelChange : the batch recorded (a batch is recorded even when no label changed)

        Raises
        ------
        InvalidOptionError
            Points not 1-D integers, empty or out of range; label not 0 or 1; who, note or
            model_version not strings; segments not whole numbers. Nothing is recorded then.
        LabelStoreError
            The store is closed.
        """
        pts = self._check_points(points)
        if not _is_int(label) or int(label) not in LABEL_NAMES:
            raise InvalidOptionError(
                f"label: expected {LABEL_OTHER} (other) or {LABEL_GUARDRAIL} (guardrail), "
                f"got {label!r}"
            )
        label = int(label)
        segments_json = self._check_meta(who, model_version, segments, note)
        with self._lock:
            conn = self._connection()
            conn.execute("BEGIN IMMEDIATE")
            try:
                self._connection()  # another process may have committed before our write lock
                old = self._labels.at(pts).astype(np.int64)
                changed = old != label
                cp, co = pts[changed], old[changed]
                prev = np.zeros(len(cp), np.int64)
                had = co != UNLABELLED
                prev[had] = current_batch(conn, cp[had])
                batch = insert_batch(
                    conn,
                    who=who,
                    model_version=model_version,
                    kind="label",
                    label=label,
                    segments=segments_json,
                    note=note,
                    n_points=len(cp),
                )
                insert_changes(conn, batch, cp, co, np.full(len(cp), label), prev)
                conn.executemany(
                    "INSERT INTO labels (point, label, batch) VALUES (?, ?, ?) ON CONFLICT (point) "
                    "DO UPDATE SET label = excluded.label, batch = excluded.batch",
                    ((p, label, batch) for p in cp.tolist()),
                )
                conn.execute("COMMIT")
            except BaseException:
                conn.execute("ROLLBACK")
                raise
            self._labels.assign(cp, np.full(len(cp), label))
        return LabelChange(batch=batch, n_points=len(cp), points=pts, undone_batch=None)

    def undo(self, *, who: str | None = None) -> LabelChange | None:
        """Revert the most recent labelling (of ``who`` when given) not undone yet.

        Undos themselves are never undone: a second undo reverts the labelling before. Each
        point gets back the label it had before the batch, except points another batch has
        relabelled since (they keep that label). When the label a point gets back was set by
        a batch that has been undone in the meantime, the label before that batch is restored
        instead (and so on). The undo is recorded as a batch of its own (kind ``'undo'``) and the
        original is marked undone.

        Returns
        -------
        LabelChange or None
            None when there is nothing to undo.
        """
        if who is not None and not isinstance(who, str):
            raise InvalidOptionError(f"who: expected a str or None, got {type(who).__name__}")
        with self._lock:
            conn = self._connection()
            conn.execute("BEGIN IMMEDIATE")
            try:
                self._connection()
                query = (
                    "SELECT id, who, label, segments, model_version FROM batches "
                    "WHERE kind = 'label' AND undone_by IS NULL"
                )
                args: tuple[Any, ...] = ()
                if who is not None:
                    query += " AND who = ?"
                    args = (who,)
                row = conn.execute(query + " ORDER BY id DESC LIMIT 1", args).fetchone()
                if row is None:
                    conn.execute("ROLLBACK")
                    return None
                target, target_who, label, segments, model_version = row
                pts, old, prev = batch_changes(conn, target)
                keep = current_batch(conn, pts, missing_ok=True) == target
                pts, old, prev = pts[keep], old[keep], prev[keep]
                old, prev = skip_undone(conn, self.path, pts, old, prev)
                batch = insert_batch(
                    conn,
                    who=target_who if who is None else who,
                    model_version=model_version,
                    kind="undo",
                    label=None,
                    segments=segments,
                    note=f"undo of batch {target}",
                    n_points=len(pts),
                    undoes=target,
                )
                insert_changes(
                    conn, batch, pts, np.full(len(pts), label), old, np.full(len(pts), target)
                )
                gone = old == UNLABELLED
                conn.executemany(
                    "DELETE FROM labels WHERE point = ?", ((p,) for p in pts[gone].tolist())
                )
                conn.executemany(
                    "UPDATE labels SET label = ?, batch = ? WHERE point = ?",
                    zip(
                        old[~gone].tolist(), prev[~gone].tolist(), pts[~gone].tolist(), strict=True
                    ),
                )
                conn.execute("UPDATE batches SET undone_by = ? WHERE id = ?", (batch, target))
                conn.execute("COMMIT")
            except BaseException:
                if conn.in_transaction:
                    conn.execute("ROLLBACK")
                raise
            self._labels.assign(pts, old)
        return LabelChange(batch=batch, n_points=len(pts), points=pts, undone_batch=target)

    def _check_meta(
        self, who: object, model_version: object, segments: object, note: object
    ) -> str:
        """The batch's descriptive fields checked; returns the segments as JSON."""
        if not isinstance(who, str):
            raise InvalidOptionError(
                f"who: expected a str (the operator), got {type(who).__name__}"
            )
        if model_version is not None and not isinstance(model_version, str):
            raise InvalidOptionError(
                f"model_version: expected a str or None, got {type(model_version).__name__}"
            )
        if not isinstance(note, str):
            raise InvalidOptionError(f"note: expected a str, got {type(note).__name__}")
        seg = np.asarray(segments if not isinstance(segments, str) else [segments])
        if seg.ndim != 1 or (seg.size and seg.dtype.kind not in "iu"):
            raise InvalidOptionError(
                f"segments: expected a sequence of segment numbers, got {segments!r:.80}"
            )
        return json.dumps([int(s) for s in seg.tolist()])

    # -- reading --------------------------------------------------------------------------------

    def history(
        self, *, points: Sequence[int] | np.ndarray | None = None, limit: int = 100
    ) -> list[dict[str, Any]]:
        """Changes, newest first.

        One entry per batch and (old, new) pair: a labelling of unlabelled and of "other"
        points to "guardrail" gives two entries of the same batch; a labelling that changed
        nothing gives one entry with ``n_points`` 0 and ``old`` None.

        Parameters
        ----------
        points : only the entries touching these points; ``n_points`` then counts only them
        limit : at most this many entries

        Returns
        -------
        list of dict
            ``{"batch", "at" (ISO 8601 UTC), "who", "model_version", "kind" ("label" | "undo"),
            "old", "new" ("guardrail" | "other" | None for unlabelled), "n_points", "segments"
            (list of int), "note", "undone" (bool), "undoes" (batch id or None)}``
        """
        if not _is_int(limit) or limit < 0:
            raise InvalidOptionError(f"limit: expected a whole number >= 0, got {limit!r}")
        wanted = None if points is None else self._check_points(points, allow_empty=True)
        if limit == 0 or (wanted is not None and len(wanted) == 0):
            return []
        with self._lock:
            return read_history(self._connection(), wanted, limit)

    def counts(self) -> dict[str, int]:
        """``{"labelled_points", "guardrail_points", "other_points", "batches"}`` (batches of
        both kinds)."""
        with self._lock:
            conn = self._connection()
            guardrail = int(np.count_nonzero(self._labels.labels == LABEL_GUARDRAIL))
            other = int(np.count_nonzero(self._labels.labels == LABEL_OTHER))
            (batches,) = conn.execute("SELECT COUNT(*) FROM batches").fetchone()
        return {
            "labelled_points": guardrail + other,
            "guardrail_points": guardrail,
            "other_points": other,
            "batches": int(batches),
        }

    # -- life -----------------------------------------------------------------------------------

    def close(self) -> None:
        """Close the store (again: no effect); later calls raise :class:`LabelStoreError`."""
        with self._lock:
            if self._conn is not None:
                self._conn.close()
                self._conn = None

    def __enter__(self) -> LabelStore:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._conn is None else "open"
        return f"LabelStore({str(self.path)!r}, n_points={self.n_points}, {state})"
