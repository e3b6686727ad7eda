"""Training the crop classifier on labelled crops, measured on held-out groups (§3.3).

``"fast"`` mode keeps the pretrained backbone frozen and trains a small head (feature
standardisation + a linear layer, or one hidden layer) on the crops' 1280-d embeddings, which the
caller may cache: retraining takes seconds on a CPU. ``"full"`` mode fine-tunes the whole network
with a new 2-class final layer (§3.3 "fine tuning"): class-weighted cross-entropy,
horizontal-flip augmentation, AdamW, cosine learning rate; minutes on a CPU for a few thousand
crops.
"""

from __future__ import annotations

import copy
import json
import math
import time
from datetime import UTC, datetime
from typing import Any

import numpy as np
import torch
from torch import nn

from guardrail_core.errors import InvalidOptionError, TrainingDataError
from guardrail_core.extract.classify.backbone import (
    ARCHITECTURE,
    EMBEDDING_DIM,
    backbone_info,
    check_crops,
    check_embeddings,
    embed_crops,
    load_backbone,
    to_input,
)
from guardrail_core.extract.classify.crop_classifier import (
    GuardrailClassifier,
    make_head,
    model_version,
)
from guardrail_core.extract.classify.crop_classifier_params import CLASS_NAMES, ClassifierParams
from guardrail_core.extract.classify.torch_threads import one_thread
from guardrail_core.progress import progress_bar

_DEFAULTS = ClassifierParams()


def classification_metrics(labels: np.ndarray, predicted: np.ndarray) -> dict[str, Any]:
    """Per-class recall, precision, F1 and count, plus accuracy.

    Parameters
    ----------
    labels, predicted : (N,) bool, True = guardrail.

    Returns
    -------
    dict
        ``{"guardrail": {"recall", "precision", "f1", "n"}, "other": {...}, "accuracy", "n"}``;
        a ratio with a zero denominator is None (JSON null).
    """
    labels = np.asarray(labels, bool)
    predicted = np.asarray(predicted, bool)
    if labels.shape != predicted.shape or labels.ndim != 1:
        raise InvalidOptionError(
            f"metrics: expected labels and predictions of the same (N,) shape, got "
            f"{labels.shape} and {predicted.shape}"
        )

    def ratio(num: int, den: int) -> float | None:
        return float(num / den) if den else None

    out: dict[str, Any] = {}
    for name, cls in (("guardrail", True), ("other", False)):
        truth = labels == cls
        called = predicted == cls
        tp = int(np.count_nonzero(truth & called))
        recall = ratio(tp, int(truth.sum()))
        precision = ratio(tp, int(called.sum()))
        if recall is None or precision is None:
            f1 = None
        else:
            f1 = 0.0 if recall + precision == 0 else 2 * recall * precision / (recall + precision)
        out[name] = {"recall": recall, "precision": precision, "f1": f1, "n": int(truth.sum())}
    out["accuracy"] = ratio(int(np.count_nonzero(labels == predicted)), len(labels))
    out["n"] = len(labels)
    return out


def held_out_mask(
    labels: np.ndarray,
    groups: np.ndarray,
    fraction: float,
    rng: np.random.Generator,
    *,
    draws: int = _DEFAULTS.held_out_draws,
) -> np.ndarray:
    """(N,) bool: crops of a random subset of whole groups, about ``fraction`` of the groups.

    Groups are stratified by what they hold (only guardrail, only other, both) and the count per
    stratum is rounded at random; of up to ``draws`` draws the first in which both classes appear
    in both parts is taken, else the first that leaves both classes to train on, else nothing is
    held out (too few groups to measure).
    """
    n = len(labels)
    if fraction == 0:
        return np.zeros(n, bool)
    _, inverse = np.unique(groups, return_inverse=True)
    n_groups = int(inverse.max()) + 1
    has_pos = np.bincount(inverse, weights=labels, minlength=n_groups) > 0
    has_neg = np.bincount(inverse, weights=~labels, minlength=n_groups) > 0
    stratum = has_pos.astype(np.int64) + 2 * has_neg.astype(np.int64)
    fallback = None
    for _ in range(draws):
        held_groups = np.zeros(n_groups, bool)
        for s in np.unique(stratum):
            members = np.flatnonzero(stratum == s)
            target = fraction * len(members)
            count = int(np.floor(target) + (rng.random() < target - np.floor(target)))
            held_groups[rng.permutation(members)[:count]] = True
        held = held_groups[inverse]
        train_both = labels[~held].any() and not labels[~held].all()
        if not train_both or not held.any():
            continue
        if labels[held].any() and not labels[held].all():
            return held
        if fallback is None:
            fallback = held
    return fallback if fallback is not None else np.zeros(n, bool)


