"""Sections and stacks (§4.1, Fig. 11): a run cut by horizontal planes, its section clusters
stacked into candidate poles.

Each horizontal section of a run holds clusters: long ones where it cuts a rail or a beam,
compact ones where it cuts a pole (or a baluster, a stay, a fragment of a sparse rail). Compact
clusters that stand above each other in enough nearly consecutive sections support each other
and are grouped into a stack, one per candidate pole.

References
----------
Matsumoto, Mori, Masuda (2019), ISPRS Archives, §4.1, Fig. 11.
Fukano, Masuda (2015), "Detection and classification of pole-like objects from mobile mapping
data", ISPRS Annals II-3/W5.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from guardrail_core.reconstruct.poles.circles import fit_circles
from guardrail_core.reconstruct.poles.params import PoleParams

#: Sections are lifted this many cluster gaps apart for one 3-D neighbour search (any factor
#: above 1 keeps them apart; not a threshold).
_SECTION_LIFT = 10.0


@dataclass(frozen=True)
class SectionClusters:
    """The clusters of a run's horizontal sections.

    Attributes
    ----------
    section : (N,) int64, section of each point, 0 at the run's lowest point
    cluster : (N,) int64, cluster of each point, 0 .. C-1 (each within one section)
    centroid : (C, 2) float64, metres: each cluster's xy centroid
    compact : (C,) bool: clusters that may be a pole's section (not wide, not flat)
    """

    section: np.ndarray
    cluster: np.ndarray
    centroid: np.ndarray
    compact: np.ndarray


def section_clusters(xyz: np.ndarray, params: PoleParams) -> SectionClusters:
    """Cut a run's points (N, 3), metres, into horizontal sections and each section into
    clusters; mark the compact ones.

    A cluster is compact when its xy extent is at most ``max_cluster_width_m`` and, where it has
    ``min_circle_points``, its circle is no larger than ``flat_radius_factor`` x
    ``max_radius_m`` (a larger one is a flat piece: a cap seen from above, a beam end).
    """
    n = len(xyz)
    # §4.1: horizontal section planes, every section_step_m.
    section = np.floor((xyz[:, 2] - xyz[:, 2].min()) / params.section_step_m).astype(np.int64)
    # §4.1: in each section, points split into clusters along the run (gaps between them).
    # Sections are kept apart by lifting them far from each other in a 3-D search.
    lifted = np.column_stack([xyz[:, :2], section * (_SECTION_LIFT * params.cluster_gap_m)])
    pairs = cKDTree(lifted).query_pairs(params.cluster_gap_m, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    n_cluster, cluster = connected_components(graph, directed=False)
    count = np.bincount(cluster, minlength=n_cluster)
    lo = np.full((n_cluster, 2), np.inf)
    hi = np.full((n_cluster, 2), -np.inf)
    np.minimum.at(lo, cluster, xyz[:, :2])
    np.maximum.at(hi, cluster, xyz[:, :2])
    width = np.linalg.norm(hi - lo, axis=1)
    compact = width <= params.max_cluster_width_m

    # §4.1: circles fitted to the compact clusters with enough points (algebraic LSQ,
    # outlier rejection); a circle far too big for a pole marks a flat piece (a cap seen from
    # above, a beam end), not a pole's section.
    fit_label = np.where(
        compact[cluster] & (count[cluster] >= params.min_circle_points), cluster, -1
    )
    _, c_radius, _, _ = fit_circles(xyz[:, :2], fit_label, n_cluster, params, refine=False)
    flat = np.isfinite(c_radius) & (c_radius > params.flat_radius_factor * params.max_radius_m)
    compact &= ~flat
    centroid: np.ndarray = np.stack(
        [np.bincount(cluster, xyz[:, k], n_cluster) for k in range(2)], 1
    ).astype(np.float64)
    centroid = centroid / np.maximum(count, 1)[:, None]
    return SectionClusters(section, cluster.astype(np.int64), centroid, compact)


def stack_clusters(clusters: SectionClusters, params: PoleParams) -> tuple[np.ndarray, np.ndarray]:
    """Group the compact clusters into stacks, one per candidate pole.

    §4.1: vertically aligned circles are joined. A cluster is a seed when compact clusters of at
    least ``min_sections`` nearly consecutive sections (skipping at most ``max_section_gap``)
    lie within ``stack_radius_m`` of it: a pole's sections support each other; the fragments of
    a sparse rail (one or two sections per rail) do not.

    Returns
    -------
    stack : (N,) int64, the stack of each point, -1 for none
    centre : (S, 2) float64, metres: each stack's median cluster centre
    """
    section, cluster, centroid = clusters.section, clusters.cluster, clusters.centroid
    n, n_cluster = len(cluster), len(centroid)
    cand = np.flatnonzero(clusters.compact)
    if len(cand) == 0:
        return np.full(n, -1, np.int64), np.zeros((0, 2))
    first_pt = np.full(n_cluster, n, np.int64)
    np.minimum.at(first_pt, cluster, np.arange(n))
    sec_of_cand = section[first_pt[cand]]
    n_sec = int(section.max()) + 1
    # Support: per candidate, the longest run of nearly consecutive sections holding candidates
    # within stack_radius_m of it (itself included).
    cpairs = cKDTree(centroid[cand]).query_pairs(params.stack_radius_m, output_type="ndarray")
    i_all = np.concatenate([cpairs[:, 0], cpairs[:, 1], np.arange(len(cand))])
    j_all = np.concatenate([cpairs[:, 1], cpairs[:, 0], np.arange(len(cand))])
    support_key = np.unique(i_all * n_sec + sec_of_cand[j_all])
    owner, sec = support_key // n_sec, support_key % n_sec
    brk = np.ones(len(support_key), bool)
    brk[1:] = (owner[1:] != owner[:-1]) | (np.diff(sec) > params.max_section_gap + 1)
    run = np.cumsum(brk) - 1
    own = np.searchsorted(support_key, np.arange(len(cand)) * n_sec + sec_of_cand)
    support = np.bincount(run)[run[own]]
    stack_of_cand, centre = _group_stacks(
        centroid[cand], support, support >= params.min_sections, params.stack_radius_m
    )
    stack_of_cluster = np.full(n_cluster, -1, np.int64)
    stack_of_cluster[cand] = stack_of_cand
    return stack_of_cluster[cluster], centre


def _group_stacks(
    centres: np.ndarray, support: np.ndarray, seed: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Greedy grouping of seed clusters into stacks, strongest support first.

    Each stack takes the unassigned seeds within ``radius`` of the median centre of the seeds
    around its strongest one, so stacks never chain along a rail. Returns the stack of each
    cluster (K,) int64 (-1: none) and the stack centres (S, 2).
    """
    stack_of = np.full(len(centres), -1, np.int64)
    out: list[np.ndarray] = []
    idx = np.flatnonzero(seed)
    if len(idx) == 0:
        return stack_of, np.zeros((0, 2))
    tree = cKDTree(centres[idx])
    free = np.ones(len(idx), bool)
    for i in np.lexsort((np.arange(len(idx)), -support[idx])):  # per stack
        if not free[i]:
            continue
        near = np.asarray(tree.query_ball_point(centres[idx[i]], radius), np.int64)
        near = near[free[near]]
        centre = np.median(centres[idx[near]], axis=0)
        near = np.asarray(tree.query_ball_point(centre, radius), np.int64)
        near = near[free[near]]
        if len(near) == 0:
            near = np.array([i])
        free[near] = False
        stack_of[idx[near]] = len(out)
        out.append(np.median(centres[idx[near]], axis=0))
    return stack_of, np.array(out).reshape(-1, 2)


def in_line(
    z: np.ndarray, cluster: np.ndarray, centroid: np.ndarray, params: PoleParams
) -> np.ndarray:
    """(n,) bool: the points of one stack (heights ``z`` (n,), metres, their section clusters
    ``cluster`` (n,), indexing ``centroid`` (C, 2)) whose cluster centroid lies within
    ``in_line_m`` of the median centroid of the stack's lowest clusters (those within
    ``base_fit_height_m`` of its lowest point)."""
    low = z <= z.min() + params.base_fit_height_m
    foot = np.median(centroid[np.unique(cluster[low])], axis=0)
    return np.linalg.norm(centroid[cluster] - foot, axis=1) <= params.in_line_m
