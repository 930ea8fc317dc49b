"""Point-cloud preprocessing (3.5.3, B.2): workspace crop, support-plane RANSAC and removal,
voxel down-sampling and tangent-plane up-sampling to a fixed count per segment.

All functions are numpy, deterministic for a given ``numpy.random.Generator``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from .types import SupportPlane, Workspace


def crop_mask(points: np.ndarray, workspace: Workspace | None) -> np.ndarray:
    """Bool ``(N,)``: points inside the axis-aligned ``workspace`` box (all if None)."""
    if workspace is None:
        return np.ones(len(points), dtype=bool)
    lo, hi = np.asarray(workspace.min), np.asarray(workspace.max)
    return np.all((points >= lo) & (points <= hi), axis=1)


@dataclasses.dataclass(frozen=True)
class PlaneFit:
    normal: np.ndarray
    """(3,) unit normal pointing into free space (toward the viewpoint, else +z)."""
    offset: float
    """``d`` of ``normal . x + d = 0``."""
    inliers: np.ndarray
    """(N,) bool, within the RANSAC threshold."""

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        return points @ self.normal + self.offset

    def as_support(self) -> SupportPlane:
        return SupportPlane(tuple(float(v) for v in self.normal), float(self.offset))


def fit_plane_ransac(
    points: np.ndarray,
    rng: np.random.Generator,
    *,
    threshold: float = 0.005,
    iterations: int = 128,
    eval_points: int = 3000,
    viewpoint: np.ndarray | None = None,
    min_fraction: float = 0.05,
) -> PlaneFit | None:
    """Dominant plane by RANSAC (B.2), refit by least squares (principal axes) on its inliers.

    Hypotheses from random point triples are scored all at once on ``eval_points`` random points
    (a ``(eval, iterations)`` distance matrix), the best is refit twice on its inliers among
    ``4 eval_points`` random points (drawn with replacement) and its inliers recomputed on the
    whole cloud. Returns None if fewer than ``min_fraction`` (and < 3) points
    support it. The normal is oriented toward ``viewpoint`` (the sensor sees the plane's free
    side) or, without one, toward +z.
    """
    n = len(points)
    if n < 3:
        return None
    p = points.astype(np.float64)
    tri = p[rng.integers(0, n, size=(iterations, 3))]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(nrm, axis=1)
    ok = length > 1e-12
    if not ok.any():
        return None
    nrm = nrm[ok] / length[ok, None]
    d = -(nrm * tri[ok, 0]).sum(1)
    sub = p[rng.integers(0, n, eval_points)] if n > eval_points else p
    score = (np.abs(sub @ nrm.T + d) < threshold).sum(0)
    best = int(np.argmax(score))
    normal, offset = nrm[best], d[best]
    # least-squares refits on the inliers of a larger random subset (the plane of 10^4
    # inliers is as good as that of all of them), final inliers on the whole cloud
    ref = p if n <= 4 * eval_points else p[rng.integers(0, n, 4 * eval_points)]
    for _ in range(2):
        inl = np.abs(ref @ normal + offset) < threshold
        if inl.sum() < 3:
            return None
        # smallest principal axis of the inliers from their 3x3 scatter matrix (the same
        # plane as an SVD of the centred (n, 3) inliers, at a fraction of the cost)
        q = ref[inl]
        c = q.mean(0)
        qc = q - c
        _, vec = np.linalg.eigh(qc.T @ qc)
        normal = vec[:, 0]
        offset = -float(normal @ c)
    inliers = np.abs(p @ normal + offset) < threshold
    if inliers.sum() < max(3, min_fraction * n):
        return None
    up = (viewpoint @ normal + offset) if viewpoint is not None else normal[2]
    if up < 0:
        normal, offset = -normal, -offset
    return PlaneFit(normal, float(offset), inliers)


def voxel_downsample(points: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """One representative (the first point) per occupied voxel of edge ``voxel``.

    Returns ``(indices (M,), inverse (N,))``: indices of the kept points into ``points`` and,
    for every point, the position of its voxel's representative in ``indices``.
    """
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    key = np.floor(points / voxel).astype(np.int64)
    key -= key.min(0)
    dims = key.max(0) + 1
    flat = (key[:, 0] * dims[1] + key[:, 1]) * dims[2] + key[:, 2]
    _, index, inverse = np.unique(flat, return_index=True, return_inverse=True)
    return index.astype(np.int64), inverse.reshape(-1).astype(np.int64)


def estimate_normals(
    points: np.ndarray, k: int = 10, viewpoint: np.ndarray | None = None, tree=None
) -> np.ndarray:
    """Unit normals ``(N, 3)`` by PCA of the ``k`` nearest neighbours, oriented toward
    ``viewpoint`` (or +z without one)."""
    n = len(points)
    if n < 3:
        return np.tile([0.0, 0.0, 1.0], (n, 1))
    tree = tree if tree is not None else cKDTree(points)
    _, nb = tree.query(points, k=min(k, n))
    q = points[nb] - points[nb].mean(1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", q, q)
    _, vec = np.linalg.eigh(cov)
    nrm = vec[:, :, 0]
    ref = (viewpoint - points) if viewpoint is not None else np.array([0.0, 0.0, 1.0])
    flip = (nrm * ref).sum(-1) < 0
    nrm[flip] *= -1
    return nrm


def resample(
    points: np.ndarray,
    n: int,
    rng: np.random.Generator,
    *,
    voxel: float = 0.004,
    neighbors: int = 8,
) -> np.ndarray:
    """Down/up-sample a segment to exactly ``n`` points (3.5.3).

    Down: voxel down-sampling (even density), then a random subset. Up: the missing points are
    drawn on the tangent planes of random existing points (plane by PCA of their ``neighbors``
    nearest neighbours), at a random offset within the local point spacing, so new points stay
    on the observed surface instead of duplicating it.
    """
    if len(points) == 0:
        raise ValueError("points must hold at least one point, got 0")
    pts = points.astype(np.float64)
    if len(pts) > n:
        idx, _ = voxel_downsample(pts, voxel)
        if len(idx) >= n:
            return pts[rng.choice(idx, n, replace=False)]
        rest = np.setdiff1d(np.arange(len(pts)), idx)
        extra = rng.choice(rest, n - len(idx), replace=False)
        return pts[np.concatenate([idx, extra])]
    if len(pts) == n:
        return pts
    missing = n - len(pts)
    src = rng.integers(0, len(pts), missing)
    if len(pts) < 3:
        jitter = rng.normal(scale=voxel / 4, size=(missing, 3))
        return np.concatenate([pts, pts[src] + jitter])
    k = min(neighbors, len(pts))
    tree = cKDTree(pts)
    dist, nb = tree.query(pts[src], k=k)
    q = pts[nb] - pts[nb].mean(1, keepdims=True)
    _, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", q, q))
    u, v = vec[:, :, 2], vec[:, :, 1]  # the two in-plane directions
    spacing = dist[:, 1:].mean(1) if k > 1 else np.full(missing, voxel)
    r = spacing * np.sqrt(rng.uniform(size=missing)) * 0.5
    phi = rng.uniform(0, 2 * np.pi, missing)
    new = pts[src] + (r * np.cos(phi))[:, None] * u + (r * np.sin(phi))[:, None] * v
    return np.concatenate([pts, new])
