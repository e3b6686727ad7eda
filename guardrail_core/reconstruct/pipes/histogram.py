"""The x histogram of vertical-pipe detection (Matsumoto et al. 2019, §4.3, Fig. 14)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from guardrail_core.reconstruct.pipes.params import PipeParams


@dataclass(frozen=True)
class PipeHistogram:
    """The x histogram of vertical-pipe detection (§4.3, Fig. 14).

    Attributes
    ----------
    edges : (B + 1,) float64, metres, unit x
    counts : (B,) int64, points per bin (pole points excluded)
    threshold : float, points per bin: regions above it are vertical-pipe candidates
    """

    edges: np.ndarray
    counts: np.ndarray
    threshold: float


def x_histogram(x: np.ndarray, x0: float, x1: float, p: PipeParams) -> PipeHistogram:
    """Histogram of ``x`` (N,) metres, all within [x0, x1), in ``histogram_bin_m`` bins from
    ``x0``; its threshold is ``histogram_factor`` times the median count, at least
    ``histogram_min_count``."""
    n_bins = max(1, int(math.ceil((x1 - x0) / p.histogram_bin_m)))
    edges = x0 + p.histogram_bin_m * np.arange(n_bins + 1)
    counts = np.bincount(bin_of(x, edges, p), minlength=n_bins).astype(np.int64)
    threshold = max(p.histogram_factor * float(np.median(counts)), p.histogram_min_count)
    return PipeHistogram(edges, counts, float(threshold))


def bin_of(x: np.ndarray, edges: np.ndarray, p: PipeParams) -> np.ndarray:
    """The bin (N,) int64 of each ``x`` (N,) metres (the last bin takes the right edge)."""
    n_bins = len(edges) - 1
    return np.minimum(((x - edges[0]) / p.histogram_bin_m).astype(np.int64), n_bins - 1)


def regions_above(counts: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """First bins (starts) and bins one past the last (stops) of the runs above ``threshold``."""
    above = np.concatenate([[False], counts > threshold, [False]])
    return np.flatnonzero(~above[:-1] & above[1:]), np.flatnonzero(above[:-1] & ~above[1:])
