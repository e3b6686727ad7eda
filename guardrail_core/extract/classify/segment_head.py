"""The segment head: P(guardrail) of a segment from its shape, its neighbours and its crop.

The crop classifier (§3.3) sees only an image, and a segment without a usable image gets no
answer from it. The segment head is a small network over every segment: its shape and neighbour
features (:mod:`guardrail_core.extract.classify.shape_features`), the crop classifier's logit,
and whether there was a crop at all. It is trained on crop logits predicted out of fold (by crop
classifiers that never saw that crop), so it learns how far to trust the crop classifier on new
data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from guardrail_core.errors import InvalidOptionError, ModelFormatError
from guardrail_core.extract.classify.crop_classifier_params import TRAINING_CLIP
from guardrail_core.extract.classify.shape_features import (
    SEGMENT_FEATURE_NAMES,
    WHOLE_COMPONENT_FEATURE_NAMES,
    feature_columns,
)
from guardrail_core.extract.classify.torch_threads import one_thread
from guardrail_core.params import StageParams, param


def max_logit(clip: float) -> float:
    """The largest crop logit the head sees when crop probabilities are clipped to ``clip``."""
    clip = max(float(clip), TRAINING_CLIP)
    return float(np.log((1 - clip) / clip))


@dataclass(frozen=True)
class SegmentHeadParams(StageParams):
    """Training of the segment head."""

    hidden_units: int = param(64, ge=1, le=4096, doc="width of each member's hidden ReLU layer")
    members: int = param(
        3,
        ge=1,
        le=32,
        doc="networks trained side by side from different initial weights, their logits "
        "averaged (the saved head is one network, members x hidden_units wide): one network's "
        "verdict on a segment unlike its training segments swings with its initial draw (on the "
        "real KITTI street, two draws called 110 and 1,065 points guardrail), the average far "
        "less. Training takes members times as long",
    )
    epochs: int = param(1000, ge=1, le=100_000, doc="full-batch AdamW steps")
    fine_tune_epochs: int = param(
        200,
        ge=1,
        le=100_000,
        doc="full-batch AdamW steps when a trained head is fine-tuned (the review app's Train "
        "starts from the run's model): few enough that what its training drives taught stays "
        "where the run's labels do not say otherwise. On four streets of designs the model "
        "never saw, 200 reached F 0.98 within 100 operator labels on all four (README, the "
        "review loop's learning curve)",
    )
    lr: float = param(1e-2, gt=0, le=1, doc="learning rate")
    weight_decay: float = param(1e-4, ge=0, le=1, doc="AdamW decoupled weight decay")
    folds: int = param(
        4,
        ge=2,
        le=100,
        doc="the training crops are split into this many folds of whole spatial blocks; each "
        "fold's crop logits come from a crop classifier trained on the other folds",
    )
    feature_dropout: float = param(
        0.0,
        ge=0,
        lt=1,
        doc="share of the shape and neighbour features hidden from each segment at each "
        "training step, drawn anew each step (a hidden feature reads as its training mean; the "
        "crop logit and has-crop never are). Trained on every feature, a head may veto any crop "
        "by a shape it never saw; hidden ones teach it to hear the crop. It trades precision "
        "on the designs it was trained on for recall on those it was not (README, leave one "
        "design out): 0.1 took a development street's thrie beam, left out of training, from F "
        "0.80 to 0.95 for 0.002 of F on the fourteen development streets; 0.5 lost 0.009 there",
    )
    ignored_features: str = param(
        "",
        doc="segment features the head does not read, comma-separated (the model lists those "
        "it reads); 'intensity_mean,intensity_std' for a model meant for scanners whose "
        "intensity is calibrated otherwise than its training drives'",
    )

    def check_relations(self) -> None:
        try:
            self.columns()
        except ValueError as exc:
            self.fail(f"ignored_features: {exc}")

    def feature_names(self) -> tuple[str, ...]:
        """The segment features the head reads, in :data:`SEGMENT_FEATURE_NAMES` order: all but
        the ignored ones and those kept for models trained before chains."""
        ignored = [name.strip() for name in self.ignored_features.split(",") if name.strip()]
        feature_columns(ignored)  # every name known
        ignored += WHOLE_COMPONENT_FEATURE_NAMES
        return tuple(name for name in SEGMENT_FEATURE_NAMES if name not in ignored)

    def columns(self) -> np.ndarray:
        """(K,) int64: the columns of the segment features the head reads."""
        names = self.feature_names()
        if not names:
            raise ValueError("every segment feature is ignored")
        return feature_columns(names)


def head_inputs(
    features: np.ndarray, crop_proba: np.ndarray, clip: float = TRAINING_CLIP
) -> np.ndarray:
    """(S, F + 2) float32: the features, the crop logit (0 without a crop) and has-crop (0/1).

    Parameters
    ----------
    features : (S, F) float32,
        :func:`~guardrail_core.extract.classify.shape_features.segment_features`
    crop_proba : (S,) float, the crop classifier's P(guardrail); NaN where there is no crop
    clip : crop probabilities are clipped to [clip, 1 - clip] first (never less than
        :data:`TRAINING_CLIP`)
    """
    features = np.asarray(features, np.float32)
    crop_proba = np.asarray(crop_proba, np.float64)
    if features.ndim != 2 or crop_proba.shape != (len(features),):
        raise InvalidOptionError(
            f"segment head: expected (S, F) features and (S,) crop probabilities, got "
            f"{features.shape} and {crop_proba.shape}"
        )
    has_crop = np.isfinite(crop_proba)
    clip = max(float(clip), TRAINING_CLIP)
    p = np.clip(np.where(has_crop, crop_proba, 0.5), clip, 1 - clip)
    logit = np.log(p / (1 - p))
    return np.concatenate(
        [features, logit[:, None].astype(np.float32), has_crop[:, None].astype(np.float32)],
        axis=1,
    )


def _layers(n_inputs: int, hidden_units: int) -> tuple[nn.Linear, nn.Linear]:
    """A network's two layers, freshly drawn (in this order, as :func:`_network` draws them)."""
    return nn.Linear(n_inputs, hidden_units), nn.Linear(hidden_units, 2)


