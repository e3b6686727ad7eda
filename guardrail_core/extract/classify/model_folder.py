"""Save and load a trained crop classifier (§3.3) as a model folder.

A model folder holds two files:

``model.json``
    ``format_version`` (:data:`MODEL_FORMAT_VERSION`) and the classifier's ``info``: architecture
    ("efficientnet-lite0"), mode ("fast" or "full"), input_size (px), classes, threshold, version
    (``<UTC time>-<8 hex of the weights' sha256>``), created (ISO 8601), backbone (weights package,
    version and sha256), trained_on (the caller's description of the data), metrics
    ``{"held_out": ...}``, training (counts, seconds) and params.
``weights.npz``
    Only numeric arrays: a fast model stores its feature standardisation and head, a full model the
    whole network's state dict.

Loading never unpickles: ``np.load(allow_pickle=False)`` and JSON. The weights' sha256 must match the
version, so a file swapped or damaged after saving is refused.
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from guardrail_core.errors import IncompatibleModelError, ModelFormatError
from guardrail_core.extract.classify.backbone import ARCHITECTURE, backbone_info
from guardrail_core.extract.classify.crop_classifier import (
    SEGMENT_PREFIX,
    GuardrailClassifier,
    weights_digest,
)
from guardrail_core.extract.classify.crop_classifier_params import CLASS_NAMES, MODES
from guardrail_core.extract.classify.shape_features import feature_columns
from guardrail_core.formats.atomic import staged_folder

__all__ = ["MODEL_FORMAT_VERSION", "MODEL_FILE", "WEIGHTS_FILE", "load_model", "save_model"]

MODEL_FORMAT_VERSION = (
    2  # 2: optional segment head (segment.* arrays, "segment_head" in model.json)
)
MODEL_FILE = "model.json"
WEIGHTS_FILE = "weights.npz"

#: Keys of model.json besides format_version, with the JSON types they must have.
_REQUIRED: dict[str, type | tuple[type, ...]] = {
    "architecture": str,
    "mode": str,
    "input_size": int,
    "classes": list,
    "threshold": (int, float),
    "version": str,
    "created": str,
    "backbone": dict,
    "trained_on": dict,
    "metrics": dict,
    "params": dict,
}


def save_model(
    clf: GuardrailClassifier,
    folder: Path,
    *,
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> Path:
    """Write ``clf`` as a model folder, atomically (a half-written folder never appears).

    Parameters
    ----------
    clf : GuardrailClassifier
    folder : Path, the model folder to create.
    overwrite : bool, replace an existing non-empty ``folder``.
    inputs : what the model was trained from (the drives' parts, the run's tables, the label
        store); ``folder`` must not be, hold, or replace any of them.

    Returns
    -------
    Path, the folder written.

    Raises
    ------
    OutputExistsError
        ``folder`` exists, is not empty and ``overwrite`` is False; the old folder is then left
        untouched.
    InputInsideOutputError
        Writing ``folder`` would delete an input (see
        :func:`guardrail_core.formats.atomic.check_output`).
    """
    folder = Path(folder)
    document = {"format_version": MODEL_FORMAT_VERSION, **clf.info}
    text = json.dumps(document, indent=2, allow_nan=False) + "\n"
    arrays: dict[str, Any] = clf.weights()  # only numeric arrays; savez must not pickle
    with staged_folder(folder, overwrite=overwrite, inputs=inputs) as staging:
        (staging / MODEL_FILE).write_text(text, encoding="utf-8")
        with open(staging / WEIGHTS_FILE, "wb") as f:
            np.savez(f, allow_pickle=False, **arrays)
    return folder


def _check_document(folder: Path, document: Any) -> dict[str, Any]:
    if not isinstance(document, dict):
        raise ModelFormatError(
            f"{folder / MODEL_FILE}: expected a JSON object, got {type(document).__name__}"
        )
    if "format_version" not in document:
        raise ModelFormatError(f"{folder / MODEL_FILE}: the key format_version is missing")
    version = document["format_version"]
    if version != MODEL_FORMAT_VERSION or isinstance(version, bool):
        raise IncompatibleModelError(
            f"{folder}: expected model format_version {MODEL_FORMAT_VERSION}, got {version!r} "
            "(written by another version of guardrail; retrain or use that version)"
        )
    missing = [key for key in _REQUIRED if key not in document]
    if missing:
        raise ModelFormatError(f"{folder / MODEL_FILE}: keys missing: {', '.join(missing)}")
    for key, kind in _REQUIRED.items():
        value = document[key]
        if not isinstance(value, kind) or isinstance(value, bool):
            expected = kind.__name__ if isinstance(kind, type) else "a number"
            raise ModelFormatError(
                f"{folder / MODEL_FILE}: expected {key} to be {expected}, "
                f"got {type(value).__name__} {value!r}"
            )
    if document["architecture"] != ARCHITECTURE:
        raise IncompatibleModelError(
            f"{folder}: expected architecture {ARCHITECTURE!r}, got {document['architecture']!r}"
        )
    if document["mode"] not in MODES:
        raise IncompatibleModelError(
            f"{folder}: expected mode one of {list(MODES)}, got {document['mode']!r}"
        )
    if document["classes"] != list(CLASS_NAMES):
        raise IncompatibleModelError(
            f"{folder}: expected classes {list(CLASS_NAMES)}, got {document['classes']!r}"
        )
    threshold = float(document["threshold"])
    if not (math.isfinite(threshold) and 0 <= threshold <= 1):
        raise ModelFormatError(
            f"{folder / MODEL_FILE}: expected threshold in [0, 1], got {threshold}"
        )
    if "held_out" not in document["metrics"]:
        raise ModelFormatError(f"{folder / MODEL_FILE}: metrics.held_out is missing")
    return document


def _read_weights(path: Path) -> dict[str, np.ndarray]:
    """Arrays of an .npz file, refusing pickled (object) arrays."""
    try:
        with np.load(path, allow_pickle=False) as npz:
            return {name: npz[name] for name in npz.files}
    except ValueError as exc:  # numpy refuses object arrays without allow_pickle
        raise ModelFormatError(
            f"{path}: expected only numeric arrays, got pickled object data (refused, not "
            f"loaded): {exc}"
        ) from exc
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise ModelFormatError(f"{path}: expected an .npz archive of arrays, got {exc}") from exc


#: The model shipped with the package: fast mode, trained on simulated drives of both scanners
#: (the profile scanner with cameras, the multi-beam scanner without); docs/default-model.md
#: says how to make it again.
DEFAULT_MODEL_DIR = Path(__file__).resolve().parents[2] / "models" / "default"


def load_model(folder: Path) -> GuardrailClassifier:
    """Read a model folder written by :func:`save_model`.

    Parameters
    ----------
    folder : Path

    Returns
    -------
    GuardrailClassifier, with ``info`` = ``model.json`` less ``format_version``.

    Raises
    ------
    ModelFormatError
        The folder or a file is missing, model.json is not valid JSON or lacks keys, weights.npz is
        not an archive of numeric arrays (pickled data is refused unread), the weights do not fit
        the architecture, or their sha256 does not match the version.
    IncompatibleModelError
        format_version other than :data:`MODEL_FORMAT_VERSION`, unknown architecture, mode or
        classes, or (fast models) embeddings from other pretrained weights than those installed.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ModelFormatError(f"{folder}: expected a model folder, got nothing there")
    model_path = folder / MODEL_FILE
    weights_path = folder / WEIGHTS_FILE
    for path in (model_path, weights_path):
        if not path.is_file():
            raise ModelFormatError(
                f"{folder}: expected {path.name} in the model folder, it is missing"
            )
    try:
        document = json.loads(model_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelFormatError(f"{model_path}: expected JSON, got {exc}") from exc
    document = _check_document(folder, document)
    weights = _read_weights(weights_path)

    digest = weights_digest(weights)[:8]
    if not document["version"].endswith(f"-{digest}"):
        raise ModelFormatError(
            f"{weights_path}: the weights' sha256 starts {digest}, the version "
            f"{document['version']!r} says otherwise (file replaced or damaged)"
        )
    if document["mode"] == "fast":
        saved = document["backbone"].get("weights_sha256")
        installed = backbone_info()["weights_sha256"]
        if saved != installed:
            raise IncompatibleModelError(
                f"{folder}: a fast model works on embeddings of the pretrained weights with sha256 "
                f"{saved}, the installed {ARCHITECTURE} weights have {installed}"
            )

    has_head = any(name.startswith(SEGMENT_PREFIX) for name in weights)
    if has_head != ("segment_head" in document):
        raise ModelFormatError(
            f"{folder}: model.json and weights.npz disagree on whether there is a segment head"
        )
    if has_head:
        names = document["segment_head"].get("features")
        try:
            feature_columns(names if isinstance(names, list) else [repr(names)])
        except ValueError as exc:
            raise IncompatibleModelError(
                f"{folder}: the segment head was trained on segment features this version "
                f"does not compute ({exc}); retrain the model"
            ) from exc

    info = {key: value for key, value in document.items() if key != "format_version"}
    try:
        return GuardrailClassifier.from_weights(info, weights)
    except ModelFormatError as exc:
        raise ModelFormatError(f"{folder}: {exc}") from exc
