"""Occupancy and volumetric IoU of unions of posed superquadrics and of triangle meshes (C.2.5, C.2.10).

IoU is a Monte-Carlo estimate: ``n`` points uniform in the joint axis-aligned bounding box, drawn from
a fixed generator (so repeated calls agree), classified by occupancy (``F <= 1`` for superquadric
unions, ray parity for meshes). Given ``n_u`` points in the union, the intersection count is
binomial, so the standard error is ``sqrt(IoU (1 - IoU) / n_u)`` (about 0.002 for IoU 0.5 with
``n = 50 000`` and a union filling a third of the box). :func:`volume_iou_estimate` returns it.

Mesh containment (:func:`mesh_contains`) counts crossings of the vertical ray ``z -> +inf`` from each
point with the triangles (odd = inside), vectorised by binning points on an x-y grid so each
triangle is tested only against points under its footprint; tens of thousands of points against
a ten-thousand-face mesh take a fraction of a second. The mesh must be watertight. Points on a
ray through an edge or vertex exactly are measure-zero for random samples.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import torch
import trimesh

from .mesh import mesh_vertices
from .numerics import as_tensor
from .types import Superquadric, SuperquadricTensors, pack
from .world import occupied

DEFAULT_SAMPLES = 50_000


@dataclasses.dataclass(frozen=True)
class IoUEstimate:
    """Monte-Carlo IoU with its binomial standard error and the number of points used."""

    iou: float
    stderr: float
    n_points: int
    n_union: int


Shapes = Sequence[Superquadric] | SuperquadricTensors
Solid = Shapes | trimesh.Trimesh


def _tensors(shapes: Shapes, dtype=torch.float64) -> SuperquadricTensors:
    if isinstance(shapes, SuperquadricTensors):
        return SuperquadricTensors(shapes.params.to(dtype), shapes.kinds, shapes.poses.to(dtype))
    return pack(list(shapes), dtype=dtype)


def occupancy(points, shapes: Shapes) -> np.ndarray | torch.Tensor:
    """Hard occupancy ``F(x) <= 1`` (C.2.5, C.2.10) of world ``points (..., N, 3)``: bool ``(..., N)``.

    Numpy in, numpy out; an empty set of shapes occupies nothing.
    """
    as_numpy = not isinstance(points, torch.Tensor)
    pts = as_tensor(points, dtype=torch.float64 if as_numpy else None)
    if pts.ndim < 2 or pts.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., N, 3), got {tuple(pts.shape)}")
    t = _tensors(shapes, pts.dtype)
    occ = occupied(pts, t.params, t.poses, t.kinds)
    return occ.numpy() if as_numpy else occ


def shapes_bounds(shapes: Shapes, margin: float = 0.02) -> np.ndarray:
    """World axis-aligned box ``(2, 3)`` (min, max) containing every shape.

    From the vertices of each shape's mesh (exact surface points), grown by ``margin`` times the
    extent to cover the chord sag between vertices (< 1 % at the resolution used).
    """
    t = _tensors(shapes)
    if len(t) == 0:
        return np.zeros((2, 3))
    lo, hi = [], []
    for i in range(len(t)):
        v = mesh_vertices(t.params[i], int(t.kinds[i]), 16)
        w = v @ t.poses[i, :3, :3].T + t.poses[i, :3, 3]
        lo.append(w.amin(0).numpy())
        hi.append(w.amax(0).numpy())
    lo, hi = np.min(lo, 0), np.max(hi, 0)
    pad = margin * (hi - lo).max()
    return np.stack([lo - pad, hi + pad])


def _solid_bounds(solid: Solid) -> np.ndarray:
    if isinstance(solid, trimesh.Trimesh):
        if len(solid.vertices) == 0:
            return np.zeros((2, 3))
        return np.asarray(solid.bounds, dtype=np.float64)
    return shapes_bounds(solid)


def mesh_contains(vertices, faces, points) -> np.ndarray:
    """Inside test of ``points (N, 3)`` for a watertight mesh ``vertices (V, 3)``, ``faces (F, 3)``.

    Parity of crossings of the ray ``(x, y, z + s)``, ``s > 0``, with the triangles. Returns bool ``(N,)``.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[-1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {points.shape}")
    V = np.asarray(vertices, dtype=np.float64)
    Fc = np.asarray(faces, dtype=np.int64)
    n = len(points)
    if n == 0 or len(Fc) == 0:
        return np.zeros(n, dtype=bool)
    tri = V[Fc]  # (F, 3, 3)
    # drop triangles with no x-y footprint (vertical ones cannot be crossed by a vertical ray)
    e1, e2 = tri[:, 1, :2] - tri[:, 0, :2], tri[:, 2, :2] - tri[:, 0, :2]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    keep = np.abs(det) > 1e-300
    tri, det, e1, e2 = tri[keep], det[keep], e1[keep], e2[keep]

    lo = points[:, :2].min(0)
    hi = points[:, :2].max(0)
    nb = int(max(1, min(1024, np.sqrt(n / 4.0))))
    cell = np.maximum((hi - lo) / nb, 1e-12)
    pb = np.clip(((points[:, :2] - lo) / cell).astype(np.int64), 0, nb - 1)
    pbin = pb[:, 0] * nb + pb[:, 1]
    order = np.argsort(pbin, kind="stable")
    counts = np.bincount(pbin, minlength=nb * nb)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])

    tlo = np.floor((tri[:, :, :2].min(1) - lo) / cell).astype(np.int64)
    thi = np.floor((tri[:, :, :2].max(1) - lo) / cell).astype(np.int64)
    tlo = np.clip(tlo, 0, nb - 1)
    thi = np.clip(thi, -1, nb - 1)
    nx = np.maximum(thi[:, 0] - tlo[:, 0] + 1, 0)
    ny = np.maximum(thi[:, 1] - tlo[:, 1] + 1, 0)
    # (triangle, bin) pairs
    nbins = nx * ny
    t_idx = np.repeat(np.arange(len(tri)), nbins)
    local = np.arange(nbins.sum()) - np.repeat(np.cumsum(nbins) - nbins, nbins)
    bx = tlo[t_idx, 0] + local // np.maximum(ny[t_idx], 1)
    by = tlo[t_idx, 1] + local % np.maximum(ny[t_idx], 1)
    b = bx * nb + by
    # (triangle, point) pairs
    cnt = counts[b]
    t2 = np.repeat(t_idx, cnt)
    local2 = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    p_idx = order[np.repeat(starts[b], cnt) + local2]
    # barycentric coordinates of the point's x-y in the triangle's footprint
    rel = points[p_idx, :2] - tri[t2, 0, :2]
    u = (rel[:, 0] * e2[t2, 1] - rel[:, 1] * e2[t2, 0]) / det[t2]
    v = (e1[t2, 0] * rel[:, 1] - e1[t2, 1] * rel[:, 0]) / det[t2]
    inside = (u >= 0) & (v >= 0) & (u + v <= 1)
    z = (1 - u - v) * tri[t2, 0, 2] + u * tri[t2, 1, 2] + v * tri[t2, 2, 2]
    crossing = inside & (z > points[p_idx, 2])
    hits = np.bincount(p_idx[crossing], minlength=n)
    return (hits % 2) == 1