def _class_weights(labels: np.ndarray) -> torch.Tensor:
    """Balanced cross-entropy weights N / (2 n_c), index order of :data:`CLASS_NAMES`."""
    counts = np.array([np.count_nonzero(~labels), np.count_nonzero(labels)], np.float64)
    return torch.tensor(len(labels) / (len(counts) * counts), dtype=torch.float32)


def _fit_fast(
    embeddings: np.ndarray, labels: np.ndarray, params: ClassifierParams
) -> tuple[nn.Module, np.ndarray, np.ndarray]:
    """Standardisation and head trained on (N, 1280) embeddings, full batch."""
    mean = embeddings.mean(axis=0, dtype=np.float64).astype(np.float32)
    scale = embeddings.std(axis=0, dtype=np.float64).astype(np.float32)
    scale = np.maximum(scale, np.float32(1e-6))  # constant features: keep them at 0
    x = torch.from_numpy((embeddings - mean) / scale)
    y = torch.from_numpy(labels.astype(np.int64))
    with torch.random.fork_rng(devices=[]), one_thread():
        torch.manual_seed(params.seed)
        head = make_head(params.fast_hidden_units, params.fast_dropout)
        loss_fn = nn.CrossEntropyLoss(weight=_class_weights(labels))
        optimiser = torch.optim.AdamW(head.parameters(), lr=params.fast_lr, weight_decay=0.0)
        matrices = [p for name, p in head.named_parameters() if name.endswith("weight")]
        head.train()
        for _ in range(params.fast_epochs):
            optimiser.zero_grad()
            loss = loss_fn(head(x), y)
            if params.fast_l2:
                loss = loss + params.fast_l2 * sum(m.square().sum() for m in matrices)
            loss.backward()
            optimiser.step()
    head.eval()
    head.requires_grad_(False)
    return head, mean, scale


def _fit_full(
    crops: np.ndarray, labels: np.ndarray, params: ClassifierParams, *, progress: bool
) -> nn.Module:
    """Fine-tune the whole pretrained network with a new 2-class final layer (§3.3)."""
    n = len(crops)
    batch = min(params.batch_size, n)
    steps_per_epoch = math.ceil(n / batch)
    y = torch.from_numpy(labels.astype(np.int64))
    pretrained = load_backbone()  # before seeding: a first load draws random initial weights
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(params.seed)
        generator = torch.Generator().manual_seed(params.seed)
        net = copy.deepcopy(pretrained)
        net._fc = nn.Linear(EMBEDDING_DIM, len(CLASS_NAMES))  # §3.3: new two-class layer
        net.requires_grad_(True)
        head_ids = {id(p) for p in net._fc.parameters()}
        param_groups: list[dict[str, Any]] = [
            {"params": [p for p in net.parameters() if id(p) not in head_ids]},
            {"params": list(net._fc.parameters()), "lr": params.full_head_lr},
        ]
        optimiser = torch.optim.AdamW(
            param_groups,
            lr=params.full_lr,
            weight_decay=params.full_weight_decay,
        )
        total = params.full_epochs * steps_per_epoch
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=total)
        loss_fn = nn.CrossEntropyLoss(weight=_class_weights(labels))
        net.train()
        with progress_bar(
            total=total, desc="fine-tuning", unit="step", enabled=progress, leave=False
        ) as bar:
            for epoch in range(params.full_epochs):
                order = torch.randperm(n, generator=generator).numpy()
                for step in range(steps_per_epoch):
                    idx = np.sort(order[step * batch : (step + 1) * batch])
                    if len(idx) < 2:  # batch norm needs two samples; it is another crop next epoch
                        schedule.step()
                        bar.update()
                        continue
                    x = to_input(crops[idx])
                    flip = torch.rand(len(idx), generator=generator) < params.full_flip_probability
                    x = torch.where(flip[:, None, None, None], x.flip(3), x)
                    loss = loss_fn(net(x), y[idx])
                    optimiser.zero_grad()
                    loss.backward()
                    optimiser.step()
                    schedule.step()
                    bar.update()
                    bar.set_postfix(epoch=epoch + 1, loss=f"{loss.item():.3f}")
    net.eval()
    net.requires_grad_(False)
    return net


