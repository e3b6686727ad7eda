"""Re-predicting a run with another model, and writing the predictions into the run folder.

The classification and label correction of §3.3 run again on the segments the run holds
(:func:`~guardrail_core.extract.classify.score_and_correct.score_and_correct`, as ``guardrail
process`` ran them); the review app does it when an operator activates or fine-tunes a model.
"""

from __future__ import annotations

import dataclasses
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from guardrail_core.errors import InvalidOptionError
from guardrail_core.extract.classify.crop_classifier import GuardrailClassifier
from guardrail_core.extract.classify.crop_classifier_params import TRAINING_CLIP
from guardrail_core.extract.classify.label_correction_params import CorrectionParams
from guardrail_core.extract.classify.score_and_correct import score_and_correct
from guardrail_core.extract.classify.segment_extents import SegmentExtents
from guardrail_core.extract.classify.segment_scores import ClassifyParams
from guardrail_core.extract.crops import CROP_OK
from guardrail_core.formats.run_folder import SEGMENT_FIELDS, Run, load_run, replace_run_tables
from guardrail_core.formats.run_info import ModelRef, Predicted
from guardrail_core.review.run_crops import complete_embeddings, read_crops

__all__ = ["PREDICTION_FIELDS", "predict_run", "write_predictions"]

#: Fields of segments.npz that :func:`predict_run` computes and :func:`write_predictions` replaces.
PREDICTION_FIELDS = ("crop_probability", "probability", "raw_label", "label")


def predict_run(
    run: Run,
    model: GuardrailClassifier,
    *,
    correction: CorrectionParams | None = None,
    drive_root: str | Path | None = None,
) -> dict[str, np.ndarray]:
    """Re-predict every segment of a run with ``model`` (the classify and correction stages).

    A fast model classifies the run's stored ``embeddings.npy`` (float16, so with the run's own
    model the crop probabilities agree with the pipeline's to about 2e-5, the segment
    probabilities to about 5e-6 on the demo run); a full model, or a run without embeddings, runs
    the network on the crops, cut from the drive's images as the pipeline cut them.

    Parameters
    ----------
    run : the run folder
    model : the classifier (with its segment head, if any)
    correction : label correction rules; None takes the run's own (``params.correction``)
    drive_root : the drive folder the crops are cut from; None: ``run.json``'s drive path

    Returns
    -------
    dict
        ``crop_probability`` (S,) float32 (NaN without a crop or not asked), ``probability`` (S,) float32,
        ``raw_label`` (S,) bool (``probability >= threshold``, NaN counting as other),
        ``label`` (S,) bool (corrected).

    Raises
    ------
    MissingDriveFileError
        An image a crop is cut from is missing or unreadable.
    IncompatibleModelError
        The run's segment features were laid out by another version of guardrail.
    """
    segments = run.segments

    def stored_embeddings(rows: np.ndarray) -> np.ndarray | None:
        stored = complete_embeddings(run, model.input_size, rows=rows, drive_root=drive_root)
        return None if stored is None else stored[rows]

    extents = SegmentExtents(
        segments["slice_index"],
        segments["lateral"],
        segments["height"],
        segments["component"],
        segments["n_points"],
    )
    scores = score_and_correct(
        model,
        segments["features"],
        segments["crop_status"] == CROP_OK,
        extents,
        lambda rows: read_crops(run, rows, model.input_size, drive_root=drive_root),
        _run_classify(run),
        _run_correction(run) if correction is None else correction,
        stored_embeddings=stored_embeddings,
        keep_embeddings=False,
    )
    return {
        name: getattr(scores, name).astype(SEGMENT_FIELDS[name][0]) for name in PREDICTION_FIELDS
    }


def write_predictions(
    run_root: Path, predictions: dict[str, np.ndarray], model: GuardrailClassifier
) -> None:
    """Replace a run's predictions by those of another model, in place.

    segments.npz's four fields (:data:`PREDICTION_FIELDS`), segments.csv and run.json's
    ``model`` and counts (``guardrail_segments_raw``, ``guardrail_segments``,
    ``guardrail_points``) are rewritten, each file atomically
    (:func:`~guardrail_core.formats.run_folder.replace_run_tables`, run.json last). run.json keeps the
    previous model under ``predicted.previous_model``; an existing reconstruction (made from the
    old labels) is marked ``reconstruction.outdated`` until ``guardrail reconstruct`` runs again.

    Parameters
    ----------
    run_root : the run folder
    predictions : :func:`predict_run` of the run
    model : the model that made them

    Raises
    ------
    RunFolderError
        Not a run folder.
    InvalidOptionError
        A prediction missing or of the wrong length; the run is left as it was.
    """
    run = load_run(run_root)
    n = len(run)
    for name in PREDICTION_FIELDS:
        if name not in predictions or np.shape(predictions[name]) != (n,):
            got = np.shape(predictions[name]) if name in predictions else "nothing"
            raise InvalidOptionError(
                f"predictions[{name!r}]: expected shape ({n},) for the run's segments, got {got}"
            )
    segments = dict(run.segments)
    for name in PREDICTION_FIELDS:
        segments[name] = np.asarray(predictions[name], SEGMENT_FIELDS[name][0])
    previous = run.info.model
    label = segments["label"]
    counts = dataclasses.replace(
        run.info.counts,
        guardrail_segments_raw=int(segments["raw_label"].sum()),
        guardrail_segments=int(label.sum()),
        guardrail_points=int(segments["n_points"][label].sum()),
    )
    reconstruction = run.info.reconstruction
    if reconstruction is not None:
        reconstruction = dataclasses.replace(
            reconstruction,
            outdated=f"made from the labels of model {previous.version}; "
            "run `guardrail reconstruct` again",
        )
    info = dataclasses.replace(
        run.info,
        model=ModelRef(version=model.version, mode=model.mode, threshold=model.threshold),
        predicted=Predicted(
            at=datetime.now(UTC).replace(microsecond=0).isoformat(), previous_model=previous
        ),
        counts=counts,
        reconstruction=reconstruction,
    )
    replace_run_tables(run.root, segments=segments, info=info.to_json())


def _run_classify(run: Run) -> ClassifyParams:
    """The run's own classify parameters; a run from before shape-first asked every crop, and
    one from before the crop probability clip gave the head the crops' probabilities as they
    came."""
    stored = run.info.params.get("classify")
    if stored is None:
        return ClassifyParams(shape_first=False, crop_probability_clip=TRAINING_CLIP)
    return ClassifyParams.from_json({"crop_probability_clip": TRAINING_CLIP, **stored})


def _run_correction(run: Run) -> CorrectionParams:
    """The run's own correction rules; a run from before the fill floor filled by position
    alone, one from before the rule of what stands behind a rail kept it, one from before
    wide segments touching a rail's back kept them, one from before the crop veto kept
    short components whatever their crops said, one from before the rules of long objects
    kept their pieces called guardrail, one from before posts' stubs left them other, one
    from before the rule of a hedge grown into a rail's back kept it, and one from before the
    infill of a railing left the short pieces inside its slices as the classifier called them."""
    before = {
        "fill_min_probability": 0.0,
        "behind_gap_m": float("inf"),
        "behind_wide_m": float("inf"),
        "crop_veto_max_slices": 0,
        "object_window_slices": 0,
        "inside_max_slices": 0,
        "post_stub_gap_m": 0.0,
        "behind_own_wide_m": float("inf"),
        "infill_max_slices": 0,
    }
    stored = {**before, **(run.info.params.get("correction") or {})}
    known = CorrectionParams.__dataclass_fields__
    return CorrectionParams(**{k: v for k, v in stored.items() if k in known})
