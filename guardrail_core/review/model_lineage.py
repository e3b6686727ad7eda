"""Which model a fine-tuning on a run's labels starts from.

The review app's *Fine-tune from labels* and ``guardrail train --run`` both fine-tune the
segment head of the model that made the run (what its training drives taught stays where the
labels do not say otherwise), and every fine-tuning starts from that same model with every
label so far: a chain of fine-tunings, each on the one before, drifts. A model is found by its
version among the fine-tuned models the app saved (``REVIEW_DIR/models/<version>/``, model
folders as :mod:`guardrail_core.extract.classify.model_folder` writes them) and the shipped default
model.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR, MODEL_FILE

#: The folder, in a drive's review folder, where the app saves fine-tuned models.
FINE_TUNED_MODELS_DIR = "models"


def fine_tuned_models(folder: Path) -> dict[str, Path]:
    """The model folders saved under ``folder`` (``REVIEW_DIR/models``), by version (their
    names); empty where there is no such folder."""
    folder = Path(folder)
    if not folder.is_dir():
        return {}
    return {path.name: path for path in sorted(folder.iterdir()) if (path / MODEL_FILE).is_file()}


def model_folder_of(version: str, folders: Mapping[str, Path]) -> Path | None:
    """The folder of the model ``version``: ``folders[version]``, else the shipped default
    model's when it is that version; None where neither is."""
    if version in folders:
        return folders[version]
    shipped = DEFAULT_MODEL_DIR / MODEL_FILE
    if shipped.is_file() and model_info(DEFAULT_MODEL_DIR)["version"] == version:
        return DEFAULT_MODEL_DIR
    return None


def fine_tuning_start_folder(version: str, folders: Mapping[str, Path]) -> Path | None:
    """The folder of the model that a fine-tuning of a run predicted by model ``version``
    starts from: the model ``version`` was itself fine-tuned from (its
    ``trained_on.segment_head_from``), else ``version`` itself (a model trained from drives);
    None where that folder is not known (see :func:`model_folder_of`)."""
    folder = model_folder_of(version, folders)
    if folder is not None:
        origin = model_info(folder).get("trained_on", {}).get("segment_head_from")
        if origin:
            folder = model_folder_of(origin, folders)
    return folder


def model_info(folder: Path) -> dict[str, Any]:
    """The ``model.json`` of a model folder."""
    info: dict[str, Any] = json.loads((Path(folder) / MODEL_FILE).read_text(encoding="utf-8"))
    return info
