"""§3.3 from segments to their labels: the classifier's scores, then label correction.

What ``guardrail process`` does on each tile
(:func:`guardrail_core.process.tile_task.process_window`) and what re-predicting a run with
another model does (:func:`guardrail_core.review.predictions.predict_run`), written once so that
both give a segment the same label.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from guardrail_core.extract.classify.label_correction import correct_labels
from guardrail_core.extract.classify.label_correction_params import CorrectionParams
from guardrail_core.extract.classify.segment_extents import SegmentExtents
from guardrail_core.extract.classify.segment_scores import (
    ClassifyParams,
    SegmentScores,
    score_segments,
    weighed_crop_probability,
)
from guardrail_core.timing import StageTimer

if TYPE_CHECKING:  # the classifier brings torch
    from guardrail_core.extract.classify.crop_classifier import GuardrailClassifier


@dataclass(frozen=True)
class CorrectedScores(SegmentScores):
    """What the classifier says of S segments (:class:`SegmentScores`: ``crop_probability``,
    ``probability``, ``raw_label``, ``asked``, ``embeddings``), and their corrected labels.

    Attributes
    ----------
    label : (S,) bool, ``raw_label`` corrected by the segments' neighbours (True: guardrail)
    """

    label: np.ndarray


def score_and_correct(
    model: GuardrailClassifier,
    features: np.ndarray,
    has_crop: np.ndarray,
    extents: SegmentExtents,
    crops: Callable[[np.ndarray], np.ndarray],
    classify: ClassifyParams = ClassifyParams(),
    correction: CorrectionParams = CorrectionParams(),
    *,
    stored_embeddings: Callable[[np.ndarray], np.ndarray | None] | None = None,
    keep_embeddings: bool = True,
    timer: StageTimer | None = None,
    progress: bool = False,
) -> CorrectedScores:
    """Classify S segments (:func:`~.segment_scores.score_segments`) and correct their raw
    labels by their neighbours (:func:`~.label_correction.correct_labels`), §3.3.

    Parameters
    ----------
    model : the classifier (the crop classifier, and the segment head if it has one)
    features : (S, F) float32 shape and neighbour features
        (:func:`~.shape_features.segment_features`)
    has_crop : (S,) bool, segments with a crop
    extents : where the S segments lie: slice, lateral and height extents (metres),
        wireframe component, points
    crops : ``crops(rows)``: the (K, C, C, 3) uint8 RGB crops of the segments ``rows`` (K,)
        int64, C = ``model.input_size`` px; called at most once, with the crops the CNN is
        asked about
    classify : whether the shape is asked first, and the crop probabilities' clip
    correction : the rules of label correction
    stored_embeddings : fast models: ``stored_embeddings(rows)``, the (K, 1280) float
        embeddings of those crops kept from before, or None (then the crops are cut and
        embedded); None: always the crops
    keep_embeddings : False: no (S, 1280) array of embeddings is made (``embeddings`` None)
    timer : records the stages ``"classify"`` and ``"correction"`` (seconds, S segments each)
    progress : a progress bar while the CNN runs

    Returns
    -------
    CorrectedScores
        ``crop_probability`` (S,) float64 (NaN without a crop or where the CNN was not asked),
        ``probability`` (S,) float64, ``raw_label`` (S,) bool, ``asked`` (S,) bool,
        ``embeddings`` (S, 1280) float32 or None, ``label`` (S,) bool.
    """
    stage = timer.stage if timer is not None else _untimed
    with stage("classify", points=len(features)):
        scores = score_segments(
            model,
            features,
            has_crop,
            crops,
            classify,
            stored_embeddings=stored_embeddings,
            keep_embeddings=keep_embeddings,
            progress=progress,
        )
    with stage("correction", points=len(features)):
        # The crop veto counts the crops the segment head weighed, whichever the CNN was asked.
        weighed = weighed_crop_probability(
            model, features, scores.crop_probability, classify.crop_probability_clip
        )
        label = correct_labels(scores.raw_label, extents, correction, scores.probability, weighed)
    kept = {field.name: getattr(scores, field.name) for field in dataclasses.fields(scores)}
    return CorrectedScores(**kept, label=label)


@contextlib.contextmanager
def _untimed(name: str, *, points: int | None = None) -> Iterator[None]:
    """What :meth:`StageTimer.stage` is without a timer: nothing."""
    yield
