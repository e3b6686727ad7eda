"""The models an operator can activate: those fine-tuned in the app, and the one that made the run.

Each fine-tuned model is a model folder ``REVIEW_DIR/models/<version>/`` (see
:mod:`guardrail_core.extract.classify.model_folder`). The active model is the one whose
predictions the run folder holds (``run.json``'s ``model.version``): activating a model
re-predicts the run and writes its predictions into the run folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from guardrail_core.extract.classify.crop_classifier import GuardrailClassifier
from guardrail_core.extract.classify.model_folder import MODEL_FILE, load_model, save_model
from guardrail_core.formats.run_folder import Run
from guardrail_core.review.model_lineage import (
    fine_tuned_models,
    fine_tuning_start_folder,
    model_info,
)


class UnknownModelError(KeyError):
    """No model folder of that version is known to the app."""


class ModelRegistry:
    """Model folders by version.

    Parameters
    ----------
    folder : where fine-tuned models are saved
    run : the run under review (its ``run.json`` names the active model)
    run_model_dir : the folder of the model that made the run, when known
    """

    def __init__(self, folder: Path, run: Run, run_model_dir: str | Path | None = None) -> None:
        self.folder = Path(folder)
        self.run = run
        self.run_model_dir = Path(run_model_dir) if run_model_dir else None

    @property
    def active_version(self) -> str:
        return self.run.info.model.version

    def _folders(self) -> dict[str, Path]:
        folders: dict[str, Path] = {}
        if self.run_model_dir is not None and (self.run_model_dir / MODEL_FILE).is_file():
            folders[model_info(self.run_model_dir)["version"]] = self.run_model_dir
        folders.update(fine_tuned_models(self.folder))
        return folders

    def list(self) -> list[dict[str, Any]]:
        """Every known model, newest first, with its held-out figures."""
        rows = []
        folders = self._folders()
        for version, path in folders.items():
            info = model_info(path)
            rows.append(_row(info, active=version == self.active_version))
        if self.active_version not in folders:  # made the run, folder not given
            rows.append(
                {
                    "version": self.active_version,
                    "created": None,
                    "mode": self.run.info.model.mode,
                    "held_out": None,
                    "held_out_current": None,
                    "active": True,
                    "folder_known": False,
                }
            )
        return sorted(rows, key=lambda r: r["created"] or "", reverse=True)

    def info(self, version: str) -> dict[str, Any]:
        """The active (or given) model's row; metrics are None where its folder is not known."""
        for row in self.list():
            if row["version"] == version:
                return row
        raise UnknownModelError(version)

    def add(self, model: GuardrailClassifier) -> Path:
        """Save a fine-tuned model as ``folder/<version>``.

        A version names the second a model was made and a digest of its weights, so a folder
        of that version already there holds this very model: two fine-tunings on the same
        labels from the same start, within one second, make the same weights. It is kept, not
        written again."""
        folder = self.folder / model.version
        if (folder / MODEL_FILE).is_file():
            return folder
        return save_model(model, folder)

    def fine_tuning_start(self) -> GuardrailClassifier | None:
        """The model a fine-tuning starts from: the one the active model was itself fine-tuned
        from, else the active model, so that every fine-tuning starts from the model that made
        the run, with every label given so far (a chain of fine-tunings on a model's own
        labels drifts); None where its folder is not known. The shipped default model is known
        whether the run names its folder or not
        (:func:`guardrail_core.review.model_lineage.fine_tuning_start_folder`)."""
        folder = fine_tuning_start_folder(self.active_version, self._folders())
        return None if folder is None else load_model(folder)

    def load(self, version: str) -> GuardrailClassifier:
        """The model of that version.

        Raises
        ------
        UnknownModelError
            No folder of that version is known.
        """
        folders = self._folders()
        if version not in folders:
            raise UnknownModelError(version)
        return load_model(folders[version])


def _row(info: dict[str, Any], *, active: bool) -> dict[str, Any]:
    metrics = info.get("metrics", {})
    return {
        "version": info["version"],
        "created": info.get("created"),
        "mode": info.get("mode"),
        "held_out": metrics.get("held_out"),
        "held_out_current": metrics.get("held_out_current"),
        "trained_on": info.get("trained_on"),
        "active": active,
        "folder_known": True,
    }