def _occupancy_of(solid: Solid, points: np.ndarray) -> np.ndarray:
    if isinstance(solid, trimesh.Trimesh):
        return mesh_contains(solid.vertices, solid.faces, points)
    return occupancy(points, solid)


def volume_iou_estimate(
    a: Solid,
    b: Solid,
    *,
    n: int = DEFAULT_SAMPLES,
    generator: torch.Generator | int | None = None,
) -> IoUEstimate:
    """Monte-Carlo volumetric IoU of two solids (unions of posed superquadrics or watertight meshes).

    ``n`` points uniform in the joint bounding box; deterministic for a given ``generator``
    (int seed or ``torch.Generator``; default seed 0). Two empty solids give IoU 0.
    """
    if n <= 0:
        raise ValueError(f"n must be positive, got {n}")
    ba, bb = _solid_bounds(a), _solid_bounds(b)
    lo, hi = np.minimum(ba[0], bb[0]), np.maximum(ba[1], bb[1])
    g = generator
    if not isinstance(g, torch.Generator):
        g = torch.Generator()
        g.manual_seed(0 if generator is None else int(generator))
    u = torch.rand(n, 3, generator=g, dtype=torch.float64).numpy()
    pts = lo + u * (hi - lo)
    oa, ob = _occupancy_of(a, pts), _occupancy_of(b, pts)
    n_union = int((oa | ob).sum())
    if n_union == 0:
        return IoUEstimate(0.0, 0.0, n, 0)
    iou = float((oa & ob).sum()) / n_union
    return IoUEstimate(iou, float(np.sqrt(iou * (1 - iou) / n_union)), n, n_union)


def volume_iou(a: Solid, b: Solid, *, n: int = DEFAULT_SAMPLES, generator=None) -> float:
    """:func:`volume_iou_estimate` as a plain float (standard error ``sqrt(IoU(1-IoU)/n_union)``)."""
    return volume_iou_estimate(a, b, n=n, generator=generator).iou
