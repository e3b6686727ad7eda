"""What the crop classifier (§3.3) is and how it is trained: its classes, modes and parameters."""

from __future__ import annotations

from dataclasses import dataclass

from guardrail_core.params import StageParams, param

#: Class index -> name; index 1 is the positive class.
CLASS_NAMES = ("other", "guardrail")
#: ``"fast"``: a head on frozen embeddings; ``"full"``: the whole network fine-tuned.
MODES = ("fast", "full")
#: The network halves its resolution five times: input sizes must be multiples of this.
SIZE_STEP = 32
#: The segment head is trained on crop probabilities clipped to [this, 1 - this]; classifying
#: clips at least as much (``ClassifyParams.crop_probability_clip``).
TRAINING_CLIP = 1e-5


@dataclass(frozen=True)
class ClassifierParams(StageParams):
    """Parameters of the crop classifier (§3.3).

    ``mode`` ``"fast"`` trains a small head on the frozen pretrained backbone's cached embeddings
    in seconds; ``"full"`` fine-tunes the whole network (the paper's fine tuning), minutes on a
    CPU. ``fast_*`` fields apply to the first, ``full_*`` fields to the second.
    """

    input_size_px: int = param(
        128,
        unit="px",
        ge=SIZE_STEP,
        le=1024,
        doc="crops are input_size_px x input_size_px RGB uint8; a multiple of 32 (the net's "
        "total stride)",
    )
    mode: str = param("fast", choices=MODES, doc="'fast' (frozen backbone) or 'full' (fine-tune)")
    fast_epochs: int = param(
        300, ge=1, le=100_000, doc="full-batch optimisation steps of the fast head"
    )
    fast_lr: float = param(1e-2, gt=0, le=1, doc="learning rate of the fast head (AdamW)")
    fast_l2: float = param(
        1e-3, ge=0, le=10, doc="L2 penalty on the head's weights, added to the mean cross-entropy"
    )
    fast_hidden_units: int = param(
        0,
        ge=0,
        le=4096,
        doc="0: the head is one linear layer on the standardised embedding (a linear probe); "
        "else the width of one hidden ReLU layer",
    )
    fast_dropout: float = param(
        0.2, ge=0, lt=1, doc="dropout before the output layer (only with hidden units)"
    )
    fast_refit_on_all: bool = param(
        True,
        doc="after measuring on the held-out groups, train the final fast head on all crops "
        "(seconds); a full model is always the one measured (refitting would double the minutes "
        "of fine-tuning)",
    )
    full_epochs: int = param(
        5, ge=1, le=1000, doc="passes over the training crops when fine-tuning"
    )
    full_lr: float = param(
        2e-4, gt=0, le=1, doc="learning rate of the pretrained layers (AdamW, cosine decay to 0)"
    )
    full_head_lr: float = param(
        2e-3, gt=0, le=1, doc="learning rate of the new 2-class final layer"
    )
    full_weight_decay: float = param(1e-2, ge=0, le=1, doc="AdamW decoupled weight decay")
    full_flip_probability: float = param(
        0.5, ge=0, le=1, doc="fine-tuning: share of training crops flipped left to right"
    )
    batch_size: int = param(
        32, ge=2, le=4096, doc="crops per optimisation step (full mode) and per inference batch"
    )
    held_out_fraction: float = param(
        0.2,
        ge=0,
        le=0.9,
        doc="share of groups (spatial blocks) held out to measure the model; 0 measures nothing",
    )
    held_out_draws: int = param(
        200,
        ge=1,
        le=100_000,
        doc="random splits tried to find one with both classes on both sides of the split",
    )
    threshold: float = param(
        0.5, ge=0, le=1, doc="probability of 'guardrail' above which a crop is called guardrail"
    )
    min_crops: int = param(
        10, ge=1, le=1_000_000, doc="fewer labelled crops than this raise TrainingDataError"
    )
    seed: int = param(
        0,
        ge=0,
        doc="seeds the split, the weight initialisation, shuffling, dropout and augmentation",
    )

    def check_relations(self) -> None:
        if self.input_size_px % SIZE_STEP:
            self.fail(
                f"input_size_px must be a whole multiple of {SIZE_STEP} px (e.g. 64, 128, 224), "
                f"got {self.input_size_px}"
            )
