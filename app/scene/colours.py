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

    The selection is not coloured here: the scene draws it over the points.
    """
    # Each point gets a code into a small palette, and the palette is indexed once: 400,000
    # points take a few milliseconds, not the 26 ms of assigning RGB rows mask by mask.
    point_segment = np.asarray(point_segment)
    inside = point_segment >= 0
    s = np.maximum(point_segment, 0)
    base = np.where(point_segment == -1, 1, 0)  # road, else off the road
    if mode == "probability":  # one colour per segment, then per point
        palette = np.concatenate([[OFF_ROAD, ROAD], probability_colours(probability)])
        code = np.where(inside, 2 + s, base)
    else:
        palette = np.stack([OFF_ROAD, ROAD, GUARDRAIL, OTHER, NO_VALUE])
        if mode == "label":
            own = np.asarray(point_labels)
            flag = np.where(own >= 0, own == 1, segment_label[s])  # a point's own label wins
            code = np.where(inside, np.where(flag, 2, 3), base)
        elif mode == "prediction":
            code = np.where(inside, np.where(raw_label[s], 2, 3), base)
        elif mode == "truth":
            if point_class is None:
                code = np.where(inside, 4, base)
            else:  # every point of a guardrail, in a segment or not
                truth = np.isin(point_class, list(GUARDRAIL_CLASSES))
                code = np.where(truth, 2, np.where(inside, 3, base))
        else:
            raise ValueError(f"colour mode: expected one of {COLOUR_MODES}, got {mode!r}")
    return palette[code]


def _css(colour: np.ndarray) -> str:
    return "rgb({}, {}, {})".format(*(int(c) for c in colour))


def _swatch(colour: np.ndarray, text: str) -> str:
    return (
        f'<span style="display:inline-block;width:10px;height:10px;border-radius:2px;'
        f'background:{_css(colour)};margin:0 4px 0 8px"></span>{text}'
    )


def colour_legend(mode: str) -> str:
    """HTML: what the colours of ``mode`` (one of :data:`COLOUR_MODES`) mean."""
    common = [_swatch(ROAD, "road"), _swatch(OFF_ROAD, "no segment"), _swatch(SELECTED, "selected")]
    if mode == "probability":
        stops = ", ".join(_css(c) for c in _RAMP)
        scale = (
            '<div style="height:10px;border-radius:3px;margin:2px 8px;'
            f'background:linear-gradient(to right, {stops})"></div>'
            '<div style="display:flex;justify-content:space-between;margin:0 8px">'
            "<span>0 %</span><span>P(guardrail)</span><span>100 %</span></div>"
        )
        items = [_swatch(NO_VALUE, "no probability"), *common]
        return f'<div style="font-size:12px">{scale}{"".join(items)}</div>'
    if mode not in COLOUR_MODES:
        raise ValueError(f"colour mode: expected one of {COLOUR_MODES}, got {mode!r}")
    meaning = {"label": "label", "prediction": "raw prediction", "truth": "truth"}[mode]
    items = [
        _swatch(GUARDRAIL, f"guardrail ({meaning})"),
        _swatch(OTHER, "other"),
        *common,
    ]
    return f'<div style="font-size:12px;line-height:1.8">{"".join(items)}</div>'