def _make_info(
    params: ClassifierParams,
    weights: dict[str, np.ndarray],
    *,
    trained_on: dict[str, Any],
    held_out: dict[str, Any] | None,
    training: dict[str, Any],
) -> dict[str, Any]:
    created = datetime.now(UTC).replace(microsecond=0)
    return {
        "architecture": ARCHITECTURE,
        "mode": params.mode,
        "input_size": params.input_size_px,
        "classes": list(CLASS_NAMES),
        "threshold": params.threshold,
        "version": model_version(created, weights),
        "created": created.isoformat(),
        "backbone": backbone_info(),
        "trained_on": trained_on,
        "metrics": {"held_out": held_out},
        "training": training,
        "params": params.to_json(),
    }


def train_classifier(
    crops: np.ndarray | None,
    labels: np.ndarray,
    *,
    groups: np.ndarray | None = None,
    embeddings: np.ndarray | None = None,
    params: ClassifierParams = ClassifierParams(),  # noqa: B008 (frozen, immutable)
    trained_on: dict | None = None,
    progress: bool = False,
) -> GuardrailClassifier:
    """Train the guardrail / other crop classifier and measure it on held-out groups (§3.3).

    Parameters
    ----------
    crops : (N, S, S, 3) uint8 with S == ``params.input_size_px``, or None
        Needed in full mode; in fast mode they may be replaced by ``embeddings``.
    labels : (N,) bool, True = guardrail.
    groups : (N,) int or None
        Id of the spatial block of each crop; held-out crops are whole groups, so neighbouring
        (near-identical) crops are never split between training and measurement. None: each crop
        is its own group.
    embeddings : (N, 1280) float32 or None
        Fast mode: :func:`embed_crops` of the crops, computed earlier (skips the backbone; used
        instead of ``crops`` when both are given). Full mode ignores them.
    params : ClassifierParams
    trained_on : dict or None
        JSON-serialisable description of the data (drives, segment counts, ...), stored as is.
    progress : bool, show progress bars (on a terminal).

    Returns
    -------
    GuardrailClassifier
        ``info["metrics"]["held_out"]`` holds :func:`classification_metrics` of the model trained
        without the held-out groups (~``held_out_fraction`` of the groups, both classes in both
        parts when the groups allow), plus ``n_train`` and ``n_held_out``; None when nothing could
        be held out. Fast mode then refits the head on all crops (``fast_refit_on_all``, seconds),
        so the delivered model saw more data than the one measured; full mode delivers the
        measured network itself.

    Raises
    ------
    TrainingDataError
        Fewer than ``params.min_crops`` crops, or only one class.
    InvalidOptionError
        Wrong shapes or dtypes, no crops in full mode (nor embeddings in fast mode), or
        ``trained_on`` not JSON.

    References
    ----------
    Matsumoto et al. 2019, §3.3 (CNN, two classes, fine tuning with few images).
    """
    clock = time.perf_counter()
    if not isinstance(params, ClassifierParams):
        raise InvalidOptionError(f"params: expected ClassifierParams, got {type(params).__name__}")
    labels_in = np.asarray(labels)
    if labels_in.ndim != 1 or not (
        labels_in.dtype == bool
        or (labels_in.dtype.kind in "iu" and np.isin(labels_in, (0, 1)).all())
    ):
        raise InvalidOptionError(
            f"labels: expected an (N,) bool array (True = guardrail), got shape {labels_in.shape} "
            f"dtype {labels_in.dtype}"
        )
    y = labels_in.astype(bool)
    n = len(y)
    if crops is not None:
        crops = check_crops(crops, params.input_size_px)
        if len(crops) != n:
            raise InvalidOptionError(f"crops: expected {n} crops (one per label), got {len(crops)}")
    if params.mode == "full":
        embeddings = None  # fine-tuning changes the features: cached embeddings are of no use
        if crops is None:
            raise InvalidOptionError(
                "train_classifier: full mode fine-tunes the network on the crops, got no crops "
                "(embeddings are not enough)"
            )
    elif embeddings is not None:
        embeddings = check_embeddings(embeddings, n)
    elif crops is None:
        raise InvalidOptionError("train_classifier: expected crops or embeddings, got neither")
    if groups is None:
        g = np.arange(n)
    else:
        g = np.asarray(groups)
        if g.shape != (n,) or g.dtype.kind not in "iu":
            raise InvalidOptionError(
                f"groups: expected an ({n},) integer array of block ids, got shape {g.shape} "
                f"dtype {g.dtype}"
            )
    trained_on = {} if trained_on is None else trained_on
    try:
        trained_on = json.loads(json.dumps(trained_on, allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise InvalidOptionError(
            f"trained_on: expected a JSON-serialisable dict, got {exc}"
        ) from exc
    if not isinstance(trained_on, dict):
        raise InvalidOptionError(f"trained_on: expected a dict, got {type(trained_on).__name__}")

    n_pos = int(y.sum())
    if n < params.min_crops:
        raise TrainingDataError(
            f"training: expected at least {params.min_crops} labelled crops, got {n}"
        )
    if n_pos == 0 or n_pos == n:
        raise TrainingDataError(
            f"training: expected crops of both classes, got {n_pos} guardrail and {n - n_pos} other"
        )

    held = held_out_mask(
        y,
        g,
        params.held_out_fraction,
        np.random.default_rng(params.seed),
        draws=params.held_out_draws,
    )
    train = ~held
    held_out: dict[str, Any] | None = None

    if params.mode == "fast":
        if embeddings is None:
            assert crops is not None
            embeddings = embed_crops(
                crops, batch_size=max(params.batch_size, 64), progress=progress
            )
        info_stub: dict[str, Any] = {
            "mode": "fast",
            "input_size": params.input_size_px,
            "threshold": params.threshold,
        }
        head, mean, scale = _fit_fast(embeddings[train], y[train], params)
        if held.any():
            measured = GuardrailClassifier(
                info_stub, head=head, feature_mean=mean, feature_scale=scale
            )
            predicted = measured.predict_proba(embeddings=embeddings[held]) > params.threshold
            held_out = classification_metrics(y[held], predicted)
            if params.fast_refit_on_all:
                head, mean, scale = _fit_fast(embeddings, y, params)
        clf = GuardrailClassifier(info_stub, head=head, feature_mean=mean, feature_scale=scale)
        refit = bool(held.any() and params.fast_refit_on_all)
    else:
        assert crops is not None
        net = _fit_full(crops[train], y[train], params, progress=progress)
        clf = GuardrailClassifier(
            {"mode": "full", "input_size": params.input_size_px, "threshold": params.threshold},
            net=net,
        )
        if held.any():
            proba = clf.predict_proba(
                crops[held], batch_size=max(params.batch_size, 64), progress=progress
            )
            held_out = classification_metrics(y[held], proba > params.threshold)
        refit = False

    if held_out is not None:
        held_out.pop("n")
        held_out["n_train"] = int(train.sum())
        held_out["n_held_out"] = int(held.sum())
        held_out["n_groups_held_out"] = int(len(np.unique(g[held])))
        held_out["threshold"] = params.threshold
    training = {
        "n_crops": n,
        "n_guardrail": n_pos,
        "n_other": n - n_pos,
        "n_groups": int(len(np.unique(g))),
        "final_model_trained_on": "all crops" if refit or held_out is None else "training split",
        "seconds": round(time.perf_counter() - clock, 2),
    }
    clf.info = _make_info(
        params, clf.weights(), trained_on=trained_on, held_out=held_out, training=training
    )
    return clf
