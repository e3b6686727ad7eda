"""The trained crop classifier as an object: P(guardrail) of crops (§3.3), and of segments.

A fast model is a feature standardisation and a small head on the frozen backbone's embeddings;
a full model is the whole fine-tuned network.
:mod:`guardrail_core.extract.classify.crop_classifier_training` makes one,
:mod:`guardrail_core.extract.classify.model_folder` saves and loads it.
"""

from __future__ import annotations

import hashlib
from datetime import datetime
from typing import Any

import numpy as np
import torch
from torch import nn

from guardrail_core.errors import InvalidOptionError, ModelFormatError
from guardrail_core.extract.classify.backbone import (
    ARCHITECTURE,
    EMBEDDING_DIM,
    CropEmbedder,
    check_crops,
    check_embeddings,
    embed_crops,
    new_network,
    normalise,
)
from guardrail_core.extract.classify.cnn_runtime import BATCH_SIZE, CropNetwork, chosen_runtime
from guardrail_core.extract.classify.crop_classifier_params import (
    CLASS_NAMES,
    TRAINING_CLIP,
    ClassifierParams,
)
from guardrail_core.extract.classify.segment_head import SegmentHead
from guardrail_core.extract.classify.shape_features import check_feature_layout, feature_columns
from guardrail_core.extract.classify.torch_threads import one_thread

SEGMENT_PREFIX = "segment."  # names of the segment head's arrays in weights.npz
#: shape_decides keeps this far (in probability) from the threshold: the head runs in float32,
#: its bounds in float64.
DECIDED_MARGIN = 1e-4


def make_head(hidden_units: int, dropout: float) -> nn.Module:
    """The fast model's head: (B, 1280) standardised embeddings -> (B, 2) logits; a linear layer,
    or one hidden ReLU layer of ``hidden_units`` with dropout."""
    if hidden_units == 0:
        return nn.Linear(EMBEDDING_DIM, len(CLASS_NAMES))
    return nn.Sequential(
        nn.Linear(EMBEDDING_DIM, hidden_units),
        nn.ReLU(),
        nn.Dropout(dropout),
        nn.Linear(hidden_units, len(CLASS_NAMES)),
    )


class CropProbability(nn.Module):
    """(B, S, S, 3) uint8 crops -> (B,) float32 P(guardrail) of a full (2-class) network."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, crops: torch.Tensor) -> torch.Tensor:
        return torch.softmax(self.net(normalise(crops)), dim=1)[:, 1]


def _new_full_network() -> nn.Module:
    """EfficientNet-Lite0 with a 2-class final layer (random weights)."""
    return new_network(num_classes=len(CLASS_NAMES))


def weights_digest(weights: dict[str, np.ndarray]) -> str:
    """sha256 (hex) of named arrays: names, dtypes, shapes and bytes, in name order."""
    digest = hashlib.sha256()
    for name in sorted(weights):
        array = np.ascontiguousarray(weights[name])
        digest.update(f"{name}|{array.dtype.str}|{array.shape}|".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def model_version(created: datetime, weights: dict[str, np.ndarray]) -> str:
    """``<UTC creation time YYYYmmddTHHMMSS>-<8 hex of the weights' sha256>``."""
    return f"{created:%Y%m%dT%H%M%S}-{weights_digest(weights)[:8]}"


