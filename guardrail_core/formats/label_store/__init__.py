"""Operators' labels of drive points, in SQLite, with the full history of who changed what.

Labels belong to the drive's points (their index in the drive), not to segments: they survive a
re-segmentation of the drive and a restart of the review app. One store file per drive::

    meta     (key, value)                 schema_version, n_points, drive_name, created
    batches  (id, at, who, model_version, kind, label, segments, note, n_points, undoes, undone_by)
             one row per operator action: kind 'label' (set points to ``label``) or 'undo'
             (``undoes`` = the batch it reverted; that batch's ``undone_by`` = the undo)
    changes  (batch, old, new, n, points, prev)   WITHOUT ROWID
             the points a batch changed, one row per (old, new) pair: ``points`` the point indices
             as one little-endian int32 BLOB (sorted), ``prev`` (int32 BLOB, same order) the batch
             that had set each point's old value (0: none), so relabelling 100k points is a few rows
    labels   (point, label, batch)        WITHOUT ROWID
             the current label of every labelled point and the batch that set it

Durability: the journal is WAL with ``synchronous=FULL`` and every change (a
:meth:`LabelStore.set_labels` or a :meth:`LabelStore.undo`) is one transaction, so a crash or a
killed process loses no committed label (a power cut included). Measured on the development
machine (2 shared cores, ext4 on a virtual disk, a drive of 2.56M points): ``set_labels`` of 300
points takes about 1.0 ms (median of 50; 0.5 ms with ``synchronous=NORMAL``, which may lose the
last commits on a power cut), so FULL it is; 100,000 points take 0.1 s (0.25 s when relabelling),
an undo of them 0.2 s. :meth:`LabelStore.labels_at` looks points up in the labelled
ones, which are all the store holds in memory (a survey's memory follows what operators labelled,
not its length); opening a store of 1M labelled points reads them in about 0.6 s.

Threads: one :class:`LabelStore` may be shared by the threads of a process (web workers and a
training thread); every statement group runs under one lock. Another process (or another
:class:`LabelStore` on the same file) may write too: each call first checks SQLite's
``data_version`` and re-reads the labels when someone else committed.

Modules: :mod:`.schema` (label values, tables, opening a store file), :mod:`.changes` (recording
batches and walking them back for an undo), :mod:`.history` (reading the history),
:mod:`.sparse` (the labelled points in memory), :mod:`.store` (:class:`LabelStore`, the API).
"""

from guardrail_core.formats.label_store.schema import (
    LABEL_GUARDRAIL,
    LABEL_NAMES,
    LABEL_OTHER,
    LABELS_FILE,
    REVIEW_DIR,
    SCHEMA_VERSION,
    UNLABELLED,
    default_store_path,
)
from guardrail_core.formats.label_store.store import LabelChange, LabelStore

__all__ = [
    "LABELS_FILE",
    "LABEL_GUARDRAIL",
    "LABEL_NAMES",
    "LABEL_OTHER",
    "REVIEW_DIR",
    "SCHEMA_VERSION",
    "UNLABELLED",
    "LabelChange",
    "LabelStore",
    "default_store_path",
]
