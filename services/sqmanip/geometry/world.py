"""Posed superquadrics in the world frame: implicit values, occupancy and normals (C.2.5, C.2.10).

Points are ``(..., N, 3)`` in the world frame; a set of ``M`` shapes is ``params (..., M, 9)``,
``poses (..., M, 4, 4)`` and ``kinds (M,)`` (or one int for all). Results are ``(..., M, N)``.
"""

from __future__ import annotations

import torch

from .superquadric import SUPERELLIPSOID, check_points, implicit_homogeneous, normal
from .transforms import se3_inverse, transform_points


def to_object_frames(points: torch.Tensor, poses: torch.Tensor) -> torch.Tensor:
    """World points ``(..., N, 3)`` into each object frame: ``(..., M, N, 3)``."""
    check_points(points)
    return transform_points(se3_inverse(poses), points.unsqueeze(-3))


def _per_kind(fn, local, params, kinds):
    if isinstance(kinds, int):
        return fn(local, params, kinds)
    kinds = torch.as_tensor(kinds)
    unique = torch.unique(kinds).tolist()
    if len(unique) == 1:
        return fn(local, params, int(unique[0]))
    out = None
    for kind in unique:
        value = fn(local, params, int(kind))
        # (M,) -> (M, 1) for values (..., M, N) and (M, 1, 1) for normals (..., M, N, 3).
        trailing = value.ndim - (params.ndim - 1)
        mask = (kinds.to(value.device) == kind).reshape(-1, *([1] * trailing))
        out = value if out is None else torch.where(mask, value, out)
    return out


def world_implicit(
    points: torch.Tensor,
    params: torch.Tensor,
    poses: torch.Tensor,
    kinds: torch.Tensor | int = SUPERELLIPSOID,
) -> torch.Tensor:
    """``S_i(x) = f_D^{e1}(T_i^{-1} x)`` for every shape ``i`` and point: ``(..., M, N)``."""
    local = to_object_frames(points, poses)
    return _per_kind(implicit_homogeneous, local, params, kinds)


def world_normal(
    points: torch.Tensor,
    params: torch.Tensor,
    poses: torch.Tensor,
    kinds: torch.Tensor | int = SUPERELLIPSOID,
) -> torch.Tensor:
    """Unit outward normals in the world frame of every shape at every point: ``(..., M, N, 3)``."""
    local = to_object_frames(points, poses)
    n_local = _per_kind(normal, local, params, kinds)
    return n_local @ poses[..., :3, :3].transpose(-1, -2)


def union_implicit(points, params, poses, kinds=SUPERELLIPSOID) -> torch.Tensor:
    """``F(x) = min_i S_i(x)`` (C.2.5), ``(..., N)``; +inf for an empty set of shapes."""
    if params.shape[-2] == 0:
        return torch.full(points.shape[:-1], float("inf"), dtype=points.dtype, device=points.device)
    return world_implicit(points, params, poses, kinds).amin(-2)


def soft_occupancy(points, params, poses, kinds=SUPERELLIPSOID, sharpness: float = 1000.0):
    """Occupancy ``V(x) = sigmoid(p (1 - F(x)))`` (C.2.6) with ``p = sharpness``, ``(..., N)``."""
    F = union_implicit(points, params, poses, kinds)
    return torch.sigmoid(sharpness * (1.0 - F.clamp_max(1e6)))


def occupied(points, params, poses, kinds=SUPERELLIPSOID) -> torch.Tensor:
    """Hard occupancy ``F(x) <= 1`` (C.2.10), boolean ``(..., N)``."""
    return union_implicit(points, params, poses, kinds) <= 1.0
