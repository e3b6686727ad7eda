"""The leave-one-design-out benchmark's training pool (``benchmarks/accuracy_lodo.py``): every
design is left out of as many streets, and a street's cut segments are kept and reused only
while they were cut with today's parameters."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from guardrail_core.extract.classify.backbone import EMBEDDING_DIM
from guardrail_core.extract.classify.model_training import TrainingSet
from guardrail_core.synth.designs import list_designs

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def lodo():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location(
        "accuracy_lodo", ROOT / "benchmarks" / "accuracy_lodo.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["accuracy_lodo"] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("draw", [1, 2, 9])
def test_each_design_misses_one_street_of_every_pair(lodo, draw: int) -> None:  # type: ignore[no-untyped-def]
    shipped = list_designs()
    streets = [lodo.pool_designs(draw, j, shipped) for j in range(2 * lodo.POOL_PAIRS)]
    for first, second in zip(streets[::2], streets[1::2], strict=True):
        assert sorted(first + second) == sorted(shipped)  # the pair splits the designs
        assert abs(len(first) - len(second)) <= 1
    for design in shipped:
        assert sum(design not in s for s in streets) == lodo.POOL_PAIRS
    # Pairs are drawn apart: not every pair splits the designs alike.
    assert len({tuple(s) for s in streets[::2]}) > 1
    seeds = [lodo.pool_seed(draw, j) for j in range(2 * lodo.POOL_PAIRS)]
    assert all(8001 <= s <= 8999 for s in seeds) and len(set(seeds)) == len(seeds)
    other = {lodo.pool_seed(draw % 9 + 1, j) for j in range(2 * lodo.POOL_PAIRS)}
    assert not other & set(seeds)


def test_joined_pools_train_on_the_streets_lacking_the_design(lodo, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    for draw in (1, 2):  # as if simulated: only the folders' drive.json is looked at
        for j in range(2 * lodo.POOL_PAIRS):
            street = tmp_path / "pool" / f"draw{draw}" / f"street_{lodo.pool_seed(draw, j)}"
            street.mkdir(parents=True)
            (street / "drive.json").write_text("{}")
    design = list_designs()[0]
    one = [lodo.pool_training(tmp_path, design, (draw,), 1, 0.0) for draw in (1, 2)]
    both = lodo.pool_training(tmp_path, design, (1, 2), 1, 0.0)
    assert [len(streets) for streets in one] == [lodo.POOL_PAIRS] * 2
    assert both == one[0] + one[1]
    for path in both:
        draw, j = divmod(int(path.name.split("_")[1]) - lodo.FIRST_SEED - 1, 100)
        assert design not in lodo.pool_designs(draw, j, list_designs())


def _set(n: int, crops: list[int], group: int) -> TrainingSet:
    has_crop = np.zeros(n, bool)
    has_crop[crops] = True
    return TrainingSet(
        features=np.full((n, 3), float(group), np.float32),
        labels=np.arange(n) % 2 == 0,
        groups=np.full(n, group, np.int64),
        has_crop=has_crop,
        crops=None,
        sources=[{"drive": f"d{group}"}],
        embeddings=np.full((len(crops), EMBEDDING_DIM), float(group), np.float32),
    )


def test_joined_sets_keep_their_blocks_apart_and_embeddings_in_crop_order(lodo) -> None:  # type: ignore[no-untyped-def]
    joined = lodo.joined([_set(4, [1, 3], 0), _set(3, [0], 0)])
    assert joined.groups.tolist() == [0, 0, 0, 0, 1_000_000, 1_000_000, 1_000_000]
    assert np.flatnonzero(joined.has_crop).tolist() == [1, 3, 4]
    assert joined.embeddings is not None and joined.embeddings.shape == (3, EMBEDDING_DIM)
    assert joined.embeddings[:, 0].tolist() == [0.0, 0.0, 0.0]
    assert joined.features.shape == (7, 3) and joined.sources == [{"drive": "d0"}, {"drive": "d0"}]


def test_a_street_is_cut_once_and_again_when_cut_otherwise(
    lodo,  # type: ignore[no-untyped-def]
    drive_path: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    street = tmp_path / "street_8101"
    street.symlink_to(drive_path, target_is_directory=True)
    cuts: list[Path] = []
    cut = lodo.labelled_segments

    def counted(paths, size):  # type: ignore[no-untyped-def]
        cuts.extend(paths)
        return cut(paths, size)

    monkeypatch.setattr(lodo, "labelled_segments", counted)
    first = lodo.street_set(street, 128)
    assert cuts == [street]
    fresh = cut([street], 128)
    assert np.array_equal(first.labels, fresh.labels) and first.labels.any()
    assert np.array_equal(first.features, fresh.features)
    assert first.embeddings is not None
    assert first.embeddings.shape == (int(fresh.has_crop.sum()), EMBEDDING_DIM)
    cache = tmp_path / "street_8101.segments.npz"
    assert cache.is_file() and not list(tmp_path.glob("*.part*"))

    again = lodo.street_set(street, 128)  # read back, not cut again
    assert cuts == [street]
    assert np.array_equal(again.features, first.features)
    assert np.array_equal(again.embeddings, first.embeddings)
    assert again.sources == first.sources

    lodo.street_set(street, 96)  # crops of another size: cut again
    assert cuts == [street, street]
    with np.load(cache) as saved:  # and as if cut with other extraction parameters
        kept = {k: saved[k] for k in saved.files}
    kept["key"] = np.array(str(kept["key"]).replace('"extraction"', '"extraction_before"'))
    np.savez(cache, **kept)
    lodo.street_set(street, 96)
    assert cuts == [street, street, street]
    # Cut when the segment features were others (before chains): cut again.
    monkeypatch.setattr(lodo, "SEGMENT_FEATURE_NAMES", lodo.SEGMENT_FEATURE_NAMES[:-1])
    lodo.street_set(street, 96)
    assert cuts == [street] * 4


def test_draws_are_pools_one_to_nine(lodo) -> None:  # type: ignore[no-untyped-def]
    import argparse

    assert lodo.draw_list("1,2") == [(1,), (2,)]
    assert lodo.draw_list("1+2,3") == [(1, 2), (3,)]  # one model on pools 1 and 2, one on 3
    for text in ("0", "10", "1,x", "", "1+", "2+2", "1+10"):
        with pytest.raises(argparse.ArgumentTypeError):
            lodo.draw_list(text)
    # Models of joined pools are kept apart from each pool's on disk.
    assert lodo.pool_tag((1,), 0.0) == "1" and lodo.pool_tag((1, 2), 0.0) == "1+2"
    assert lodo.pool_tag((1, 2), 0.15) == "1+2_hj0.15"


def test_test_streets_are_seeds_of_their_own(lodo) -> None:  # type: ignore[no-untyped-def]
    n = len(list_designs())
    first = [lodo.test_street_seed(d, 1) for d in range(n)]
    assert first == [lodo.FIRST_SEED + 10 * d + 5 for d in range(n)]  # the README tables'
    tests = {lodo.test_street_seed(d, k) for d in range(n) for k in range(1, lodo.TEST_STREETS + 1)}
    assert len(tests) == n * lodo.TEST_STREETS
    three_streets = {lodo.FIRST_SEED + 10 * d + i for d in range(n) for i in (1, 2, 3)}
    pools = {lodo.pool_seed(draw, j) for draw in range(1, 10) for j in range(2 * lodo.POOL_PAIRS)}
    assert not tests & (three_streets | pools)
    for street in (0, lodo.TEST_STREETS + 1):
        with pytest.raises(ValueError, match="test street"):
            lodo.test_street_seed(0, street)
