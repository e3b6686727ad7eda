"""The operators' label store: durability, history, undo, bad input."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import numpy as np
import pytest

from guardrail_core.errors import InvalidOptionError, LabelStoreError
from guardrail_core.formats.label_store import (
    LABEL_GUARDRAIL,
    LABEL_OTHER,
    SCHEMA_VERSION,
    UNLABELLED,
    LabelChange,
    LabelStore,
)

N = 1000


@pytest.fixture
def store(tmp_path: Path):
    with LabelStore(tmp_path / "labels" / "drive.sqlite", n_points=N, drive_name="d") as s:
        yield s


def test_labels_survive_close_and_reopen(tmp_path: Path) -> None:
    path = tmp_path / "nested" / "folder" / "labels.sqlite"
    with LabelStore(path, n_points=N, drive_name="drive A") as s:
        assert (s.point_labels() == UNLABELLED).all()
        s.set_labels([3, 1, 2, 3], LABEL_GUARDRAIL, who="ann", segments=[7], note="rail")
        s.set_labels(np.arange(500, 600), LABEL_OTHER, who="bob", model_version="m1")
        before = s.point_labels()
        counts = s.counts()
        history = s.history()
    with LabelStore(path, n_points=N) as s:
        assert s.drive_name == "drive A"
        assert np.array_equal(s.point_labels(), before)
        assert (
            s.counts()
            == counts
            == {
                "labelled_points": 103,
                "guardrail_points": 3,
                "other_points": 100,
                "batches": 2,
            }
        )
        assert s.history() == history
    expected = np.full(N, UNLABELLED, np.int8)
    expected[[1, 2, 3]] = LABEL_GUARDRAIL
    expected[500:600] = LABEL_OTHER
    assert np.array_equal(before, expected)
    assert before.dtype == np.int8


def test_label_change_counts_only_changed_points(store: LabelStore) -> None:
    first = store.set_labels(np.array([5, 4, 4, 9]), LABEL_GUARDRAIL, who="ann")
    assert isinstance(first, LabelChange)
    assert first.n_points == 3 and first.undone_batch is None
    assert first.points.dtype == np.int64 and first.points.tolist() == [4, 5, 9]
    second = store.set_labels([4, 5, 6], LABEL_GUARDRAIL, who="ann")
    assert second.batch > first.batch
    assert second.n_points == 1 and second.points.tolist() == [4, 5, 6]
    nothing = store.set_labels([4], LABEL_GUARDRAIL, who="ann")
    assert nothing.n_points == 0
    entry = store.history(limit=1)[0]
    assert entry["batch"] == nothing.batch and entry["n_points"] == 0 and entry["old"] is None


def test_point_labels_is_a_snapshot(store: LabelStore) -> None:
    labels = store.point_labels()
    labels[:] = LABEL_GUARDRAIL  # the caller's copy: the store is not affected
    assert (store.point_labels() == UNLABELLED).all()
    store.set_labels([1], LABEL_OTHER, who="ann")
    assert (labels == LABEL_GUARDRAIL).all()


def test_history_per_point_after_label_relabel_undo(store: LabelStore) -> None:
    b1 = store.set_labels(np.arange(10), LABEL_GUARDRAIL, who="ann", segments=[1, 2]).batch
    b2 = store.set_labels(np.arange(5, 15), LABEL_OTHER, who="ann", model_version="v2").batch

    h7 = store.history(points=[7])
    assert [(e["batch"], e["old"], e["new"], e["n_points"]) for e in h7] == [
        (b2, "guardrail", "other", 1),
        (b1, None, "guardrail", 1),
    ]
    assert h7[0]["model_version"] == "v2" and h7[1]["segments"] == [1, 2]
    h = store.history()
    assert [(e["batch"], e["old"], e["new"], e["n_points"]) for e in h] == [
        (b2, None, "other", 5),  # points 10..14
        (b2, "guardrail", "other", 5),  # points 5..9
        (b1, None, "guardrail", 10),
    ]
    assert store.history(points=[5, 6, 12, 999])[0]["n_points"] == 1  # 12 of b2's None -> other
    assert store.history(points=[999]) == []
    assert len(store.history(limit=2)) == 2

    undo = store.undo()
    assert undo is not None and undo.undone_batch == b2 and undo.n_points == 10
    assert undo.points.tolist() == list(range(5, 15))
    labels = store.point_labels()
    assert (labels[:10] == LABEL_GUARDRAIL).all() and (labels[10:] == UNLABELLED).all()
    h7 = store.history(points=[7])
    assert [(e["kind"], e["old"], e["new"], e["undone"]) for e in h7] == [
        ("undo", "other", "guardrail", False),
        ("label", "guardrail", "other", True),
        ("label", None, "guardrail", False),
    ]
    assert h7[0]["undoes"] == b2
    h12 = store.history(points=[12])
    assert [(e["kind"], e["old"], e["new"]) for e in h12] == [
        ("undo", "other", None),
        ("label", None, "other"),
    ]

    # Undo never undoes an undo: the next one takes the labelling before.
    undo2 = store.undo()
    assert undo2 is not None and undo2.undone_batch == b1 and undo2.n_points == 10
    assert (store.point_labels() == UNLABELLED).all()
    assert store.undo() is None
    assert store.counts() == {
        "labelled_points": 0,
        "guardrail_points": 0,
        "other_points": 0,
        "batches": 4,
    }


def test_undo_matches_a_stack_of_snapshots(tmp_path: Path) -> None:
    """Random labellings and undos by one operator: the store behaves as a stack of states."""
    rng = np.random.default_rng(3)
    path = tmp_path / "s.sqlite"
    store = LabelStore(path, n_points=200)
    states = [np.full(200, UNLABELLED, np.int8)]
    for step in range(120):
        if rng.random() < 0.3:
            change = store.undo()
            assert (change is None) == (len(states) == 1)
            if len(states) > 1:
                previous, current = states[-2], states.pop()
                assert change is not None
                assert change.points.tolist() == np.flatnonzero(previous != current).tolist()
        else:
            points = rng.integers(0, 200, rng.integers(1, 60))
            label = int(rng.integers(0, 2))
            state = states[-1].copy()
            changed = int(np.count_nonzero(state[np.unique(points)] != label))
            state[points] = label
            assert store.set_labels(points, label, who="ann").n_points == changed
            states.append(state)
        assert np.array_equal(store.point_labels(), states[-1]), step
        if step % 40 == 39:
            store.close()
            store = LabelStore(path, n_points=200)
            assert np.array_equal(store.point_labels(), states[-1])
    store.close()


def test_undo_of_one_operator_keeps_the_other_operators_labels(store: LabelStore) -> None:
    ann = store.set_labels([1, 2, 3], LABEL_GUARDRAIL, who="ann").batch
    bob = store.set_labels([3, 4], LABEL_OTHER, who="bob").batch
    undo = store.undo(who="ann")
    assert undo is not None and undo.undone_batch == ann
    assert undo.points.tolist() == [1, 2]  # point 3 is bob's now
    assert store.point_labels()[:6].tolist() == [-1, -1, -1, 0, 0, -1]
    assert store.undo(who="ann") is None
    # Bob's undo gives point 3 back the label before ann's undone batch: none.
    undo = store.undo(who="bob")
    assert undo is not None and undo.undone_batch == bob
    assert (store.point_labels() == UNLABELLED).all()


def test_committed_labels_survive_a_killed_process(tmp_path: Path) -> None:
    path = tmp_path / "crash.sqlite"
    script = textwrap.dedent(
        f"""
        import os, sys
        import numpy as np
        from guardrail_core.formats.label_store import LabelStore
        store = LabelStore({str(path)!r}, n_points={N})
        store.set_labels(np.arange(100, 200), 1, who="ann")
        store.set_labels([150, 300], 0, who="ann")
        conn = store._conn
        conn.execute("BEGIN IMMEDIATE")  # a change under way when the process dies
        conn.execute("INSERT INTO labels (point, label, batch) VALUES (500, 1, 99)")
        sys.stdout.flush()
        os._exit(1)  # no close, no checkpoint, no commit
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[2],
    )
    assert done.returncode == 1, done.stderr
    assert (tmp_path / "crash.sqlite-wal").exists()  # the commits live in the WAL only
    with LabelStore(path, n_points=N) as store:
        labels = store.point_labels()
        assert np.flatnonzero(labels == LABEL_GUARDRAIL).tolist() == [
            p for p in range(100, 200) if p != 150
        ]
        assert np.flatnonzero(labels == LABEL_OTHER).tolist() == [150, 300]
        assert store.counts()["batches"] == 2
        assert store.undo() is not None  # the history is whole: the last batch can be undone
        assert np.flatnonzero(store.point_labels() >= 0).tolist() == list(range(100, 200))