def _network(n_inputs: int, hidden_units: int) -> nn.Sequential:
    first, second = _layers(n_inputs, hidden_units)
    return nn.Sequential(first, nn.ReLU(), second)


def average_of_members(
    w1: torch.Tensor, b1: torch.Tensor, w2: torch.Tensor, b2: torch.Tensor
) -> nn.Sequential:
    """One network whose logits are the mean of k members': their hidden layers side by side
    (w1 (k H, D), b1 (k H,)), their output layers (w2 (k, 2, H), b2 (k, 2)) each weighted 1 / k."""
    k, _, h = w2.shape
    first, second = _layers(w1.shape[1], k * h)
    with torch.no_grad():
        first.weight.copy_(w1)
        first.bias.copy_(b1)
        second.weight.copy_(w2.permute(1, 0, 2).reshape(2, k * h) / k)
        second.bias.copy_(b2.mean(dim=0))
    return nn.Sequential(first, nn.ReLU(), second)


def members_of(
    net: nn.Sequential, members: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The k members of a network :func:`average_of_members` made: w1 (k H, D), b1 (k H,),
    w2 (k, 2, H), b2 (k, 2), each member answering with the average's output bias (the inverse
    of :func:`average_of_members` up to how the bias is shared among the members)."""
    state = net.state_dict()
    w1, b1 = state["0.weight"].clone(), state["0.bias"].clone()
    second, bias = state["2.weight"], state["2.bias"]
    h = second.shape[1] // members
    if h * members != second.shape[1]:
        raise InvalidOptionError(
            f"segment head: a network {second.shape[1]} units wide is not {members} members"
        )
    w2 = (second.reshape(2, members, h).permute(1, 0, 2) * members).contiguous()
    b2 = bias.expand(members, 2).clone()
    return w1, b1, w2, b2


class SegmentHead:
    """A trained segment head: standardisation and a one-hidden-layer network.

    Attributes
    ----------
    mean, scale : (F + 2,) float32, standardisation of :func:`head_inputs`
    columns : (F,) int64 or None, the columns of the segment features given to :meth:`proba`
        and :meth:`proba_range` that the head reads (None: all of them)
    """

    def __init__(
        self,
        mean: np.ndarray,
        scale: np.ndarray,
        net: nn.Sequential,
        columns: np.ndarray | None = None,
    ) -> None:
        self.mean = mean
        self.scale = scale
        self.columns = None if columns is None else np.asarray(columns, np.int64)
        if self.columns is not None and len(self.columns) != len(mean) - 2:
            raise ModelFormatError(
                f"segment head: it takes {len(mean) - 2} features, {len(self.columns)} are named"
            )
        self._net = net
        net.eval()
        net.requires_grad_(False)

    @property
    def n_inputs(self) -> int:
        return int(len(self.mean))

    def _read(self, features: np.ndarray) -> np.ndarray:
        features = np.asarray(features, np.float32)
        if self.columns is None:
            return features
        if features.ndim != 2 or features.shape[1] <= self.columns.max(initial=-1):
            raise InvalidOptionError(
                f"segment head: expected (S, F) features with the columns it reads, got "
                f"{features.shape}"
            )
        return np.ascontiguousarray(features[:, self.columns])  # a column pick is F-ordered

    def proba(
        self, features: np.ndarray, crop_proba: np.ndarray, clip: float = TRAINING_CLIP
    ) -> np.ndarray:
        """(S,) float64 P(guardrail) of segments; see :func:`head_inputs` for the inputs."""
        x = head_inputs(self._read(features), crop_proba, clip)
        if x.shape[1] != self.n_inputs:
            raise InvalidOptionError(
                f"segment head: expected {self.n_inputs - 2} features per segment, got "
                f"{x.shape[1] - 2}"
            )
        if len(x) == 0:
            return np.zeros(0)
        z = torch.from_numpy((x - self.mean) / self.scale)
        with torch.inference_mode(), one_thread():
            return torch.softmax(self._net(z), dim=1)[:, 1].numpy().astype(np.float64)

    def proba_range(
        self, features: np.ndarray, clip: float = TRAINING_CLIP
    ) -> tuple[np.ndarray, np.ndarray]:
        """The least and the greatest P(guardrail) the head can give each segment with a crop,
        whatever the crop's probability: what the shape alone leaves open.

        Exact: with the other inputs fixed, the head's output logit is piecewise linear in the
        crop logit (one hidden ReLU layer), so its extremes over the clipped logits lie at the
        ends or where a hidden unit switches on or off.

        Parameters
        ----------
        features : (S, F) float32, as for :meth:`proba`
        clip : the crop probabilities' clip, as for :meth:`proba`

        Returns
        -------
        lo, hi : (S,) float64 in [0, 1], lo <= :meth:`proba` <= hi for every crop probability
        """
        x = head_inputs(self._read(features), np.full(len(features), 0.5)).astype(np.float64)
        top = max_logit(clip)
        if x.shape[1] != self.n_inputs:
            raise InvalidOptionError(
                f"segment head: expected {self.n_inputs - 2} features per segment, got "
                f"{x.shape[1] - 2}"
            )
        state = {k: v.double().numpy() for k, v in self._net.state_dict().items()}
        w1, b1 = state["0.weight"], state["0.bias"]  # (H, F + 2), (H,)
        w_out = state["2.weight"][1] - state["2.weight"][0]  # (H,): class 1's logit minus 0's
        b_out = float(state["2.bias"][1] - state["2.bias"][0])
        logit_col = self.n_inputs - 2
        z = (x - self.mean.astype(np.float64)) / self.scale.astype(np.float64)
        z[:, logit_col] = 0.0
        # Hidden pre-activations as a + slope * t, t the crop logit: (S, H) and (H,)
        slope = w1[:, logit_col] / float(self.scale[logit_col])
        a = z @ w1.T + b1 - float(self.mean[logit_col]) * slope
        with np.errstate(divide="ignore", invalid="ignore"):
            switch = np.where(slope != 0, -a / slope, -top)  # (S, H)
        t = np.concatenate(
            [
                np.full((len(x), 2), [-top, top]),
                np.clip(switch, -top, top),
            ],
            axis=1,
        )  # (S, H + 2) candidate crop logits
        lo = np.full(len(x), np.inf)
        hi = np.full(len(x), -np.inf)
        for k in range(t.shape[1]):  # one (S, H) pass per candidate keeps the memory small
            logit = np.maximum(a + t[:, k : k + 1] * slope, 0.0) @ w_out + b_out
            lo, hi = np.minimum(lo, logit), np.maximum(hi, logit)
        sigmoid = 1.0 / (1.0 + np.exp(-np.stack([lo, hi])))
        return sigmoid[0], sigmoid[1]

    def weights(self, prefix: str) -> dict[str, np.ndarray]:
        """Named arrays for ``weights.npz``: ``<prefix>mean``, ``<prefix>scale``, the layers."""
        out = {f"{prefix}net.{k}": v.numpy().copy() for k, v in self._net.state_dict().items()}
        out[f"{prefix}mean"] = self.mean
        out[f"{prefix}scale"] = self.scale
        return out

    @classmethod
    def from_weights(
        cls, weights: dict[str, np.ndarray], prefix: str, columns: np.ndarray | None = None
    ) -> SegmentHead:
        """Rebuild from :meth:`weights` (and the ``columns`` it reads);
        :class:`ModelFormatError` when they do not fit."""
        try:
            mean = np.asarray(weights[f"{prefix}mean"], np.float32)
            scale = np.asarray(weights[f"{prefix}scale"], np.float32)
            first = np.asarray(weights[f"{prefix}net.0.weight"])
        except KeyError as exc:
            raise ModelFormatError(f"weights: the segment head lacks {exc.args[0]}") from exc
        if mean.ndim != 1 or scale.shape != mean.shape or not np.all(scale > 0):
            raise ModelFormatError("weights: the segment head's standardisation is malformed")
        if first.ndim != 2 or first.shape[1] != len(mean):
            raise ModelFormatError(
                f"weights: the segment head's first layer {first.shape} does not take "
                f"{len(mean)} inputs"
            )
        net = _network(len(mean), first.shape[0])
        state = {
            k[len(prefix) + 4 :]: torch.from_numpy(np.array(v))
            for k, v in weights.items()
            if k.startswith(f"{prefix}net.")
        }
        try:
            net.load_state_dict(state, strict=True)
        except RuntimeError as exc:
            raise ModelFormatError(f"weights: the segment head does not load: {exc}") from exc
        return cls(mean, scale, net, columns)


def fit_segment_head(
    features: np.ndarray,
    crop_proba: np.ndarray,
    labels: np.ndarray,
    params: SegmentHeadParams = SegmentHeadParams(),
    *,
    seed: int = 0,
    columns: np.ndarray | None = None,
    sample_weight: np.ndarray | None = None,
    start: SegmentHead | None = None,
) -> SegmentHead:
    """Train a segment head, full batch, with balanced class weights: ``params.members``
    networks from different initial weights, saved as one network that averages their logits.
    Or fine-tune one: from ``start``'s networks, for ``params.fine_tune_epochs``.

    Parameters
    ----------
    features : (S, F) float32 segment features
    crop_proba : (S,) out-of-fold crop P(guardrail), NaN where there is no crop
    labels : (S,) bool, True = guardrail; both classes must occur
    columns : (K,) int, the feature columns the head reads (None: all F)
    sample_weight : (S,) float > 0, how much each segment's label counts (None: all alike); the
        classes stay balanced by count, and each segment's loss is weighted by its class
        weight times this
    start : a trained head to start from, with its standardisation, so that the new head first
        answers as it does; it must read the same columns and be ``params.members`` networks
        of ``params.hidden_units`` (else :class:`InvalidOptionError`)
    """
    if columns is not None:
        features = np.ascontiguousarray(np.asarray(features, np.float32)[:, np.asarray(columns)])
    x = head_inputs(features, crop_proba)
    y = np.asarray(labels, bool)
    counts = np.array([np.count_nonzero(~y), np.count_nonzero(y)], np.float64)
    if len(y) != len(x) or counts.min() == 0:
        raise InvalidOptionError(
            f"segment head: expected labels of both classes for {len(x)} segments, got "
            f"{int(counts[1])} guardrail and {int(counts[0])} other"
        )
    if sample_weight is not None:
        sample_weight = np.asarray(sample_weight, np.float32)
        if sample_weight.shape != y.shape or not (
            np.isfinite(sample_weight).all() and (sample_weight > 0).all()
        ):
            raise InvalidOptionError(
                f"segment head: expected {len(y)} positive finite sample weights, got "
                f"{sample_weight.shape}"
            )
    mean = x.mean(axis=0)
    scale = np.maximum(x.std(axis=0), np.float32(1e-6))
    epochs = params.epochs
    if start is not None:
        _check_start(start, columns, x.shape[1], params)
        mean, scale, epochs = start.mean, start.scale, params.fine_tune_epochs
    z = torch.from_numpy((x - mean) / scale)
    target = torch.from_numpy(y.astype(np.int64))
    class_weight = torch.tensor(len(y) / (2 * counts), dtype=torch.float32)
    # CrossEntropyLoss's weighted mean, each term weighted by its class and its segment.
    w = class_weight[target]
    if sample_weight is not None:
        w = w * torch.from_numpy(sample_weight)
    each = nn.CrossEntropyLoss(reduction="none")
    k = params.members
    with torch.random.fork_rng(devices=[]), one_thread():
        torch.manual_seed(seed)
        members = [_layers(x.shape[1], params.hidden_units) for _ in range(k)]
        # The members as stacked tensors, trained in one pass: each member's loss reaches only
        # its own weights, and AdamW updates every weight on its own, so this is k trainings.
        h = params.hidden_units
        if start is None:
            first = (
                torch.cat([a.weight.detach() for a, _ in members]),  # (k H, D)
                torch.cat([a.bias.detach() for a, _ in members]),  # (k H,)
                torch.stack([b.weight.detach() for _, b in members]),  # (k, 2, H)
                torch.stack([b.bias.detach() for _, b in members]),  # (k, 2)
            )
        else:
            first = members_of(start._net, k)
        w1, b1, w2, b2 = (nn.Parameter(t) for t in first)
        optimiser = torch.optim.AdamW(
            [w1, b1, w2, b2], lr=params.lr, weight_decay=params.weight_decay
        )
        n_shape = z.shape[1] - 2  # the last two inputs, the crop logit and has-crop, stay
        # The features hidden are drawn on their own generator, the same for every member and
        # whatever the members' initial draws took.
        hiding = torch.Generator().manual_seed(seed)
        for _ in range(epochs):
            optimiser.zero_grad()
            seen = z
            if params.feature_dropout > 0:
                draw = torch.rand(len(z), n_shape, generator=hiding)
                kept = (draw >= params.feature_dropout).to(z.dtype)
                seen = torch.cat([z[:, :n_shape] * kept, z[:, n_shape:]], dim=1)
            hidden = torch.relu(torch.addmm(b1, seen, w1.T)).view(len(z), k, h)
            logits = torch.einsum("skh,kch->skc", hidden, w2) + b2  # (S, k, 2)
            # Each member's weighted mean loss, summed over the members.
            loss = (each(logits.permute(0, 2, 1), target[:, None].expand(-1, k)) * w[:, None]).sum()
            (loss / w.sum()).backward()
            optimiser.step()
        net = average_of_members(w1.detach(), b1.detach(), w2.detach(), b2.detach())
    return SegmentHead(mean.astype(np.float32), scale.astype(np.float32), net, columns)


def _check_start(
    start: SegmentHead, columns: np.ndarray | None, n_inputs: int, params: SegmentHeadParams
) -> None:
    """:class:`InvalidOptionError` unless ``start`` can be fine-tuned with these columns and
    params (see :func:`fit_segment_head`); the message names the features that differ."""
    same_columns = (start.columns is None and columns is None) or (
        start.columns is not None
        and columns is not None
        and np.array_equal(start.columns, np.asarray(columns))
    )
    width = start._net.state_dict()["0.weight"].shape[0]
    if not same_columns or start.n_inputs != n_inputs:
        differ = _columns_differ(start.columns, start.n_inputs - 2, columns, n_inputs - 2)
        raise InvalidOptionError(
            "segment head: the head to start from reads other segment features than those "
            f"asked for ({differ}); "
            "fine-tune it on the columns it reads (SegmentHead.columns)"
        )
    if width != params.members * params.hidden_units:
        raise InvalidOptionError(
            f"segment head: the head to start from is {width} units wide, not "
            f"{params.members} members of {params.hidden_units}"
        )


def column_names(columns: np.ndarray | None) -> tuple[str, ...]:
    """The segment features' names of ``columns`` (K,) int (None: every column)."""
    if columns is None:
        return SEGMENT_FEATURE_NAMES
    return tuple(SEGMENT_FEATURE_NAMES[int(k)] for k in columns)


def _columns_differ(
    start: np.ndarray | None, n_start: int, asked: np.ndarray | None, n_asked: int
) -> str:
    """Which features the head to start from (``start`` columns, ``n_start`` of them) reads and
    the ones asked for (``asked``, ``n_asked``) do not, and the reverse, by name."""
    if (start is None or asked is None) and n_start != n_asked:
        return f"it reads {n_start} columns, {n_asked} are asked for"
    have, want = column_names(start), column_names(asked)
    only_start = [name for name in have if name not in want]
    only_asked = [name for name in want if name not in have]
    parts = []
    if only_start:
        parts.append("it reads " + ", ".join(only_start) + ", not asked for")
    if only_asked:
        parts.append("it does not read " + ", ".join(only_asked) + ", asked for")
    return "; ".join(parts) or "the same features in another order"
