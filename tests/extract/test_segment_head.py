"""The segment head: fusing shape features with the crop classifier's answer."""

from __future__ import annotations

import dataclasses
import itertools
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from guardrail_core.errors import IncompatibleModelError, InvalidOptionError, ModelFormatError
from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR, load_model
from guardrail_core.extract.classify.segment_head import (
    SegmentHead,
    SegmentHeadParams,
    average_of_members,
    fit_segment_head,
    head_inputs,
    members_of,
)
from guardrail_core.extract.classify.shape_features import (
    NEIGHBOUR_FEATURE_NAMES,
    SEGMENT_FEATURE_DIM,
    SHAPE_FEATURE_NAMES,
    WHOLE_COMPONENT_FEATURE_NAMES,
    feature_columns,
)

QUICK = SegmentHeadParams(hidden_units=16, epochs=300, members=1)


def test_inputs_carry_the_crop_logit_and_whether_there_was_a_crop() -> None:
    x = head_inputs(np.ones((3, 2), np.float32), np.array([0.9, np.nan, 0.5]))
    np.testing.assert_allclose(x[:, 2], [np.log(9.0), 0.0, 0.0], atol=1e-6)
    np.testing.assert_array_equal(x[:, 3], [1.0, 0.0, 1.0])
    with pytest.raises(InvalidOptionError, match="crop probabilities"):
        head_inputs(np.ones((3, 2)), np.zeros(2))


