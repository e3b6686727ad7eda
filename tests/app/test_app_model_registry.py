"""Which model the review app's fine-tuning starts from."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from app.model_registry import ModelRegistry
from guardrail_core.extract.classify.model_folder import DEFAULT_MODEL_DIR, load_model, save_model


def _registry(folder: Path, version: str, run_model_dir: Path | None = None) -> ModelRegistry:
    """A registry whose run holds the predictions of the model ``version``."""
    run = SimpleNamespace(info=SimpleNamespace(model=SimpleNamespace(version=version)))
    return ModelRegistry(folder, run, run_model_dir)  # type: ignore[arg-type]


def test_the_shipped_model_that_made_the_run_is_the_start_without_its_folder(
    tmp_path: Path,
) -> None:
    shipped = load_model(DEFAULT_MODEL_DIR)
    start = _registry(tmp_path / "models", shipped.version).fine_tuning_start()
    assert start is not None and start.version == shipped.version
    assert _registry(tmp_path / "models", "20260101T000000-00000000").fine_tuning_start() is None


def test_a_fine_tuned_model_active_leads_back_to_its_start(tmp_path: Path) -> None:
    shipped = load_model(DEFAULT_MODEL_DIR)
    tuned = load_model(DEFAULT_MODEL_DIR)
    tuned.info["version"] = "20260102T000000-11111111"
    tuned.info["trained_on"] = {"labels": "operator labels", "segment_head_from": shipped.version}
    save_model(tuned, tmp_path / "models" / tuned.version)
    start = _registry(tmp_path / "models", tuned.version).fine_tuning_start()
    assert start is not None and start.version == shipped.version
    # A model trained from drives has no start of its own: it is the start.
    own = _registry(tmp_path / "models", shipped.version, DEFAULT_MODEL_DIR).fine_tuning_start()
    assert own is not None and own.version == shipped.version


def test_the_same_model_added_twice_is_one_folder(tmp_path: Path) -> None:
    # Two fine-tunings on the same labels from the same start within one second make the same
    # weights, so the same version: the second one is that model, not a clash.
    tuned = load_model(DEFAULT_MODEL_DIR)
    registry = _registry(tmp_path / "models", tuned.version)
    first = registry.add(tuned)
    assert registry.add(tuned) == first
    assert load_model(first).version == tuned.version
    assert sorted(p.name for p in (tmp_path / "models").iterdir()) == [tuned.version]
