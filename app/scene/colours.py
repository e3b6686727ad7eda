"""Point colours of the 3D scene: by label, raw prediction, probability or truth."""

from __future__ import annotations

import numpy as np

from guardrail_core.classes import GUARDRAIL_CLASSES

COLOUR_MODES = ("label", "prediction", "probability", "truth")

GUARDRAIL = np.array([242, 142, 43], np.uint8)  # orange
OTHER = np.array([110, 150, 200], np.uint8)  # steel blue
ROAD = np.array([72, 72, 76], np.uint8)
OFF_ROAD = np.array([110, 110, 110], np.uint8)
SELECTED = np.array([255, 40, 200], np.uint8)  # magenta: never a label colour
NO_VALUE = np.array([190, 190, 190], np.uint8)

# A perceptual ramp (viridis stops) for probabilities 0 -> 1.
_RAMP = np.array(
    [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], np.float64
)


def probability_colours(p: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 viridis colours of probabilities; grey where NaN."""
    p = np.asarray(p, np.float64)
    t = np.clip(np.nan_to_num(p, nan=0.0), 0, 1) * (len(_RAMP) - 1)
    stops = np.arange(len(_RAMP))
    out = np.stack([np.interp(t, stops, _RAMP[:, c]) for c in range(3)], axis=1)
    out[np.isnan(p)] = NO_VALUE
    return out.round().astype(np.uint8)


def point_colours(
    mode: str,
    point_segment: np.ndarray,
    *,
    segment_label: np.ndarray,
    raw_label: np.ndarray,
    probability: np.ndarray,
    point_labels: np.ndarray,
    point_class: np.ndarray | None,
    selected: np.ndarray,
) -> np.ndarray:
    """(K,) points' colours, (K, 3) uint8.

    Parameters
    ----------
    mode : one of :data:`COLOUR_MODES`
    point_segment : (K,) segment of each point (negative: road -1, off-road -2)
    segment_label : (S,) bool, effective label of each segment (operator's, else the model's)
    raw_label, probability : (S,) the model's raw prediction and probability
    point_labels : (K,) int8, the operator's label of each point, -1 where none
    point_class : (K,) truth class of each point, or None when the drive has no truth
    selected : (S,) bool, selected segments (drawn magenta in every mode)
    """
    colours = np.empty((len(point_segment), 3), np.uint8)
    colours[:] = OFF_ROAD
    colours[point_segment == -1] = ROAD
    inside = point_segment >= 0
    s = point_segment[inside]
    if mode == "label":
        flag = segment_label[s]
        own = point_labels[inside]
        flag = np.where(own >= 0, own == 1, flag)  # a point's own operator label wins
        colours[inside] = np.where(flag[:, None], GUARDRAIL, OTHER)
    elif mode == "prediction":
        colours[inside] = np.where(raw_label[s][:, None], GUARDRAIL, OTHER)
    elif mode == "probability":
        colours[inside] = probability_colours(probability[s])
    elif mode == "truth":
        if point_class is None:
            colours[inside] = NO_VALUE
        else:
            truth = np.isin(point_class, list(GUARDRAIL_CLASSES))
            colours[truth] = GUARDRAIL
            colours[inside & ~truth] = OTHER
    else:
        raise ValueError(f"colour mode: expected one of {COLOUR_MODES}, got {mode!r}")
    colours[inside & selected[np.maximum(point_segment, 0)]] = SELECTED
    return colours
