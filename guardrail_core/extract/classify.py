"""Classify cropped images of sliced segments as "guardrail" or "other" (Matsumoto et al. 2019, §3.3).

The crop classifier in one import; each part lives in its own module:

- :mod:`~guardrail_core.extract.classifier_params`: the classes, the two modes and
  :class:`ClassifierParams`;
- :mod:`~guardrail_core.extract.backbone`: the ImageNet-pretrained EfficientNet-Lite0 and crop
  embeddings (:func:`embed_crops`);
- :mod:`~guardrail_core.extract.crop_classifier`: the trained model, :class:`GuardrailClassifier`;
- :mod:`~guardrail_core.extract.classifier_training`: :func:`train_classifier`, the held-out
  split and :func:`classification_metrics`;
- :mod:`~guardrail_core.extract.model_folder`: saving and loading a model folder.
"""

from guardrail_core.extract.backbone import (
    ARCHITECTURE,
    EMBEDDING_DIM,
    backbone_info,
    embed_crops,
    load_backbone,
)
from guardrail_core.extract.classifier_params import CLASS_NAMES, MODES, ClassifierParams
from guardrail_core.extract.classifier_training import (
    classification_metrics,
    held_out_mask,
    train_classifier,
)
from guardrail_core.extract.crop_classifier import (
    SEGMENT_PREFIX,
    GuardrailClassifier,
    model_version,
    weights_digest,
)

__all__ = [
    "ARCHITECTURE",
    "CLASS_NAMES",
    "EMBEDDING_DIM",
    "MODES",
    "SEGMENT_PREFIX",
    "ClassifierParams",
    "GuardrailClassifier",
    "backbone_info",
    "classification_metrics",
    "embed_crops",
    "held_out_mask",
    "load_backbone",
    "model_version",
    "train_classifier",
    "weights_digest",
]
