"""Shape first: the CNN asked only where a segment's shape leaves its label open gives the labels
asking every crop gives; the review loop completes the embeddings of the crops not asked."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from guardrail_core.extract.classify.backbone import embed_crops
from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR, load_model
from guardrail_core.extract.classify.segment_scores import (
    ClassifyParams,
    score_segments,
    weighed_crop_probability,
)
from guardrail_core.extract.crops import CROP_OK
from guardrail_core.formats.run_folder import load_run
from guardrail_core.review.predictions import predict_run
from guardrail_core.review.run_crops import complete_embeddings, read_crops


def test_shape_first_gives_the_labels_of_asking_every_crop(run_path: Path) -> None:
    """With the shipped model (not trained on this drive, so its shape is often not sure) on the
    test run's own segments and crops."""
    model = load_model(DEFAULT_MODEL_DIR)
    run = load_run(run_path)
    features = run.segments["features"]
    has_crop = run.segments["crop_status"] == CROP_OK
    cut: list[np.ndarray] = []

    def crops(rows: np.ndarray) -> np.ndarray:
        cut.append(rows)
        return read_crops(run, rows, 128)

    every = score_segments(model, features, has_crop, crops, ClassifyParams(shape_first=False))
    first = score_segments(model, features, has_crop, crops, ClassifyParams(shape_first=True))

    # Only the crops asked about are cut, once.
    assert len(cut) == 2
    np.testing.assert_array_equal(cut[0], np.flatnonzero(every.asked))
    np.testing.assert_array_equal(cut[1], np.flatnonzero(first.asked))
    np.testing.assert_array_equal(every.asked, has_crop)
    # The shape settles some crops, not all: on this street's hedges and grass, often. (The
    # model of 2026-11-27, trained on twelve streets with cameras, asks about 21 of 238.)
    assert 10 <= first.asked.sum() < 0.8 * has_crop.sum()
    assert not first.asked[~has_crop].any()
    np.testing.assert_array_equal(first.raw_label, every.raw_label)
    # The crop veto of label correction counts the crops the head weighed: the same either way.
    clip = ClassifyParams().crop_probability_clip
    weighed = [
        weighed_crop_probability(model, features, scores.crop_probability, clip)
        for scores in (every, first)
    ]
    np.testing.assert_allclose(weighed[0], weighed[1], atol=1e-6)
    assert np.isfinite(weighed[0]).sum() == first.asked.sum()
    asked = first.asked
    # (batches of other crops: the runtime may sum in another order)
    np.testing.assert_allclose(
        first.crop_probability[asked], every.crop_probability[asked], atol=1e-6
    )
    np.testing.assert_allclose(first.probability[asked], every.probability[asked], atol=1e-6)
    assert np.isnan(first.crop_probability[~asked]).all()
    assert np.isfinite(first.probability).all()
    assert first.embeddings is not None and every.embeddings is not None
    np.testing.assert_allclose(first.embeddings[asked], every.embeddings[asked], atol=1e-5)
    assert np.isnan(first.embeddings[has_crop & ~asked]).all()
    assert not first.embeddings[~has_crop].any()


def test_the_embeddings_of_crops_not_asked_are_made_once_and_kept(
    run_path: Path, model_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = tmp_path / "run"
    shutil.copytree(run_path, root)
    run = load_run(root)
    has_crop = run.segments["crop_status"] == CROP_OK
    # Decided as process decides them: with the default clip of the crops' probabilities.
    clip = ClassifyParams().crop_probability_clip
    missing = has_crop & load_model(model_path).shape_decides(run.segments["features"], clip)
    assert missing.sum() > 0
    stored = run.embeddings()
    assert stored is not None
    np.testing.assert_array_equal(np.isnan(stored).all(axis=1), missing)  # as process left it
    # The crops cut now from the drive's images are those process classified.
    asked = np.flatnonzero(has_crop & ~missing)[:24]
    again = embed_crops(read_crops(run, asked, 128)).astype(np.float16)
    np.testing.assert_allclose(again.astype(np.float32), stored[asked], atol=2e-3, rtol=2e-3)

    # Only the rows asked for are made.
    some = np.flatnonzero(missing)[:5]
    part = complete_embeddings(run, 128, rows=some)
    assert part is not None and np.isfinite(part[some]).all()
    assert (~np.isfinite(part).all(axis=1)).sum() == missing.sum() - len(some)

    completed = complete_embeddings(run, 128)
    assert completed is not None and np.isfinite(completed).all()
    expected = embed_crops(read_crops(run, np.flatnonzero(missing), 128)).astype(np.float16)
    np.testing.assert_array_equal(completed[missing], expected)
    np.testing.assert_array_equal(completed[~missing], stored[~missing])  # the rest as it was
    np.testing.assert_array_equal(load_run(root).embeddings(), completed)  # saved in the run

    def no_backbone(*args: object, **kwargs: object) -> np.ndarray:
        raise AssertionError("the backbone ran again")

    monkeypatch.setattr("guardrail_core.extract.classify.backbone.embed_crops", no_backbone)
    again = complete_embeddings(load_run(root), 128)
    assert again is not None
    np.testing.assert_array_equal(again, completed)
    # Re-predicting with the run's own model reproduces its labels and its crops not asked.
    predicted = predict_run(load_run(root), load_model(model_path))
    np.testing.assert_array_equal(predicted["label"], run.segments["label"])
    np.testing.assert_array_equal(
        np.isnan(predicted["crop_probability"]), np.isnan(run.segments["crop_probability"])
    )