class GuardrailClassifier:
    """A trained crop classifier: P(guardrail) for (N, S, S, 3) uint8 crops (§3.3), and, when
    trained from drives, a segment head that fuses it with the segments' shape.

    Made by :func:`~guardrail_core.extract.classify.crop_classifier_training.train_classifier`
    (crops alone), :func:`guardrail_core.extract.classify.model_training.train_from_drives`
    (with the segment head) or :func:`guardrail_core.extract.classify.model_folder.load_model`.

    Attributes
    ----------
    segment_head : SegmentHead or None, see :meth:`segment_proba`
    info : dict
        Everything :func:`~guardrail_core.extract.classify.model_folder.save_model` writes to
        ``model.json`` except ``format_version`` (which belongs to the store): architecture, mode,
        input_size, classes, threshold, version, created, backbone, trained_on, metrics
        {"held_out": ...}, training, params.
    """

    def __init__(
        self,
        info: dict[str, Any],
        *,
        net: nn.Module | None = None,
        head: nn.Module | None = None,
        feature_mean: np.ndarray | None = None,
        feature_scale: np.ndarray | None = None,
        segment_head: SegmentHead | None = None,
    ) -> None:
        self.info = info
        self.segment_head = segment_head
        self._net = net
        self._head = head
        self._feature_mean = feature_mean
        self._feature_scale = feature_scale
        self._networks: dict[tuple[str, str], CropNetwork] = {}  # (output, runtime) -> network
        if info["mode"] == "full":
            if net is None:
                raise InvalidOptionError("a full classifier needs its network")
            net.eval()
        else:
            if head is None or feature_mean is None or feature_scale is None:
                raise InvalidOptionError("a fast classifier needs its head and standardisation")
            head.eval()

    def __repr__(self) -> str:
        return (
            f"GuardrailClassifier(version={self.version!r}, mode={self.mode!r}, "
            f"input_size={self.input_size})"
        )

    @property
    def version(self) -> str:
        """Unique id: ``<UTC creation time YYYYmmddTHHMMSS>-<8 hex of the weights' sha256>``."""
        return str(self.info["version"])

    @property
    def mode(self) -> str:
        return str(self.info["mode"])

    @property
    def input_size(self) -> int:
        return int(self.info["input_size"])

    @property
    def threshold(self) -> float:
        return float(self.info["threshold"])

    def embed(
        self,
        crops: np.ndarray,
        *,
        batch_size: int = BATCH_SIZE,
        progress: bool = False,
        runtime: str | None = None,
    ) -> np.ndarray:
        """Embeddings the model classifies: (N, S, S, 3) uint8 -> (N, 1280) float32.

        A fast model uses the frozen ImageNet backbone (same as :func:`embed_crops`; cache and pass
        them to :meth:`predict_proba`); a full model returns its own fine-tuned pooled features.
        ``runtime``: ``auto``, ``onnxruntime`` or ``torch``; None: ``$GUARDRAIL_CNN_RUNTIME``
        (:mod:`~guardrail_core.extract.classify.cnn_runtime`).
        """
        crops = check_crops(crops, self.input_size)
        if self._net is None:
            return embed_crops(crops, batch_size=batch_size, progress=progress, runtime=runtime)
        network = self._network("embedding", runtime)
        return network(crops, batch_size=batch_size, progress=progress, desc="embedding crops")

    def predict_proba(
        self,
        crops: np.ndarray | None = None,
        *,
        embeddings: np.ndarray | None = None,
        batch_size: int = BATCH_SIZE,
        progress: bool = False,
        runtime: str | None = None,
    ) -> np.ndarray:
        """P(guardrail) of each crop.

        Parameters
        ----------
        crops : (N, S, S, 3) uint8, S == :attr:`input_size`; or None
        embeddings : (N, 1280) float32 from :meth:`embed` / :func:`embed_crops`; fast models only.
            Give exactly one of ``crops`` and ``embeddings``.
        runtime : the CNN's runtime, see :meth:`embed`

        Returns
        -------
        proba : (N,) float64 in [0, 1]

        Raises :class:`InvalidOptionError` for wrong shapes, for both or neither input, and for
        embeddings given to a full model (it needs the crops).
        """
        if (crops is None) == (embeddings is None):
            raise InvalidOptionError(
                "predict_proba: give either crops or embeddings, got "
                + ("neither" if crops is None else "both")
            )
        if embeddings is not None:
            if self._net is not None:
                raise InvalidOptionError(
                    "predict_proba: a full (fine-tuned) model needs the crops, got only embeddings"
                )
            return self._head_proba(check_embeddings(embeddings))
        crops = check_crops(crops, self.input_size)
        if self._net is None:
            embeddings = embed_crops(
                crops, batch_size=batch_size, progress=progress, runtime=runtime
            )
            return self._head_proba(embeddings)
        network = self._network("probability", runtime)
        proba = network(crops, batch_size=batch_size, progress=progress, desc="classifying crops")
        return proba.astype(np.float64)

    def segment_proba(
        self, features: np.ndarray, crop_proba: np.ndarray, crop_clip: float = TRAINING_CLIP
    ) -> np.ndarray:
        """(S,) float64 P(guardrail) of whole segments.

        With a segment head: from the segments' shape and neighbour features (S, F) and their crop
        probabilities (S,), NaN where a segment has no crop, clipped to [``crop_clip``,
        1 - ``crop_clip``] (``ClassifyParams.crop_probability_clip``); every segment gets an
        answer. Without one (a crop classifier alone): the crop probabilities as given, NaN
        included.

        Raises :class:`~guardrail_core.errors.IncompatibleModelError` for features laid out by
        another version (:func:`~.shape_features.check_feature_layout`).
        """
        if self.segment_head is None:
            return np.asarray(crop_proba, np.float64).copy()
        return self.segment_head.proba(check_feature_layout(features), crop_proba, crop_clip)

    def shape_decides(self, features: np.ndarray, crop_clip: float = TRAINING_CLIP) -> np.ndarray:
        """(S,) bool: segments whose label the segment head gives whatever their crop says.

        For these the CNN can be skipped: :meth:`segment_proba` with any crop probability in
        [0, 1] (0.5, say, for a crop not looked at) puts them on the same side of
        :attr:`threshold` as their own crop would (:meth:`SegmentHead.proba_range`). Only for
        segments that have a crop: one without keeps NaN, which the head answers otherwise.
        Without a segment head, none. On the simulated test drives (seeds 20001, 20002) the
        shape decides two thirds of the crops, with every label unchanged.

        Parameters
        ----------
        features : (S, F) float32 segment features, as for :meth:`segment_proba`
        crop_clip : the crop probabilities' clip, as for :meth:`segment_proba`
        """
        if self.segment_head is None:
            return np.zeros(len(features), bool)
        lo, hi = self.segment_head.proba_range(check_feature_layout(features), crop_clip)
        return (hi < self.threshold - DECIDED_MARGIN) | (lo >= self.threshold + DECIDED_MARGIN)

    def predict(
        self,
        crops: np.ndarray | None = None,
        *,
        embeddings: np.ndarray | None = None,
        progress: bool = False,
    ) -> np.ndarray:
        """(N,) bool: True where P(guardrail) > :attr:`threshold`."""
        return self.predict_proba(crops, embeddings=embeddings, progress=progress) > self.threshold

    def _network(self, output: str, runtime: str | None) -> CropNetwork:
        """A full model's network as a :class:`CropNetwork`: its ``"embedding"`` (pooled
        features) or ``"probability"``, made on first use per runtime."""
        assert self._net is not None  # full models only
        key = (output, chosen_runtime(runtime))
        network = self._networks.get(key)
        if network is None:
            if output == "embedding":
                network = CropNetwork(
                    CropEmbedder(self._net), self.input_size, (EMBEDDING_DIM,), runtime=key[1]
                )
            else:
                network = CropNetwork(
                    CropProbability(self._net), self.input_size, (), runtime=key[1]
                )
            network = self._networks.setdefault(key, network)
        return network

    def _head_proba(self, embeddings: np.ndarray) -> np.ndarray:
        assert self._head is not None and self._feature_mean is not None  # set for fast models
        assert self._feature_scale is not None
        z = (embeddings - self._feature_mean) / self._feature_scale
        with torch.inference_mode(), one_thread():
            logits = self._head(torch.from_numpy(np.ascontiguousarray(z, np.float32)))
            return torch.softmax(logits, dim=1)[:, 1].numpy().astype(np.float64)

    # -- serialisation (used by model_folder) -----------------------------------------------

    def weights(self) -> dict[str, np.ndarray]:
        """All tensors of the model as named numpy arrays (what ``weights.npz`` holds).

        Fast: ``feature_mean``, ``feature_scale`` (1280,) and ``head.<name>``; full: ``net.<name>``
        for the whole state dict.
        """
        segment = {} if self.segment_head is None else self.segment_head.weights(SEGMENT_PREFIX)
        if self._net is not None:
            net = self._net.state_dict().items()
            return {f"net.{k}": v.detach().cpu().numpy() for k, v in net} | segment
        assert self._head is not None and self._feature_mean is not None
        assert self._feature_scale is not None
        out = {f"head.{k}": v.detach().cpu().numpy() for k, v in self._head.state_dict().items()}
        out["feature_mean"] = self._feature_mean
        out["feature_scale"] = self._feature_scale
        return out | segment

    @classmethod
    def from_weights(
        cls, info: dict[str, Any], weights: dict[str, np.ndarray]
    ) -> GuardrailClassifier:
        """Rebuild a classifier from its ``info`` and :meth:`weights`.

        Raises :class:`ModelFormatError` when the arrays do not fit the architecture ``info``
        describes, or ``info["params"]`` is invalid.
        """
        try:
            params = ClassifierParams.from_json(info["params"])
        except InvalidOptionError as exc:
            raise ModelFormatError(f"params: {exc}") from exc
        if params.mode != info["mode"] or params.input_size_px != info["input_size"]:
            raise ModelFormatError(
                f"params say mode {params.mode!r} and input_size_px {params.input_size_px}, the model "
                f"says mode {info['mode']!r} and input_size {info['input_size']}"
            )
        segment_weights = {k: v for k, v in weights.items() if k.startswith(SEGMENT_PREFIX)}
        weights = {k: v for k, v in weights.items() if not k.startswith(SEGMENT_PREFIX)}
        head_features = info.get("segment_head", {}).get("features")
        try:
            columns = None if head_features is None else feature_columns(head_features)
        except ValueError as exc:
            raise ModelFormatError(f"segment_head.features: {exc}") from exc
        segment_head = (
            SegmentHead.from_weights(segment_weights, SEGMENT_PREFIX, columns)
            if segment_weights
            else None
        )
        for name, array in weights.items():
            if array.dtype.kind not in "fiub":
                raise ModelFormatError(
                    f"weights: expected numeric arrays, got {name} of dtype {array.dtype}"
                )
            if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
                raise ModelFormatError(f"weights: expected finite values, {name} has NaN or inf")

        def load(module: nn.Module, prefix: str) -> None:
            state = {
                k[len(prefix) :]: torch.from_numpy(np.array(v))
                for k, v in weights.items()
                if k.startswith(prefix)
            }
            try:
                module.load_state_dict(state, strict=True)
            except RuntimeError as exc:
                first = str(exc).strip().splitlines()
                raise ModelFormatError(
                    f"weights do not fit {ARCHITECTURE} ({info['mode']} mode): "
                    + "; ".join(line.strip() for line in first[:4])
                ) from exc
            module.requires_grad_(False)

        if info["mode"] == "full":
            extra = [k for k in weights if not k.startswith("net.")]
            if extra:
                raise ModelFormatError(f"weights: unexpected arrays for a full model: {extra[:5]}")
            net = _new_full_network()
            load(net, "net.")
            return cls(info, net=net, segment_head=segment_head)

        extra = [
            k
            for k in weights
            if not k.startswith("head.") and k not in ("feature_mean", "feature_scale")
        ]
        if extra:
            raise ModelFormatError(f"weights: unexpected arrays for a fast model: {extra[:5]}")
        stats = []
        for name in ("feature_mean", "feature_scale"):
            if name not in weights:
                raise ModelFormatError(f"weights: a fast model needs {name}, it is missing")
            array = np.asarray(weights[name])
            if array.shape != (EMBEDDING_DIM,) or array.dtype.kind != "f":
                raise ModelFormatError(
                    f"weights: expected {name} of shape ({EMBEDDING_DIM},) float, "
                    f"got {array.shape} {array.dtype}"
                )
            stats.append(array.astype(np.float32))
        if not np.all(np.isfinite(stats[0])) or not np.all(stats[1] > 0):
            raise ModelFormatError(
                "weights: feature_mean must be finite and feature_scale positive"
            )
        head = make_head(params.fast_hidden_units, params.fast_dropout)
        load(head, "head.")
        return cls(
            info,
            head=head,
            feature_mean=stats[0],
            feature_scale=stats[1],
            segment_head=segment_head,
        )