def test_two_stores_on_one_file_see_each_others_labels(tmp_path: Path) -> None:
    path = tmp_path / "shared.sqlite"
    with LabelStore(path, n_points=N) as a, LabelStore(path, n_points=N) as b:
        a.set_labels([1, 2], LABEL_GUARDRAIL, who="ann")
        assert b.point_labels()[[1, 2]].tolist() == [1, 1]
        b.set_labels([2, 3], LABEL_OTHER, who="bob")  # b's old values came from a's commit
        assert a.point_labels()[[1, 2, 3]].tolist() == [1, 0, 0]
        assert [e["old"] for e in a.history(points=[2])] == ["guardrail", None]
        assert a.undo(who="bob") is not None
        assert b.point_labels()[[1, 2, 3]].tolist() == [1, 1, -1]


def test_threads_share_one_store(store: LabelStore) -> None:
    def work(k: int) -> None:
        for i in range(20):
            store.set_labels([k * 100 + i], k % 2, who=f"t{k}")
            store.point_labels()

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    counts = store.counts()
    assert counts["batches"] == 80 and counts["labelled_points"] == 80
    assert counts["guardrail_points"] == 40


def test_bad_input_raises_and_changes_nothing(store: LabelStore) -> None:
    store.set_labels([1, 2], LABEL_GUARDRAIL, who="ann")
    labels, counts, history = store.point_labels(), store.counts(), store.history()
    bad_calls = [
        lambda: store.set_labels([1, N], LABEL_OTHER, who="ann"),  # out of range
        lambda: store.set_labels([-1], LABEL_OTHER, who="ann"),
        lambda: store.set_labels([1], 2, who="ann"),
        lambda: store.set_labels([1], -1, who="ann"),
        lambda: store.set_labels([1], True, who="ann"),
        lambda: store.set_labels([1.5], LABEL_OTHER, who="ann"),  # type: ignore[list-item]
        lambda: store.set_labels(np.array([[1]]), LABEL_OTHER, who="ann"),
        lambda: store.set_labels([], LABEL_OTHER, who="ann"),
        lambda: store.set_labels([True], LABEL_OTHER, who="ann"),
        lambda: store.set_labels([1], LABEL_OTHER, who=None),  # type: ignore[arg-type]
        lambda: store.set_labels([1], LABEL_OTHER, who="a", segments=["x"]),  # type: ignore[list-item]
        lambda: store.history(points=[N]),
        lambda: store.history(limit=-1),
    ]
    for call in bad_calls:
        with pytest.raises(InvalidOptionError):
            call()
    assert np.array_equal(store.point_labels(), labels)
    assert store.counts() == counts and store.history() == history


