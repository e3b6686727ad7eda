"""Reading the label store's history: one entry per batch and (old, new) pair, newest first."""

from __future__ import annotations

import json
import sqlite3
from typing import Any

import numpy as np

from guardrail_core.formats.label_store.changes import from_blob
from guardrail_core.formats.label_store.schema import LABEL_NAMES, UNLABELLED

_QUERY = (
    "SELECT b.id, b.at, b.who, b.model_version, b.kind, b.label, b.segments, b.note, "
    "b.undone_by, b.undoes, c.old, c.new, c.n, {points} FROM batches b "
    "{join} changes c ON c.batch = b.id ORDER BY b.id DESC, c.old, c.new"
)


def read_history(
    conn: sqlite3.Connection, wanted: np.ndarray | None, limit: int
) -> list[dict[str, Any]]:
    """At most ``limit`` history entries, newest first (see :meth:`LabelStore.history`).

    Parameters
    ----------
    wanted : (K,) int64 sorted point indices, the entries touching them only (``n_points`` then
        counts only them); None for every entry
    limit : >= 1
    """
    out: list[dict[str, Any]] = []
    if wanted is None:
        sql = _QUERY.format(points="NULL", join="LEFT JOIN") + " LIMIT ?"
        cursor = conn.execute(sql, (limit,))
    else:
        cursor = conn.execute(_QUERY.format(points="c.points", join="JOIN"))
    for row in cursor:
        (batch, at, who, version, kind, label, segments, note, undone_by, undoes) = row[:10]
        old, new, n, blob = row[10:]
        if wanted is not None:
            changed = from_blob(blob)
            idx = np.minimum(np.searchsorted(changed, wanted), len(changed) - 1)
            n = int(np.count_nonzero(changed[idx] == wanted))
            if n == 0:
                continue
        if old is None:  # a labelling that changed nothing
            old, new, n = UNLABELLED, label, 0
        out.append(
            {
                "batch": int(batch),
                "at": at,
                "who": who,
                "model_version": version,
                "kind": kind,
                "old": LABEL_NAMES.get(old),
                "new": LABEL_NAMES.get(new),
                "n_points": int(n),
                "segments": json.loads(segments),
                "note": note,
                "undone": undone_by is not None,
                "undoes": undoes,
            }
        )
        if len(out) >= limit:
            break
    cursor.close()
    return out
