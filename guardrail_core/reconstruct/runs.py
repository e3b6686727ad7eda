"""Guardrail runs: the guardrail points of a drive grouped into connected stretches.

A run is one continuous guardrail: the points of its rails, beams and poles touch each other
within ``link_distance_m``. Runs are what §4.1 subdivides into unit shapes; two guardrails on
either side of the street, or separated by a driveway, are different runs. A guardrail that one
slice called other cut in two (0.5 m: a shrub against its rails) is one run again where its two
pieces stand on one line with the same heights across a gap of ``bridge_m`` at most: each piece
may hold a single pole, and a unit needs two.

References
----------
Matsumoto, Mori, Masuda (2019), "Extraction and shape reconstruction of guardrails using mobile
mapping data", ISPRS Archives, §4.1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from guardrail_core.errors import ReconstructionError
from guardrail_core.params import StageParams, param


@dataclass(frozen=True)
class RunParams(StageParams):
    """How guardrail points are grouped into runs, and which ground points a run takes."""

    link_distance_m: float = param(
        0.3,
        unit="m",
        gt=0,
        le=10.0,
        doc="Points closer than this are in the same run (measured between the centroids of "
        "occupied voxels of ``1 / voxels_per_link`` of this size, so the effective distance "
        "is within about half a voxel diagonal of it).",
    )
    voxels_per_link: int = param(
        3,
        ge=1,
        doc="The voxels whose centroids are linked are ``link_distance_m / voxels_per_link`` "
        "wide: smaller ones follow the points more closely, larger ones are faster.",
    )
    min_points: int = param(
        100, ge=1, doc="Points. A group with fewer points is not a run (its points get -1)."
    )
    min_length_m: float = param(
        1.5,
        unit="m",
        ge=0,
        le=100.0,
        doc="A group whose horizontal extent (the diagonal of its xy bounding box along its "
        "principal direction) is shorter than this is not a run: shorter than one unit.",
    )
    bridge_m: float = param(
        0.8,
        unit="m",
        ge=0,
        le=10.0,
        doc="Two components closer than this (a slice of 0.5 m called other, and the link "
        "distance) are one run where they stand on one line with the same heights "
        "(bridge_window_m, bridge_height_m, bridge_lateral_m, bridge_angle_deg); 0: never.",
    )
    bridge_window_m: float = param(
        1.0,
        unit="m",
        gt=0,
        le=10.0,
        doc="Each side of a bridge is judged on its points within this horizontal distance of "
        "the gap.",
    )
    bridge_height_m: float = param(
        0.1,
        unit="m",
        gt=0,
        doc="The 10th and the 90th percentiles of the heights on either side of a bridge differ "
        "by at most this (an arch fence abutting a W-beam, 0.2 m higher at its foot, does not "
        "bridge).",
    )
    bridge_lateral_m: float = param(
        0.15,
        unit="m",
        gt=0,
        doc="Each side's end lies within this distance of the other side's line (horizontally).",
    )
    bridge_angle_deg: float = param(
        15.0,
        unit="deg",
        ge=0,
        le=90,
        doc="The two sides' lines (their principal directions, horizontally) turn by at most this.",
    )
    ground_reach_m: float = param(
        1.0,
        unit="m",
        gt=0,
        le=10.0,
        doc="Ground points within this horizontal distance of a run's points are its ground "
        "(where its poles stand); farther ones are not.",
    )
    ground_query_step: int = param(
        10,
        ge=1,
        doc="Every this-many-th point of a run looks for ground points within ``ground_reach_m`` "
        "(speed: neighbouring guardrail points have the same ground).",
    )


def check_points(xyz: np.ndarray, name: str = "xyz") -> np.ndarray:
    """``xyz`` as (N, 3) float64, or :class:`ReconstructionError` saying what came instead."""
    try:
        a = np.asarray(xyz, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ReconstructionError(f"{name} must be an (N, 3) array of numbers: {exc}") from exc
    if a.ndim != 2 or a.shape[1] != 3:
        raise ReconstructionError(f"{name} must have shape (N, 3), got {a.shape}")
    if not np.isfinite(a).all():
        n_bad = int((~np.isfinite(a).all(axis=1)).sum())
        raise ReconstructionError(f"{name} has {n_bad} points with NaN or infinite coordinates")
    return a


def group_runs(xyz: np.ndarray, params: RunParams = RunParams()) -> np.ndarray:
    """Run id of each guardrail point: connected components within ``link_distance_m``.

    Parameters
    ----------
    xyz : (N, 3) float64, metres, world: the guardrail points of a drive
    params : the grouping thresholds

    Returns
    -------
    (N,) int32: run id 0 .. R-1, numbered by the first point index of each run (deterministic);
    -1 for points of groups with fewer than ``min_points`` points or shorter than
    ``min_length_m``.

    References
    ----------
    Matsumoto et al. 2019, §4.1 (a guardrail is subdivided run by run).
    """
    xyz = check_points(xyz)
    n = len(xyz)
    out = np.full(n, -1, np.int32)
    if n == 0:
        return out
    comp, n_comp = link_components(xyz, params)
    keep = is_run(xyz, comp, n_comp, params)
    # Deterministic numbering: by the first point index of each kept component.
    first = np.full(n_comp, n, np.int64)
    np.minimum.at(first, comp, np.arange(n))
    kept = np.flatnonzero(keep)
    new_id = np.full(n_comp, -1, np.int32)
    new_id[kept[np.argsort(first[kept], kind="stable")]] = np.arange(len(kept), dtype=np.int32)
    out[:] = new_id[comp]
    return out


def link_components(xyz: np.ndarray, params: RunParams = RunParams()) -> tuple[np.ndarray, int]:
    """The connected components of guardrail points (N, 3) within ``link_distance_m``: (N,)
    int64 component of each point, and their number.

    Points are linked through the centroids of the voxels they occupy; the voxels are cells of a
    grid fixed in the frame (not anchored at the points), so a point's voxel, and with it the
    components, do not depend on which other points are given: guardrail points gathered tile
    by tile (:class:`guardrail_core.process.run_stream.RunStream`) link as those of a whole drive.
    Components are then joined across the gaps a slice called other left (:func:`_bridged`).
    """
    voxel = params.link_distance_m / params.voxels_per_link
    cell = np.floor(xyz / voxel).astype(np.int64)
    cell -= cell.min(axis=0)
    dims = cell.max(axis=0) + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    _, voxel_of_point, counts = np.unique(key, return_inverse=True, return_counts=True)
    n_vox = len(counts)
    centroids = np.zeros((n_vox, 3))
    np.add.at(centroids, voxel_of_point, xyz)
    centroids /= counts[:, None]
    pairs = cKDTree(centroids).query_pairs(params.link_distance_m, output_type="ndarray")
    graph = coo_matrix(
        (np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n_vox, n_vox)
    )
    n_comp, comp_of_voxel = connected_components(graph, directed=False)
    comp_of_voxel, n_comp = _bridged(centroids, counts, comp_of_voxel, n_comp, params)
    return comp_of_voxel[voxel_of_point].astype(np.int64), int(n_comp)


def _bridged(
    centroids: np.ndarray, counts: np.ndarray, comp: np.ndarray, n_comp: int, params: RunParams
) -> tuple[np.ndarray, int]:
    """Components (of voxels (V, 3) centroids, (V,) point counts, (V,) component) joined
    across the gaps that :func:`_one_line` bridges, renumbered 0 .. C'-1 in the order of their
    first component: the new (V,) component of each voxel and C'.

    Each pair of components is judged once, at its closest pair of voxels within
    ``bridge_m`` (:func:`_closest_voxels`)."""
    if params.bridge_m <= 0 or n_comp < 2:
        return comp, n_comp
    closest = _closest_voxels(centroids, comp, params.bridge_m)
    plan = cKDTree(centroids[:, :2])
    joins = [
        (int(comp[a]), int(comp[b]))
        for a, b in closest
        if _one_line(plan, centroids, counts, comp, (a, b), params)
    ]
    if not joins:
        return comp, n_comp
    edges = np.array(joins)
    graph = coo_matrix(
        (np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(n_comp, n_comp)
    )
    n_joined, joined = connected_components(graph, directed=False)
    return joined[comp], int(n_joined)


def _closest_voxels(centroids: np.ndarray, comp: np.ndarray, reach: float) -> list[tuple[int, int]]:
    """For each pair of components (of voxels (V, 3) centroids, (V,) component) with voxels
    within ``reach`` metres of each other, their closest pair of voxels, in the order of the
    components.

    Every pair of voxels within reach, as a tree query would give them, is 40 times the voxels
    on a rail (4 GB for 2.8 million points); the voxels are grouped by component in cells of
    ``reach`` first, and only groups of two components whose centroids stand within reach and
    two cell diagonals (the farthest two voxels of such cells can be) are compared voxel by
    voxel."""
    cell = np.floor(centroids / reach).astype(np.int64)
    key = np.column_stack([comp, cell])
    _, group, size = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    group = group.reshape(-1)
    members = np.split(np.argsort(group, kind="stable"), np.cumsum(size)[:-1])
    group_comp = comp[[m[0] for m in members]]
    group_centre = np.array([centroids[m].mean(axis=0) for m in members]).reshape(-1, 3)
    pairs = cKDTree(group_centre).query_pairs(
        reach + 2 * float(np.sqrt(3.0)) * reach, output_type="ndarray"
    )
    pairs = pairs[group_comp[pairs[:, 0]] != group_comp[pairs[:, 1]]]
    best: dict[tuple[int, int], tuple[float, int, int]] = {}
    for g, h in pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]:
        a, b = members[g], members[h]
        d = np.linalg.norm(centroids[a][:, None, :] - centroids[b][None, :, :], axis=2)
        i, j = np.unravel_index(int(np.argmin(d)), d.shape)
        if d[i, j] > reach:
            continue
        va, vb = int(a[i]), int(b[j])
        if comp[va] > comp[vb]:
            va, vb = vb, va
        pair = (int(comp[va]), int(comp[vb]))
        if pair not in best or d[i, j] < best[pair][0]:
            best[pair] = (float(d[i, j]), va, vb)
    return [(va, vb) for _, (_, va, vb) in sorted(best.items())]


def _one_line(
    plan: cKDTree,
    centroids: np.ndarray,
    counts: np.ndarray,
    comp: np.ndarray,
    ends: tuple[int, int],
    params: RunParams,
) -> bool:
    """Whether the components of the voxels ``ends`` (the closest pair across their gap) are
    one guardrail cut in two: their voxels within ``bridge_window_m`` of the gap (``plan``: a
    tree of the centroids' x, y) have the same heights (``bridge_height_m``) and parallel lines
    (``bridge_angle_deg``), each end within ``bridge_lateral_m`` of the other side's line."""
    a, b = ends
    sides = []
    for v in ends:
        near = np.asarray(plan.query_ball_point(centroids[v, :2], params.bridge_window_m))
        near = near[comp[near] == comp[v]]
        if len(near) < 3:
            return False
        sides.append((centroids[near], counts[near].astype(np.float64)))
    for q in (0.1, 0.9):
        za, zb = (_weighted_quantile(p[:, 2], w, q) for p, w in sides)
        if abs(za - zb) > params.bridge_height_m:
            return False
    lines = [_principal_line(p[:, :2], w) for p, w in sides]
    (ma, ua), (mb, ub) = lines
    if abs(float(ua @ ub)) < np.cos(np.radians(params.bridge_angle_deg)):
        return False
    for (m, u), end in (((ma, ua), centroids[b, :2]), ((mb, ub), centroids[a, :2])):
        r = end - m
        if abs(r[0] * u[1] - r[1] * u[0]) > params.bridge_lateral_m:
            return False
    return True


def _weighted_quantile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    """The ``q`` quantile of ``values`` (K,) each counted ``weights`` (K,) times."""
    order = np.argsort(values, kind="stable")
    share = np.cumsum(weights[order]) / weights.sum()
    return float(values[order][min(int(np.searchsorted(share, q)), len(values) - 1)])


def _principal_line(xy: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The weighted mean (2,) of points ``xy`` (K, 2) and their principal direction (2,)."""
    mean = np.average(xy, axis=0, weights=weights)
    d = xy - mean
    _, vectors = np.linalg.eigh((d * weights[:, None]).T @ d)
    return mean, vectors[:, -1]


def link_reach_m(params: RunParams = RunParams()) -> float:
    """Metres: no point farther than this from every point of a component can change it (join
    it, or move the centroid of a voxel it is linked through, or change a bridge to it: one
    across ``bridge_m`` judged on the points within ``bridge_window_m`` beyond): the farther
    of the link distance and the bridge with its window, and two voxel diagonals."""
    voxel = params.link_distance_m / params.voxels_per_link
    bridge = params.bridge_m + params.bridge_window_m if params.bridge_m > 0 else 0.0
    return max(params.link_distance_m, bridge) + 2 * float(np.sqrt(3.0)) * voxel


def is_run(xyz: np.ndarray, comp: np.ndarray, n_comp: int, params: RunParams) -> np.ndarray:
    """(C,) bool: the components (of :func:`link_components`) with at least ``min_points``
    points and ``min_length_m`` of horizontal length."""
    size = np.bincount(comp, minlength=n_comp)
    # Horizontal length: the xy extent along each component's principal direction.
    length = _horizontal_length(xyz[:, :2], comp, n_comp)
    return (size >= params.min_points) & (length >= params.min_length_m)


def _horizontal_length(xy: np.ndarray, label: np.ndarray, n_label: int) -> np.ndarray:
    """(L,) metres: extent of each label's xy points along its principal direction."""
    count = np.bincount(label, minlength=n_label).astype(np.float64)
    mean: np.ndarray = np.stack(
        [np.bincount(label, xy[:, k], n_label) for k in range(2)], 1
    ).astype(np.float64)
    mean = mean / np.maximum(count, 1)[:, None]
    d = xy - mean[label]
    cxx = np.bincount(label, d[:, 0] ** 2, n_label)
    cxy = np.bincount(label, d[:, 0] * d[:, 1], n_label)
    cyy = np.bincount(label, d[:, 1] ** 2, n_label)
    # Principal direction of the 2x2 covariance, in closed form.
    angle = 0.5 * np.arctan2(2 * cxy, cxx - cyy)
    direction = np.stack([np.cos(angle), np.sin(angle)], 1)
    s = np.einsum("ij,ij->i", d, direction[label])
    lo = np.full(n_label, np.inf)
    hi = np.full(n_label, -np.inf)
    np.minimum.at(lo, label, s)
    np.maximum.at(hi, label, s)
    return np.where(count > 0, hi - lo, 0.0)