def test_reopen_with_another_number_of_points_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    with LabelStore(path, n_points=N) as store:
        store.set_labels([1], LABEL_GUARDRAIL, who="ann")
    before = path.read_bytes()
    with pytest.raises(LabelStoreError, match=f"{N} points"):
        LabelStore(path, n_points=N + 1)
    assert path.read_bytes() == before
    with LabelStore(path, n_points=N) as store:
        assert store.counts()["guardrail_points"] == 1
    with pytest.raises(InvalidOptionError):
        LabelStore(tmp_path / "t.sqlite", n_points=-1)


def test_foreign_files_are_refused_unchanged(tmp_path: Path) -> None:
    text = tmp_path / "notes.sqlite"
    text.write_bytes(b"this is not a database, just some text that is long enough" * 20)
    before = text.read_bytes()
    with pytest.raises(LabelStoreError, match="SQLite"):
        LabelStore(text, n_points=N)
    assert text.read_bytes() == before

    other = tmp_path / "other.sqlite"
    with sqlite3.connect(other) as conn:
        conn.execute("CREATE TABLE things (x INTEGER)")
    conn.close()
    before = other.read_bytes()
    with pytest.raises(LabelStoreError, match="not a label store|no meta"):
        LabelStore(other, n_points=N)
    assert other.read_bytes() == before  # not even switched to WAL

    with pytest.raises(LabelStoreError, match="folder"):
        LabelStore(tmp_path, n_points=N)


def test_newer_schema_version_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    LabelStore(path, n_points=N).close()
    with sqlite3.connect(path) as conn:
        conn.execute(
            "UPDATE meta SET value = ? WHERE key = 'schema_version'", (str(SCHEMA_VERSION + 1),)
        )
    conn.close()
    with pytest.raises(LabelStoreError, match="newer"):
        LabelStore(path, n_points=N)


def test_closed_store_refuses_calls(tmp_path: Path) -> None:
    store = LabelStore(tmp_path / "s.sqlite", n_points=N)
    store.close()
    store.close()  # twice: no effect
    with pytest.raises(LabelStoreError, match="closed"):
        store.point_labels()
    with pytest.raises(LabelStoreError, match="closed"):
        store.set_labels([1], LABEL_OTHER, who="ann")


def test_store_file_is_wal_with_full_sync(store: LabelStore) -> None:
    assert store._conn is not None
    assert store._conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert store._conn.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
    assert os.path.exists(str(store.path) + "-wal")


def test_labels_looked_up_equal_the_dense_labels_through_labels_and_undos(
    store: LabelStore, tmp_path: Path
) -> None:
    """The store holds only the labelled points; looking points up gives what a dense array of
    every point's label gives, after relabelling, undoing, and reopening."""
    rng = np.random.default_rng(5)
    dense = np.full(N, UNLABELLED, np.int8)
    history: list[np.ndarray] = []
    for step in range(30):
        if step % 4 == 3 and history:
            dense = history.pop()
            assert store.undo(who="ann") is not None
        else:
            points = rng.choice(N, int(rng.integers(1, 200)), replace=False)
            label = int(rng.integers(0, 2))
            history.append(dense.copy())
            dense[points] = label
            store.set_labels(points, label, who="ann")
        asked = rng.integers(0, N, 300)
        np.testing.assert_array_equal(store.labels_at(asked), dense[asked])
        np.testing.assert_array_equal(store.point_labels(), dense)
        points, labels = store.labelled()
        np.testing.assert_array_equal(points, np.flatnonzero(dense >= 0))
        np.testing.assert_array_equal(labels, dense[dense >= 0])
    assert store.labels_at(np.zeros(0, np.int64)).shape == (0,)
    with LabelStore(store.path, n_points=N) as again:
        np.testing.assert_array_equal(again.labels_at(np.arange(N)), dense)
