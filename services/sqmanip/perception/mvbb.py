"""Minimum-volume bounding box by PCA (the MVBB baseline of 3.5.2, [86]).

The box axes are the principal axes of the segment, its extent the span of the points along
them. Returned as a box-like superquadric (``e1 = e2 = 0.2``, the smallest exponents allowed).
With a support plane, the upright variant uses the plane normal as z, PCA of the points
projected on the plane for x/y, and extends the box down to the plane (a cheap amodal fallback).
"""

from __future__ import annotations

import numpy as np

from sqmanip.geometry import Superquadric

from .preprocess import PlaneFit

MIN_HALF = 1e-3
BOX_SHAPE = (0.2, 0.2)


def _right_handed(R: np.ndarray) -> np.ndarray:
    if np.linalg.det(R) < 0:
        R = R.copy()
        R[:, 0] *= -1
    return R


def _box(points: np.ndarray, R: np.ndarray, floor: float | None = None) -> Superquadric:
    local = points @ R
    lo, hi = local.min(0), local.max(0)
    if floor is not None:
        lo[2] = min(lo[2], floor)
    half = np.maximum((hi - lo) / 2, MIN_HALF)
    pose = np.eye(4)
    pose[:3, :3] = R
    pose[:3, 3] = R @ ((hi + lo) / 2)
    return Superquadric(tuple(float(v) for v in half), BOX_SHAPE, pose=pose)


def mvbb_fit(points: np.ndarray, plane: PlaneFit | None = None) -> Superquadric:
    """PCA bounding box of ``points (N, 3)``; upright and reaching the plane if ``plane`` given."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise ValueError(f"points must have shape (N, 3) with N >= 1, got {p.shape}")
    c = p.mean(0)
    if plane is None:
        if len(p) < 3:
            R = np.eye(3)
        else:
            _, vec = np.linalg.eigh(np.cov((p - c).T))
            R = _right_handed(vec[:, ::-1])  # major axis first
        return _box(p, R)
    z = plane.normal
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(z, helper)
    u /= np.linalg.norm(u)
    v = np.cross(z, u)
    q = (p - c) @ np.stack([u, v], 1)
    if len(p) >= 3:
        _, vec = np.linalg.eigh(np.cov(q.T))
        major = vec[:, 1]
    else:
        major = np.array([1.0, 0.0])
    x = major[0] * u + major[1] * v
    R = np.stack([x, np.cross(z, x), z], 1)
    # the plane in the box frame: z_local = -offset
    return _box(p, R, floor=-plane.offset)
