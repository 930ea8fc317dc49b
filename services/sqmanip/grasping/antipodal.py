"""Antipodal point pairs and grasp poses on deformable superquadric parts (3.4, Algorithm 1).

For a surface ``S`` antipodal points satisfy ``n(x1) + n(x2) = 0`` (3.4.7) and
``(x1 - x2) x n(x1) = 0`` (3.4.8). Following 3.4.1:

1. ``x1``: approximately uniform samples over every part's surface (``geometry.sampling``), with
   closed-form normals (2.3.21); samples inside another part of the same object are dropped (they
   are not on the object's surface);
2. (3.4.8) holds on the line ``l(t) = x1 - n(x1) t``: it is intersected with *every* part by the
   Newton-Raphson line search of ``geometry.raycast`` (all roots ``t > 0``);
3. each root ``x*`` passes the relaxed (3.4.7) ``n(x1) . n(x*) < -0.9 |n(x1)| |n(x*)|``;
4. the valid root farthest from ``x1`` is ``x2``.

Everything is batched over samples, parts and roots (no Python loop over samples). Grasp poses
(3.4.2): for each pair, ``n_approach`` approach vectors at equal steps (30 deg for 12) about the
closing axis ``x2 - x1``, starting from the one closest to ``-z_t`` (straight down when possible).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
import torch

from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric, pack, sample_parts, world_implicit
from sqmanip.geometry.raycast import world_line_intersections
from sqmanip.geometry.superquadric import normal


@dataclasses.dataclass(frozen=True)
class AntipodalPairs:
    """Antipodal pairs found on an object, world frame, ``P`` pairs out of ``S`` samples."""

    x1: torch.Tensor
    """(P, 3) sampled points."""
    x2: torch.Tensor
    """(P, 3) farthest valid antipodal point of each ``x1``."""
    n1: torch.Tensor
    """(P, 3) unit outward normals at ``x1``."""
    n2: torch.Tensor
    """(P, 3) unit outward normals at ``x2``."""
    width: torch.Tensor
    """(P,) ``|x2 - x1|``."""
    part1: torch.Tensor
    """(P,) part index of ``x1``."""
    part2: torch.Tensor
    """(P,) part index of ``x2``."""
    samples: torch.Tensor
    """(S, 3) all surface samples (on the object's outer surface), for uncertainty scores."""

    def __len__(self) -> int:
        return self.x1.shape[0]


def part_normals(
    points: torch.Tensor, params: torch.Tensor, poses: torch.Tensor, kinds: torch.Tensor
) -> torch.Tensor:
    """Outward unit normal of part ``m`` at its own points: ``points (M, N, 3) -> (M, N, 3)``.

    Unlike :func:`world.world_normal` (every part at every point) this evaluates part ``m`` only
    at ``points[m]`` (2.3.21 in each part's frame, rotated back to the world).
    """
    R, t = poses[:, :3, :3], poses[:, :3, 3]
    local = (points - t.unsqueeze(1)) @ R  # R^T (x - t), row-vector form
    out = torch.empty_like(points)
    for kind in torch.unique(kinds).tolist():
        sel = (kinds == kind).nonzero().squeeze(-1)
        n_local = normal(local[sel], params[sel], int(kind))
        out[sel] = n_local @ R[sel].transpose(-1, -2)
    return out


def sample_antipodal_pairs(
    parts: Sequence[Superquadric],
    n_samples: int = 256,
    *,
    threshold: float = 0.9,
    generator: torch.Generator | int | None = 0,
    dtype: torch.dtype = torch.float64,
    n_scan: int = 48,
    newton_iters: int = 20,
) -> AntipodalPairs:
    """Antipodal pairs of the object made of ``parts`` (3.4.1, Algorithm 1 lines 4-18).

    ``n_samples`` surface samples are split over the parts by area; returns the pairs whose
    relaxed antipodal test passes. ``n_scan`` is the raycast's bracketing resolution (it must
    resolve the thinnest part along a line; 48 samples over a part's bound chord do for e >= 0.2).
    ``newton_iters`` caps the safeguarded Newton refinement (the core's float64 default of 30 buys
    sub-nanometre roots a gripper cannot use; 20 leave ``|S - 1| < 1e-6``, well under a micrometre).
    """
    if len(parts) == 0:
        raise ValidationError("target must have at least one part, got 0")
    if not 0.0 <= threshold <= 1.0:
        raise ValidationError(f"threshold must be in [0, 1], got {threshold!r}")
    pts_np, nrm_np, ids_np = sample_parts(
        list(parts), int(n_samples), generator=generator, dtype=dtype
    )
    x = torch.as_tensor(pts_np, dtype=dtype)
    n = torch.as_tensor(nrm_np, dtype=dtype)
    ids = torch.as_tensor(ids_np, dtype=torch.long)
    packed = pack(list(parts), dtype=dtype)
    M = len(parts)
    if M > 1 and x.shape[0] > 0:
        # drop samples buried inside another part: they are not on the object's surface
        S = world_implicit(x, packed.params, packed.poses, packed.kinds)  # (M, S)
        own = torch.zeros_like(S, dtype=torch.bool)
        own[ids, torch.arange(x.shape[0])] = True
        inside = ((S < 1.0 - 1e-6) & ~own).any(0)
        x, n, ids = x[~inside], n[~inside], ids[~inside]
    empty = torch.zeros(0, 3, dtype=dtype)
    if x.shape[0] == 0:
        z = torch.zeros(0, dtype=torch.long)
        return AntipodalPairs(empty, empty, empty, empty, empty[:, 0], z, z, x)

    direction = -n  # inward: the other side of the object lies at t > 0
    hits = world_line_intersections(
        x, direction, packed.params, packed.poses, packed.kinds, n_scan=n_scan, iters=newton_iters
    )  # t, valid: (M, S, K)
    Mk, S, K = hits.t.shape
    if K == 0:
        z = torch.zeros(0, dtype=torch.long)
        return AntipodalPairs(empty, empty, empty, empty, empty[:, 0], z, z, x)
    roots = x.view(1, S, 1, 3) + hits.t.unsqueeze(-1) * direction.view(1, S, 1, 3)  # (M,S,K,3)
    n_star = part_normals(roots.reshape(M, S * K, 3), packed.params, packed.poses, packed.kinds)
    n_star = n_star.reshape(M, S, K, 3)
    cos = (n_star * n.view(1, S, 1, 3)).sum(-1)  # unit normals: |n1| |n*| = 1
    valid = hits.valid & (cos < -threshold)
    t = torch.where(valid, hits.t, torch.full_like(hits.t, -math.inf))
    t_flat = t.permute(1, 0, 2).reshape(S, M * K)
    best_t, best = t_flat.max(-1)
    ok = torch.isfinite(best_t)
    part2 = torch.div(best, K, rounding_mode="floor")
    root_i = best % K
    s_idx = torch.arange(S)
    x2 = roots[part2, s_idx, root_i]
    n2 = n_star[part2, s_idx, root_i]
    return AntipodalPairs(
        x1=x[ok],
        x2=x2[ok],
        n1=n[ok],
        n2=n2[ok],
        width=best_t[ok],  # directions are unit, so t is the distance
        part1=ids[ok],
        part2=part2[ok],
        samples=x,
    )


def _perpendicular_reference(axis: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
    """Unit vectors ``(P, 3)`` perpendicular to ``axis (P, 3)``, as close to ``up`` as possible.

    Where ``axis`` is (anti)parallel to ``up`` any perpendicular is fine; world x (or y) is used.
    """
    u = up.expand_as(axis) - (axis * up).sum(-1, keepdim=True) * axis
    norm = torch.linalg.vector_norm(u, dim=-1, keepdim=True)
    ex = torch.tensor([1.0, 0.0, 0.0], dtype=axis.dtype).expand_as(axis)
    ey = torch.tensor([0.0, 1.0, 0.0], dtype=axis.dtype).expand_as(axis)
    alt = torch.where((axis[..., :1].abs() < 0.9), ex, ey)
    alt = alt - (axis * alt).sum(-1, keepdim=True) * axis
    alt = alt / torch.linalg.vector_norm(alt, dim=-1, keepdim=True)
    return torch.where(norm > 1e-6, u / norm.clamp_min(1e-12), alt)


def poses_about_axis(
    center: torch.Tensor, axis: torch.Tensor, up: np.ndarray | torch.Tensor, n_approach: int = 12
) -> torch.Tensor:
    """Gripper poses ``(P, A, 4, 4)`` with TCP at ``center (P, 3)`` and closing axis ``axis (P, 3)``.

    Approach ``z_k = cos(theta_k) z_0 + sin(theta_k) (y x z_0)``, ``theta_k = 2 pi k / A``, where
    ``z_0`` is the unit vector perpendicular to ``y = axis`` closest to ``-up`` (3.4.2: 30 deg steps
    for ``A = 12``, and the first pose is the most top-down one available for the pair).
    """
    dtype = center.dtype
    y = axis / torch.linalg.vector_norm(axis, dim=-1, keepdim=True).clamp_min(1e-12)
    up_t = torch.as_tensor(np.asarray(up), dtype=dtype)
    z0 = -_perpendicular_reference(y, up_t)
    w0 = torch.linalg.cross(y, z0)
    theta = 2 * math.pi * torch.arange(n_approach, dtype=dtype) / n_approach
    c, s = torch.cos(theta).view(1, -1, 1), torch.sin(theta).view(1, -1, 1)
    z = c * z0.unsqueeze(1) + s * w0.unsqueeze(1)  # (P, A, 3)
    yy = y.unsqueeze(1).expand_as(z)
    x = torch.linalg.cross(yy, z)
    P = center.shape[0]
    T = torch.zeros(P, n_approach, 4, 4, dtype=dtype)
    T[..., :3, 0], T[..., :3, 1], T[..., :3, 2] = x, yy, z
    T[..., :3, 3] = center.unsqueeze(1)
    T[..., 3, 3] = 1.0
    return T
