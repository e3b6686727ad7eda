"""Non-vertical pipes from chains of slice centres (§4.3, Fig. 16).

The points left once the vertical and straight pipes' are removed are cut into slices along x;
the centres of each slice's connected components are joined into polylines across the slices,
the polylines repaired where they broke or bounced off a crossing pipe, shaped (smoothed,
straight or curved) and merged where two pieces are one pipe.
"""

from __future__ import annotations

import numpy as np

from guardrail_core.reconstruct.pipes.crossings import uncross
from guardrail_core.reconstruct.pipes.merging import merge_duplicates, merge_fragments
from guardrail_core.reconstruct.pipes.params import PipeParams
from guardrail_core.reconstruct.pipes.polylines import polyline_length
from guardrail_core.reconstruct.pipes.shaping import shape_chain
from guardrail_core.reconstruct.pipes.skeleton import Chain, Skeleton
from guardrail_core.reconstruct.pipes.slices import slice_components
from guardrail_core.reconstruct.pipes.tracking import join_broken_tracks, link_centres


def chained_pipes(
    pts: np.ndarray, rest_idx: np.ndarray, x0: float, p: PipeParams
) -> tuple[list[Skeleton], int]:
    """The pipes chained from the slices of the points ``rest_idx``.

    Parameters
    ----------
    pts : (N, 3) float64, unit coordinates, metres: the points between the poles
    rest_idx : (M,) int64, indices into ``pts`` of the points left to chain
    x0 : float, metres: where the first slice starts

    Returns
    -------
    The skeletons (``idx`` into ``pts``), and how many chains were too short (under
    ``min_length_m`` or two centres) or too sparse (under ``min_points``) to be pipes.
    """
    if len(rest_idx) == 0:
        return [], 0
    # §4.3, Fig. 16(b, c): 30 mm slices along x, Delaunay wireframes, connected components.
    components = slice_components(pts[rest_idx, :2], x0, p)
    # §4.3, Fig. 16(d): neighbouring centres joined into polylines.
    tracks = uncross(join_broken_tracks(link_centres(components, p), p), p)
    skels: list[Skeleton] = []
    n_short = 0
    for t in tracks:
        comps = [c.component for c in t.centres]
        n_pts = int(components.weights[comps].sum())
        centres = t.xy()
        if len(centres) < 2 or n_pts < p.min_points or polyline_length(centres) < p.min_length_m:
            n_short += 1
            continue
        idx = rest_idx[components.members(comps)]
        own = rest_idx[components.members([c.component for c in t.centres if not c.shared])]
        shared = np.array([c.shared for c in t.centres])
        skels.append(shape_chain(Chain(centres=centres, shared=shared, own=own), idx, pts, p))
    return merge_fragments(merge_duplicates(skels, pts, p), pts, p), n_short
