"""Classifying a window's segments (§3.3), asking the CNN only where the shape leaves it open.

With a segment head, a segment's label fuses its shape and neighbour features with its crop's
probability, and for most segments the shape alone already puts the label on one side of the
threshold whatever the crop says (:meth:`GuardrailClassifier.shape_decides`, exact). Those crops
are not run through the CNN: their ``crop_probability`` is NaN, their embedding row NaN ("not
asked"), their ``probability`` the head's answer for a crop probability of 0.5, their label the
one any crop would give, and their crops are not even cut. The head sees a crop's probability
clipped to [``crop_probability_clip``, 1 - ``crop_probability_clip``] (1 % by default): the CNN is
overconfident on streets it never saw, and a crop it is sure of beyond that does not overrule a
clear shape. On the simulated streets the shape then decides about 85 % of the crops (about
65 % without the clip), and the CNN was about half of processing. The review loop embeds the
crops not asked, cut from the drive's images, the first time it needs them
(:mod:`guardrail_core.review.run_crops`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from guardrail_core.extract.classify.crop_classifier_params import TRAINING_CLIP
from guardrail_core.params import StageParams, param

if TYPE_CHECKING:  # the classifier brings torch; the parameters must not
    from guardrail_core.extract.classify.crop_classifier import GuardrailClassifier


#: See ``ClassifyParams.crop_probability_clip``; runs written before it had the training clip.
CROP_CLIP_DEFAULT = 0.01


@dataclass(frozen=True)
class ClassifyParams(StageParams):
    """How the crops are put to the classifier."""

    shape_first: bool = param(
        True,
        doc="ask the CNN only for crops whose segment's shape leaves the label open (the labels "
        "are the same; about twice as fast); false asks it for every crop, so every crop has a "
        "probability and an embedding in the run",
    )
    crop_probability_clip: float = param(
        CROP_CLIP_DEFAULT,
        ge=TRAINING_CLIP,
        lt=0.5,
        doc="the segment head sees a crop's probability clipped to [this, 1 - this]: however "
        "sure the CNN is, its crop alone does not outvote a segment's shape (the CNN is most "
        "often wrong where it is surest against the shape: far-side slices of 30-40 px); "
        "larger: fewer crops asked; 1e-05 gives the head what it was trained on",
    )


@dataclass(frozen=True)
class SegmentScores:
    """What the classifier says of S segments.

    Attributes
    ----------
    crop_probability : (S,) float64, the CNN's P(guardrail) of the crop; NaN without a crop or
        where the CNN was not asked
    probability : (S,) float64, the segment head's P(guardrail) (crops not asked count as 0.5)
    raw_label : (S,) bool, ``probability >= threshold`` (NaN counting as other)
    asked : (S,) bool, the crops the CNN looked at
    embeddings : (S, 1280) float32 backbone embeddings for a fast model (zeros without a crop,
        NaN where the CNN was not asked), else None
    """

    crop_probability: np.ndarray
    probability: np.ndarray
    raw_label: np.ndarray
    asked: np.ndarray
    embeddings: np.ndarray | None


def score_segments(
    model: GuardrailClassifier,
    features: np.ndarray,
    has_crop: np.ndarray,
    crops: Callable[[np.ndarray], np.ndarray],
    params: ClassifyParams = ClassifyParams(),
    *,
    stored_embeddings: Callable[[np.ndarray], np.ndarray | None] | None = None,
    keep_embeddings: bool = True,
    progress: bool = False,
) -> SegmentScores:
    """Classify segments from their features and crops.

    Parameters
    ----------
    model : the classifier
    features : (S, F) float32 shape and neighbour features
    has_crop : (S,) bool, segments with a crop
    crops : ``crops(rows)``: the (K, C, C, 3) uint8 RGB crops of the segments ``rows`` (K,)
        int64, all with a crop, C = ``model.input_size`` px; called at most once, with the
        crops the CNN is asked about
    params : whether the shape is asked first
    stored_embeddings : fast models: ``stored_embeddings(rows)``, the (K, 1280) backbone
        embeddings of the same crops kept from before (a run's ``embeddings.npy``), or None
        where there are none; the crops are then neither cut nor embedded. None: always the crops
    keep_embeddings : False leaves :attr:`SegmentScores.embeddings` None (no (S, 1280) array is
        made for a caller that does not keep them)
    progress : a progress bar while the CNN runs
    """
    from guardrail_core.extract.classify.backbone import EMBEDDING_DIM

    has_crop = np.asarray(has_crop, bool)
    asked = crops_to_ask(model, features, has_crop, params)
    rows = np.flatnonzero(asked)
    crop_probability = np.full(len(features), np.nan, np.float64)
    fast = model.mode == "fast"
    embeddings = None
    if fast and keep_embeddings:  # kept for quick retraining
        embeddings = np.zeros((len(features), EMBEDDING_DIM), np.float32)
        embeddings[has_crop & ~asked] = np.nan
    if len(rows):
        asked_embeddings = None
        if fast and stored_embeddings is not None:
            stored = stored_embeddings(rows)
            asked_embeddings = None if stored is None else np.asarray(stored, np.float32)
        if fast and asked_embeddings is None:
            asked_embeddings = model.embed(crops(rows), progress=progress)
        if asked_embeddings is not None:
            crop_probability[rows] = model.predict_proba(embeddings=asked_embeddings)
            if embeddings is not None:
                embeddings[rows] = asked_embeddings
        else:  # a full model runs the whole network on the crops
            crop_probability[rows] = model.predict_proba(crops(rows), progress=progress)
    probability, raw_label = fuse_scores(
        model, features, has_crop, crop_probability, params.crop_probability_clip
    )
    return SegmentScores(crop_probability, probability, raw_label, asked, embeddings)


def crops_to_ask(
    model: GuardrailClassifier,
    features: np.ndarray,
    has_crop: np.ndarray,
    params: ClassifyParams = ClassifyParams(),
) -> np.ndarray:
    """(S,) bool: the crops the CNN must look at (all crops without ``shape_first``)."""
    asked = np.asarray(has_crop, bool).copy()
    if params.shape_first:
        asked &= ~model.shape_decides(features, params.crop_probability_clip)
    return asked


def weighed_crop_probability(
    model: GuardrailClassifier,
    features: np.ndarray,
    crop_probability: np.ndarray,
    crop_clip: float = TRAINING_CLIP,
) -> np.ndarray:
    """(S,) float64: the crops' P(guardrail) where the segment head weighed them, NaN where the
    shape decided alone (:meth:`GuardrailClassifier.shape_decides`) or there is none.

    What label correction's crop veto counts (``CorrectionParams.crop_veto_max_slices``,
    :mod:`~guardrail_core.extract.classify.label_correction_params`): the same crops whether
    the CNN was asked for every crop or only those (``shape_first``), so the labels are the same
    either way.
    """
    decided = model.shape_decides(features, crop_clip)
    return np.where(decided, np.nan, np.asarray(crop_probability, np.float64))


def fuse_scores(
    model: GuardrailClassifier,
    features: np.ndarray,
    has_crop: np.ndarray,
    crop_probability: np.ndarray,
    crop_clip: float = TRAINING_CLIP,
) -> tuple[np.ndarray, np.ndarray]:
    """The segment head's (S,) probability and raw label from the features and the crops'
    probabilities (NaN where a crop was not asked, or there is none), clipped to
    [``crop_clip``, 1 - ``crop_clip``] (``ClassifyParams.crop_probability_clip``)."""
    # A crop not asked is one whose probability does not matter: any value in [0, 1] puts the
    # segment on the same side of the threshold, so the head gets 0.5 (with has-crop set).
    not_asked = np.asarray(has_crop, bool) & ~np.isfinite(crop_probability)
    probability = model.segment_proba(
        features, np.where(not_asked, 0.5, crop_probability), crop_clip
    )
    raw_label = np.nan_to_num(probability, nan=0.0) >= model.threshold
    return probability, raw_label
