"""Segmentation without training: Euclidean clustering plus a local-convexity split of objects
that touch; or the caller's per-point labels.

Clustering runs on a voxel-down-sampled copy (one representative per ``cluster_voxel`` voxel):
representatives closer than ``cluster_radius`` are connected (scipy cKDTree pairs) and the
connected components are clusters. Objects that touch are split by cutting *concave* edges
(the criterion of locally-convex connected patches): with normals ``n`` oriented toward the
sensor, two neighbouring surface points on one convex object satisfy
``(n_i - n_j) . (x_i - x_j) >= 0`` (normals diverge); where two objects meet, the seam is concave
and the product is negative. Normals are smeared across the seam, so instead of cutting single
edges, nodes with at least two concave edges are removed as *seam* nodes; the remaining
components (of at least ``min_cluster_points`` points) are seeds and every seam node or small
fragment joins its nearest seed node. Coplanar flush faces (two
boxes of equal height pushed together) have no concave seam and stay one segment, unless
colours are given and differ: an edge whose ends differ in chromaticity counts as a cut edge for
seam nodes and is also removed itself (objects of different colours that touch, the usual case in
clutter). Colour does not smear across a seam the way normals do, and two objects joined by only a
few edges have no node with two cut edges.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .config import PerceptionSettings
from .preprocess import estimate_normals, voxel_downsample


def segments_from_labels(labels: np.ndarray, min_points: int = 1) -> list[np.ndarray]:
    """Index arrays of each label >= 0 (ascending label order), dropping labels with fewer
    than ``min_points`` points."""
    out = []
    for lab in np.unique(labels):
        if lab < 0:
            continue
        idx = np.flatnonzero(labels == lab)
        if len(idx) >= min_points:
            out.append(idx)
    return out


def _components(n: int, edges: np.ndarray) -> np.ndarray:
    if len(edges) == 0:
        return np.arange(n)
    g = coo_matrix((np.ones(len(edges), dtype=np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    return lab


def _split_concave(
    x: np.ndarray,
    edges: np.ndarray,
    weight: np.ndarray,
    normals: np.ndarray,
    settings: PerceptionSettings,
    colour_cut: np.ndarray,
) -> np.ndarray:
    """Labels ``(M,)`` after removing seam nodes (>= 2 cut edges) and regrowing.

    An edge is cut where the surface is concave or where ``colour_cut`` (edges,) says the
    colour changes; colour edges are also dropped from the graph themselves. Components of the
    graph without seam nodes that weigh at least ``min_cluster_points`` points are seeds; every
    other node (seam, fragment) joins the seed of its nearest seed node.
    """
    d = x[edges[:, 0]] - x[edges[:, 1]]
    dn = normals[edges[:, 0]] - normals[edges[:, 1]]
    conv = (dn * d).sum(1) / np.linalg.norm(d, axis=1).clip(1e-12)
    cut = (conv < -settings.concavity_tolerance) | colour_cut
    seam = np.bincount(edges[cut].ravel(), minlength=len(x)) >= 2
    keep = ~seam[edges[:, 0]] & ~seam[edges[:, 1]] & ~colour_cut
    lab = _components(len(x), edges[keep])
    w = np.bincount(lab, weights=weight * ~seam)
    seed = ~seam & (w[lab] >= settings.min_cluster_points)
    if not seed.any():
        return np.zeros(len(x), dtype=np.int64)
    seeds = np.flatnonzero(seed)
    _, nearest = cKDTree(x[seeds]).query(x[~seed])
    lab = lab.copy()
    lab[~seed] = lab[seeds[nearest]]
    return np.unique(lab, return_inverse=True)[1].reshape(-1)


def chromaticity(colors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(r, g, b) / (r + g + b)`` of ``colors (N, 3)`` (blind to shading) and whether each is
    bright enough (channel sum above ``DARK``) for its chromaticity to mean anything."""
    c = np.asarray(colors, dtype=np.float64)
    total = c.sum(1, keepdims=True)
    return c / total.clip(1e-6), total[:, 0] > DARK


def _colour_change(colors: np.ndarray, edges: np.ndarray, tolerance: float) -> np.ndarray:
    """Edges whose (bright enough) ends differ in chromaticity by more than ``tolerance``."""
    chroma, bright = chromaticity(colors)
    a, b = edges[:, 0], edges[:, 1]
    differ = np.linalg.norm(chroma[a] - chroma[b], axis=1) > tolerance
    return differ & bright[a] & bright[b]


DARK = 0.15
"""Below this sum of the (0-1) channels a colour is too dark to compare."""


def cluster(
    points: np.ndarray,
    settings: PerceptionSettings,
    viewpoint: np.ndarray | None = None,
    colors: np.ndarray | None = None,
) -> list[np.ndarray]:
    """Segments of ``points (N, 3)`` as index arrays, largest first (see module docstring)."""
    return cluster_with_groups(points, settings, viewpoint, colors)[0]


def cluster_with_groups(
    points: np.ndarray,
    settings: PerceptionSettings,
    viewpoint: np.ndarray | None = None,
    colors: np.ndarray | None = None,
) -> tuple[list[np.ndarray], list[int]]:
    """:func:`cluster`, plus for each segment the id of the Euclidean cluster it was cut from
    (segments split at a concave edge or a colour change share it: the parts of one object, or
    touching objects). ``colors (N, 3)`` in [0, 1], optional."""
    if len(points) == 0:
        return [], []
    rep, inverse = voxel_downsample(points, settings.cluster_voxel)
    x = points[rep].astype(np.float64)
    weight = np.bincount(inverse, minlength=len(rep)).astype(np.float64)
    tree = cKDTree(x)
    edges = tree.query_pairs(settings.cluster_radius, output_type="ndarray")
    labels = euclidean = _components(len(x), edges)
    if settings.split_touching and len(edges) and len(x) >= 3:
        nrm = estimate_normals(x, settings.normal_neighbors, viewpoint, tree)
        colour_cut = np.zeros(len(edges), dtype=bool)
        if colors is not None:
            c = np.asarray(colors, dtype=np.float64)
            voxel_colors = (
                np.stack(  # mean colour of each voxel's points
                    [np.bincount(inverse, weights=c[:, k], minlength=len(rep)) for k in range(3)], 1
                )
                / weight[:, None]
            )
            colour_cut = _colour_change(voxel_colors, edges, settings.color_tolerance)
        split = _split_concave(x, edges, weight, nrm, settings, colour_cut)
        # never merge across Euclidean clusters: combine both labelings
        labels = np.unique(labels * (split.max() + 1) + split, return_inverse=True)[1].reshape(-1)
    point_labels = labels[inverse]
    counts = np.bincount(point_labels)
    order = [
        lab
        for lab in np.argsort(-counts, kind="stable")
        if counts[lab] >= settings.min_cluster_points
    ]
    segments = [np.flatnonzero(point_labels == lab) for lab in order]
    return segments, [int(euclidean[inverse[seg[0]]]) for seg in segments]