def synthetic(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Guardrail when feature 0 is positive, or, for half the segments (feature 1 > 0), when
    their crop says so; the crop is right 95% of the time and missing for a fifth."""
    features = rng.normal(size=(n, 3)).astype(np.float32)
    crop_truth = rng.random(n) < 0.5
    labels = np.where(features[:, 1] > 0, crop_truth, features[:, 0] > 0)
    right = rng.random(n) < 0.95
    crop = np.where(right == crop_truth, 0.9, 0.1)
    crop[rng.random(n) < 0.2] = np.nan
    labels = np.where(np.isnan(crop) & (features[:, 1] > 0), features[:, 0] > 0, labels)
    return features, crop, labels


def test_the_head_learns_when_to_trust_shape_and_when_the_crop() -> None:
    rng = np.random.default_rng(0)
    head = fit_segment_head(*synthetic(4000, rng), QUICK)
    features, crop, labels = synthetic(2000, rng)
    predicted = head.proba(features, crop) > 0.5
    shape_decides = features[:, 1] <= 0
    assert (predicted == labels)[shape_decides].mean() >= 0.97
    # Where the crop decides, the head can be no better than the crop (95%).
    crop_decides = ~shape_decides & np.isfinite(crop)
    assert (predicted == labels)[crop_decides].mean() >= 0.9


def test_weights_round_trip_and_errors() -> None:
    rng = np.random.default_rng(1)
    features, crop, labels = synthetic(500, rng)
    head = fit_segment_head(features, crop, labels, QUICK)
    again = SegmentHead.from_weights(head.weights("segment."), "segment.")
    np.testing.assert_array_equal(again.proba(features, crop), head.proba(features, crop))
    weights = head.weights("segment.")
    del weights["segment.mean"]
    with pytest.raises(ModelFormatError, match="lacks"):
        SegmentHead.from_weights(weights, "segment.")
    with pytest.raises(InvalidOptionError, match="expected 3 features"):
        head.proba(features[:, :2], crop)
    with pytest.raises(InvalidOptionError, match="both classes"):
        fit_segment_head(features, crop, np.ones(len(features), bool), QUICK)
    with pytest.raises(InvalidOptionError, match="folds"):
        SegmentHeadParams(folds=1)


def test_a_model_trained_on_drives_has_a_measured_segment_head(model_path: Path) -> None:
    model = load_model(model_path)
    assert model.segment_head is not None
    # A model trained now reads the chain features, not those over whole components.
    read = SHAPE_FEATURE_NAMES + NEIGHBOUR_FEATURE_NAMES
    assert model.segment_head.n_inputs == len(read) + 2
    info = model.info
    assert info["segment_head"]["features"] == list(read)
    assert not set(read) & set(WHOLE_COMPONENT_FEATURE_NAMES)
    held, crops = info["metrics"]["held_out"], info["metrics"]["held_out_crops"]
    # Segments are measured with or without a crop, so more of them than crops.
    assert held["n_train"] + held["n_held_out"] == info["trained_on"]["segments"]
    assert crops["n_train"] + crops["n_held_out"] == info["trained_on"]["crops"]
    assert info["trained_on"]["segments"] > info["trained_on"]["crops"]


def test_a_segment_head_of_other_features_is_refused(model_path: Path, tmp_path: Path) -> None:
    copy = tmp_path / "model"
    copy.mkdir()
    for name in ("model.json", "weights.npz"):
        (copy / name).write_bytes((model_path / name).read_bytes())
    document = json.loads((copy / "model.json").read_text())
    named = document["segment_head"]["features"]
    document["segment_head"]["features"] = [*named[:-1], "colour_hue"]
    (copy / "model.json").write_text(json.dumps(document))
    with pytest.raises(IncompatibleModelError, match="retrain"):
        load_model(copy)
    document["segment_head"]["features"] = named[:-1]  # known, but not what the weights take
    (copy / "model.json").write_text(json.dumps(document))
    with pytest.raises(ModelFormatError, match="named"):
        load_model(copy)
    del document["segment_head"]
    (copy / "model.json").write_text(json.dumps(document))
    with pytest.raises(ModelFormatError, match="disagree"):
        load_model(copy)


def test_a_head_reads_only_its_columns() -> None:
    rng = np.random.default_rng(5)
    features, crop, labels = synthetic(2000, rng)
    # A noise column in the middle, which the head is told not to read.
    wide = np.insert(features, 1, rng.normal(size=len(features)) * 100, axis=1)
    head = fit_segment_head(wide, crop, labels, QUICK, columns=np.array([0, 2, 3]))
    plain = fit_segment_head(features, crop, labels, QUICK)
    assert head.n_inputs == plain.n_inputs == 5
    np.testing.assert_allclose(head.proba(wide, crop), plain.proba(features, crop), atol=1e-6)
    lo, hi = head.proba_range(wide)
    np.testing.assert_allclose(np.stack([lo, hi]), np.stack(plain.proba_range(features)), atol=1e-6)
    with pytest.raises(InvalidOptionError, match="columns it reads"):
        head.proba(wide[:, :3], crop)


def test_weighted_labels_outvote_many_others() -> None:
    # A cluster the current model called guardrail 500 times, and 20 operators' labels in it
    # saying other: counted once each they are outvoted, counted 50 times they decide.
    rng = np.random.default_rng(7)
    centres = np.repeat([[-2.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 3.0, 0.0]], [800, 800, 520], 0)
    features = (centres + rng.normal(scale=0.3, size=centres.shape)).astype(np.float32)
    labels = np.repeat([False, True, True], [800, 800, 520])
    labels[-20:] = False  # the operators' labels
    crop = np.full(len(labels), np.nan)
    probe = np.array([[0.0, 3.0, 0.0]], np.float32)
    once = fit_segment_head(features, crop, labels, QUICK)
    weights = np.ones(len(labels), np.float32)
    weights[-20:] = 50.0
    heavy = fit_segment_head(features, crop, labels, QUICK, sample_weight=weights)
    assert once.proba(probe, np.array([np.nan]))[0] > 0.5
    assert heavy.proba(probe, np.array([np.nan]))[0] < 0.5
    # Weights of one are the unweighted loss.
    ones = fit_segment_head(features, crop, labels, QUICK, sample_weight=np.ones(len(labels)))
    np.testing.assert_allclose(ones.proba(features, crop), once.proba(features, crop), atol=1e-4)
    for bad in (np.ones(3), np.zeros(len(labels)), np.full(len(labels), np.nan)):
        with pytest.raises(InvalidOptionError, match="sample weights"):
            fit_segment_head(features, crop, labels, QUICK, sample_weight=bad)


def test_members_are_separate_trainings_whose_logits_are_averaged() -> None:
    """A head of k members is one network k x hidden_units wide: member m's hidden units are
    block m, and the output averages the members' logits. Member 0 starts from the draw a
    one-member head of the same seed starts from and is trained as it is, so it ends the same.
    No features are hidden here: the sums over the segments run in another order in a wider
    network, and hidden features can let 300 steps grow that rounding past the tolerance."""
    rng = np.random.default_rng(4)
    features, crop, labels = synthetic(2000, rng)
    quick = dataclasses.replace(QUICK, feature_dropout=0.0)
    one = fit_segment_head(features, crop, labels, quick, seed=5).weights("")
    three = fit_segment_head(
        features, crop, labels, dataclasses.replace(quick, members=3), seed=5
    ).weights("")
    h = quick.hidden_units
    assert three["net.0.weight"].shape == (3 * h, 5) and three["net.2.weight"].shape == (2, 3 * h)
    np.testing.assert_allclose(three["net.0.weight"][:h], one["net.0.weight"], atol=1e-4)
    np.testing.assert_allclose(three["net.0.bias"][:h], one["net.0.bias"], atol=1e-4)
    np.testing.assert_allclose(3 * three["net.2.weight"][:, :h], one["net.2.weight"], atol=1e-4)
    # The other members started elsewhere and ended elsewhere.
    blocks = three["net.0.weight"].reshape(3, h, 5)
    assert np.abs(blocks[1] - blocks[0]).max() > 0.1 and np.abs(blocks[2] - blocks[1]).max() > 0.1

    generator = torch.Generator().manual_seed(0)
    w1, b1 = torch.randn(3 * 4, 5, generator=generator), torch.randn(3 * 4, generator=generator)
    w2, b2 = torch.randn(3, 2, 4, generator=generator), torch.randn(3, 2, generator=generator)
    x = torch.randn(7, 5, generator=generator)
    members = [
        torch.relu(x @ w1[4 * m : 4 * m + 4].T + b1[4 * m : 4 * m + 4]) @ w2[m].T + b2[m]
        for m in range(3)
    ]
    torch.testing.assert_close(
        average_of_members(w1, b1, w2, b2)(x), torch.stack(members).mean(dim=0)
    )


def test_the_proba_range_holds_every_crop_probability_and_is_reached() -> None:
    rng = np.random.default_rng(2)
    head = fit_segment_head(*synthetic(2000, rng), QUICK)
    features = synthetic(200, rng)[0]
    lo, hi = head.proba_range(features)
    assert lo.shape == hi.shape == (len(features),) and np.all(lo <= hi)
    # Crop logits from one clipped end to the other, every 0.0023: the extremes found on this
    # grid lie within it of the exact ones.
    end = np.log((1 - 1e-5) / 1e-5)
    grid = 1.0 / (1.0 + np.exp(-np.linspace(-end, end, 10_001)))
    proba = np.stack([head.proba(features, np.full(len(features), p)) for p in grid])
    assert np.all(proba >= lo - 1e-6) and np.all(proba <= hi + 1e-6)
    np.testing.assert_allclose(proba.min(axis=0), lo, atol=1e-3)
    np.testing.assert_allclose(proba.max(axis=0), hi, atol=1e-3)
    with pytest.raises(InvalidOptionError, match="expected 3 features"):
        head.proba_range(features[:, :2])


def typical_features(head: SegmentHead, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, F) float32 segment features: those the head reads drawn around its standardisation,
    any it leaves unread (the default model's intensities) 0."""
    k = head.n_inputs - 2
    read = (head.mean[:k] + head.scale[:k] * rng.normal(size=(n, k))).astype(np.float32)
    if head.columns is None:
        return read
    features = np.zeros((n, SEGMENT_FEATURE_DIM), np.float32)
    features[:, head.columns] = read
    return features


@pytest.mark.parametrize("clip", [1e-5, 0.01, 0.2])
def test_where_the_shape_decides_every_crop_gives_the_same_label(clip: float) -> None:
    """Exact at every clip of the crop probabilities (ClassifyParams.crop_probability_clip)."""
    model = load_model(DEFAULT_MODEL_DIR)
    head = model.segment_head
    assert head is not None
    rng = np.random.default_rng(3)
    features = typical_features(head, 500, rng)
    decided = model.shape_decides(features, clip)
    assert 0.1 < decided.mean() < 0.99  # some segments left to the crop at every clip
    n = len(features)
    crop_probabilities = [np.full(n, p) for p in (0.0, 1e-3, 0.3, 0.5, 0.7, 1.0)]
    crop_probabilities += list(rng.random((5, n)))  # a different crop for every segment
    labels = np.stack(
        [model.segment_proba(features, p, clip) >= model.threshold for p in crop_probabilities]
    )
    assert np.all(labels[:, decided] == labels[0, decided])
    lo, hi = head.proba_range(features[~decided], clip)
    assert np.all((lo < model.threshold + 1e-4) & (hi >= model.threshold - 1e-4))
    # A crop beyond the clip counts as one at it.
    for p, at in ((0.0, clip), (1.0, 1 - clip)):
        np.testing.assert_array_equal(
            model.segment_proba(features, np.full(n, p), clip),
            model.segment_proba(features, np.full(n, at), clip),
        )


def test_a_wider_clip_leaves_the_shape_more_to_decide() -> None:
    """The shape decides more segments the less a crop may say (what makes the CNN cheaper)."""
    model = load_model(DEFAULT_MODEL_DIR)
    assert model.segment_head is not None
    features = typical_features(model.segment_head, 2000, np.random.default_rng(4))
    decided = [model.shape_decides(features, clip) for clip in (1e-5, 1e-3, 0.01, 0.1, 0.3)]
    for narrow, wide in itertools.pairwise(decided):
        assert np.all(wide[narrow])  # what the shape decided, it still decides
    assert decided[0].sum() < decided[2].sum() < decided[4].sum()


def test_hiding_shape_features_in_training_lets_the_crop_speak_for_an_unseen_design() -> None:
    """A head trained on streets without the thrie beam, asked about a street of it alone
    (tests/data/README.md): trained on every feature, its shape features overrule a sure crop
    on one thrie segment in seven; trained with half of them hidden at random, it follows the
    crop on nearly all, and calls hardly more of the other segments guardrail."""
    data = np.load(Path(__file__).parents[1] / "data" / "thrie_left_out_dev9105.npz")
    train = [data[f"train_{k}"].astype(np.float32) for k in ("features", "crop_proba")]
    features = data["test_features"].astype(np.float32)
    crop, thrie = data["test_crop_proba"].astype(np.float64), data["test_labels"]
    sure = thrie & (crop > 0.9)  # thrie segments whose crop says guardrail
    followed, false_alarms = {}, {}
    for dropout in (0.0, 0.5):
        params = SegmentHeadParams(epochs=300, feature_dropout=dropout)
        called = fit_segment_head(*train, data["train_labels"], params).proba(features, crop)
        followed[dropout] = (called[sure] >= 0.5).mean()
        false_alarms[dropout] = (called[~thrie] >= 0.5).mean()
    assert sure.sum() >= 500
    assert followed[0.0] <= 0.93 and followed[0.5] >= 0.97
    assert false_alarms[0.5] <= false_alarms[0.0] + 0.015


def test_members_of_an_average_are_members_that_average_to_it() -> None:
    generator = torch.Generator().manual_seed(1)
    w1, b1 = torch.randn(3 * 4, 5, generator=generator), torch.randn(3 * 4, generator=generator)
    w2, b2 = torch.randn(3, 2, 4, generator=generator), torch.randn(3, 2, generator=generator)
    net = average_of_members(w1, b1, w2, b2)
    x = torch.randn(7, 5, generator=generator)
    again = average_of_members(*members_of(net, 3))
    torch.testing.assert_close(again(x), net(x))
    with pytest.raises(InvalidOptionError, match="not 5 members"):
        members_of(net, 5)


def test_a_fine_tuned_head_keeps_what_its_start_learnt_where_the_new_labels_are_silent() -> None:
    """The start learnt feature 0 > 0. The new labels cover only feature 0 > 0.5 and teach an
    exception there (feature 1 > 2 is other): fine-tuned, the head learns the exception and
    still calls feature 0 < -1 other; a head trained on the new labels alone has nothing there
    to go by, and calls it by feature 1 as the exception taught it."""
    rng = np.random.default_rng(3)
    params = dataclasses.replace(QUICK, fine_tune_epochs=100)
    old = rng.normal(scale=[2.0, 1.0, 1.0], size=(3000, 3)).astype(np.float32)
    start = fit_segment_head(old, np.full(len(old), np.nan), old[:, 0] > 0, params)
    new = np.column_stack(
        [rng.uniform(0.5, 3, 600), rng.uniform(-1, 4, 600), rng.normal(size=600)]
    ).astype(np.float32)
    new_labels = new[:, 1] <= 2
    none = np.full(len(new), np.nan)
    tuned = fit_segment_head(new, none, new_labels, params, start=start)
    fresh = fit_segment_head(new, none, new_labels, params)
    np.testing.assert_array_equal(tuned.mean, start.mean)  # the start's standardisation
    silent = np.column_stack(
        [rng.uniform(-3, -1, 300), rng.uniform(-1, 1.5, 300), rng.normal(size=300)]
    ).astype(np.float32)
    no_crop = np.full(len(silent), np.nan)
    assert (tuned.proba(silent, no_crop) < 0.5).mean() >= 0.95
    assert (fresh.proba(silent, no_crop) < 0.5).mean() <= 0.5
    exception = new[:, 1] > 2.2
    assert (tuned.proba(new, none)[exception] < 0.5).mean() >= 0.9


def test_a_head_starts_only_from_a_head_of_its_own_shape() -> None:
    rng = np.random.default_rng(5)
    features, crop, labels = synthetic(500, rng)
    start = fit_segment_head(features, crop, labels, QUICK)
    # One step at a tiny rate: the new head answers as its start does.
    still = dataclasses.replace(QUICK, fine_tune_epochs=1, lr=1e-9)
    same = fit_segment_head(features, crop, labels, still, start=start)
    np.testing.assert_allclose(same.proba(features, crop), start.proba(features, crop), atol=1e-5)
    with pytest.raises(InvalidOptionError, match="units wide"):
        fit_segment_head(features, crop, labels, dataclasses.replace(QUICK, members=2), start=start)
    with pytest.raises(InvalidOptionError, match="it reads 3 columns, 2 are asked for"):
        fit_segment_head(features[:, :2], crop, labels, QUICK, start=start)


def test_a_head_started_on_other_features_is_refused_naming_them() -> None:
    """The message names the features that differ, not only how many (both heads below read
    three: "reads 3 features, not the 3 asked for" told an operator nothing)."""
    rng = np.random.default_rng(6)
    features, crop, labels = synthetic(500, rng)
    wide = np.zeros((len(features), SEGMENT_FEATURE_DIM), np.float32)
    names = ("height_min_m", "log_points", "chain_log_length_m", "component_log_length_m")
    wide[:, feature_columns(names[:3])] = features
    start = fit_segment_head(wide, crop, labels, QUICK, columns=feature_columns(names[:3]))
    asked = feature_columns([names[0], names[1], names[3]])
    with pytest.raises(InvalidOptionError) as refused:
        fit_segment_head(wide, crop, labels, QUICK, columns=asked, start=start)
    assert str(refused.value) == (
        "segment head: the head to start from reads other segment features than those asked "
        "for (it reads chain_log_length_m, not asked for; it does not read "
        "component_log_length_m, asked for); fine-tune it on the columns it reads "
        "(SegmentHead.columns)"
    )
    tuned = fit_segment_head(wide, crop, labels, QUICK, columns=start.columns, start=start)
    np.testing.assert_array_equal(tuned.columns, start.columns)
