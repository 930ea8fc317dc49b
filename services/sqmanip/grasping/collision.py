"""Gripper collision checks against superquadric obstacles and a support plane (3.7.15, B.5.12, C.3).

A grasp pose ``T_gr`` collides with obstacle ``i`` when ``min_j S_i(T_gr x_gr,j) < 1`` for the points
``x_gr,j`` on the open gripper, where ``S_i = f_D^{e1}(T_i^{-1} x)`` is ``< 1`` inside (C.3.11; B.5
writes the same test with ``S - 1``). The support plane is a half-space and uses its signed distance
``n . x + offset < clearance`` instead (exact, no superquadric approximation of the table needed).

Batched over candidates: points outside a part's closed-form bounding sphere, then box, are culled
(they cannot be inside it) and the rest are evaluated with one :func:`implicit_homogeneous` call per
superquadric kind. The result equals the dense ``world_implicit`` test; far obstacles cost one
entry of a distance matrix per point.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import torch

from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric, pack
from sqmanip.geometry.raycast import bound_box, bound_radius
from sqmanip.geometry.superquadric import implicit_homogeneous

from .types import Environment

SUPPORT = "support"
MAX_POINTS = 1 << 23
"""Largest number of (part, gripper point) distances formed at once by :func:`check_collisions`."""


@dataclasses.dataclass(frozen=True)
class CollisionScene:
    """Everything a gripper must not touch, packed once per planning call.

    ``labels[g]`` names obstacle group ``g`` (``"support"``, ``"box:i"``, ``"object:i"``,
    ``"target"``); a group holds one or more superquadric parts (``groups (M,)``), or the plane.
    """

    params: torch.Tensor
    """(M, 9) packed part parameters."""
    poses: torch.Tensor
    """(M, 4, 4) part-to-world."""
    kinds: torch.Tensor
    """(M,) superquadric kind per part."""
    groups: torch.Tensor
    """(M,) index into ``labels`` per part."""
    centers: torch.Tensor
    """(M, 3) bounding-sphere centres (part origins)."""
    radii: torch.Tensor
    """(M,) bounding-sphere radii (closed-form bound of :mod:`geometry.raycast`)."""
    half_extents: torch.Tensor
    """(M, 3) object-frame box ``|x| <= h`` holding each part (the sphere's for bent parts)."""
    labels: tuple[str, ...]
    plane_normal: torch.Tensor | None = None
    """(3,) unit up normal, or None."""
    plane_offset: float = 0.0
    plane_group: int = -1
    clearance: float = 0.0

    @property
    def n_groups(self) -> int:
        return len(self.labels)


def build_scene(
    environment: Environment,
    obstacles: Sequence[Sequence[Superquadric]] = (),
    target: Sequence[Superquadric] | None = None,
    *,
    clearance: float = 0.0,
    dtype: torch.dtype = torch.float32,
) -> CollisionScene:
    """Collect the support plane, ``environment.boxes``, ``obstacles`` + ``environment.objects``
    and optionally the ``target`` parts into one :class:`CollisionScene`.

    Labels: ``"support"``, ``"box:<i>"`` (index into ``environment.boxes``), ``"object:<i>"``
    (index into ``list(obstacles) + list(environment.objects)``), ``"target"``.
    """
    labels: list[str] = []
    parts: list[Superquadric] = []
    groups: list[int] = []
    plane_group = -1
    if environment.support_normal is not None:
        plane_group = len(labels)
        labels.append(SUPPORT)
    for i, box in enumerate(environment.boxes):
        groups.append(len(labels))
        labels.append(f"box:{i}")
        parts.append(box)
    for i, obj in enumerate([*obstacles, *environment.objects]):
        if len(obj) == 0:
            continue
        g = len(labels)
        labels.append(f"object:{i}")
        for p in obj:
            if not isinstance(p, Superquadric):
                raise ValidationError(
                    f"obstacles[{i}] must hold Superquadric parts, got {type(p).__name__}"
                )
            parts.append(p)
            groups.append(g)
    if target:
        g = len(labels)
        labels.append("target")
        parts.extend(target)
        groups.extend([g] * len(target))
    packed = pack(parts, dtype=dtype)
    radii = torch.zeros(len(parts), dtype=dtype)
    half = torch.zeros(len(parts), 3, dtype=dtype)
    for kind in torch.unique(packed.kinds).tolist():
        sel = packed.kinds == kind
        radii[sel] = bound_radius(packed.params[sel], int(kind))
        half[sel] = bound_box(packed.params[sel], int(kind))
    bent = packed.params[:, 6].abs() > 0  # bending leaves the box; its sphere bounds it
    half = torch.where(bent.unsqueeze(-1), radii.unsqueeze(-1).expand_as(half), half)
    normal = None
    if environment.support_normal is not None:
        normal = torch.as_tensor(environment.support_normal, dtype=dtype)
    return CollisionScene(
        params=packed.params,
        poses=packed.poses,
        kinds=packed.kinds,
        groups=torch.as_tensor(groups, dtype=torch.long),
        centers=packed.poses[:, :3, 3].clone(),
        radii=radii,
        half_extents=half,
        labels=tuple(labels),
        plane_normal=normal,
        plane_offset=float(environment.support_offset),
        plane_group=plane_group,
        clearance=float(clearance),
    )


@dataclasses.dataclass(frozen=True)
class CollisionResult:
    """Per-candidate outcome of :func:`check_collisions`."""

    collides: torch.Tensor
    """(K,) bool, True when any obstacle is hit."""
    obstacle: torch.Tensor
    """(K,) long index into ``labels`` of the obstacle hit deepest (parts before the plane); -1 free."""
    per_obstacle: torch.Tensor
    """(K, G) bool, candidate ``k`` touches obstacle group ``g`` (used by C.3.13)."""
    min_value: torch.Tensor
    """(K, G) ``min_j S_g(x_j)`` per group (the plane: signed distance - clearance + 1, so ``< 1``
    means contact everywhere); ``+inf`` where culled or absent."""
    labels: tuple[str, ...]

    def obstacle_labels(self) -> list[str | None]:
        """Label of the obstacle hit per candidate (None when free)."""
        return [self.labels[i] if i >= 0 else None for i in self.obstacle.tolist()]


def check_collisions(scene: CollisionScene, points: torch.Tensor) -> CollisionResult:
    """Does each posed gripper hit the scene? ``points (K, P, 3)`` world-frame gripper points.

    Implements ``1(min_{i,j} S_i(T_gr,k x_gr,j) <= 1)`` (C.3.12) per candidate ``k`` and obstacle
    group ``i``, with the support plane tested by signed distance.
    """
    pts = torch.as_tensor(points)
    if pts.ndim != 3 or pts.shape[-1] != 3:
        raise ValidationError(f"points must have shape (K, P, 3), got {tuple(pts.shape)}")
    pts = pts.to(scene.params.dtype)
    K, P = pts.shape[:2]
    G = scene.n_groups
    values = torch.full((K, G), float("inf"), dtype=pts.dtype)
    if K > 0 and P > 0:
        if scene.plane_normal is not None:
            sd = pts @ scene.plane_normal + scene.plane_offset  # (K, P)
            values[:, scene.plane_group] = sd.amin(-1) - scene.clearance + 1.0
        M = scene.params.shape[0]
        if M > 0:
            # bound memory: at most ~MAX_POINTS (point, part) distances per slice
            step = max(1, MAX_POINTS // (M * P))
            for s in range(0, K, step):
                values[s : s + step] = _part_values(scene, pts[s : s + step], values[s : s + step])
    hit = values < 1.0
    collides = hit.any(-1)
    # deepest part hit first (smallest S); the plane only when no part is hit
    part_vals = values.clone()
    if scene.plane_group >= 0:
        part_vals[:, scene.plane_group] = float("inf")
    best_part = part_vals.argmin(-1) if G > 0 else torch.zeros(K, dtype=torch.long)
    part_hit = (
        part_vals.gather(-1, best_part.unsqueeze(-1)).squeeze(-1) < 1.0
        if G > 0
        else torch.zeros(K, dtype=torch.bool)
    )
    obstacle = torch.full((K,), -1, dtype=torch.long)
    if scene.plane_group >= 0:
        obstacle = torch.where(hit[:, scene.plane_group], scene.plane_group, obstacle)
    obstacle = torch.where(part_hit, best_part, obstacle)
    return CollisionResult(collides, obstacle, hit, values, scene.labels)


def _part_values(scene: CollisionScene, pts: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """``min_j S_m(x_kj)`` for every (candidate k, part m), reduced into ``values (K, G)``.

    Culling in two cheap steps before the implicit function: a point must lie in a part's
    bounding sphere (one distance matrix, a GEMM) and then in its object-frame bounding box.
    """
    K, P = pts.shape[:2]
    flat = pts.reshape(K * P, 3)
    near = torch.cdist(flat, scene.centers) <= scene.radii.unsqueeze(0) * 1.001 + 1e-6  # (KP, M)
    j_idx, m_idx = near.nonzero(as_tuple=True)
    if j_idx.numel() == 0:
        return values
    R, t = scene.poses[:, :3, :3], scene.poses[:, :3, 3]
    local = torch.einsum("ti,tij->tj", flat[j_idx] - t[m_idx], R[m_idx])  # R^T (x - t)
    inbox = (local.abs() <= scene.half_extents[m_idx]).all(-1)
    j_idx, m_idx, x = j_idx[inbox], m_idx[inbox], local[inbox]
    if j_idx.numel() == 0:
        return values
    kinds = scene.kinds[m_idx]
    vals = torch.empty(m_idx.numel(), dtype=pts.dtype)
    for kind in torch.unique(kinds).tolist():
        sel = (kinds == kind).nonzero().squeeze(-1)
        prm = scene.params[m_idx[sel]]  # (T_k, 9)
        vals[sel] = implicit_homogeneous(x[sel].unsqueeze(-2), prm, int(kind)).squeeze(-1)
    k_idx = torch.div(j_idx, P, rounding_mode="floor")
    out = values.reshape(-1)
    out.scatter_reduce_(0, k_idx * scene.n_groups + scene.groups[m_idx], vals, reduce="amin")
    return out.reshape(values.shape)


def pose_collisions(
    scene: CollisionScene, poses: torch.Tensor | np.ndarray, gripper_pts: np.ndarray
) -> CollisionResult:
    """:func:`check_collisions` for gripper-frame points ``(P, 3)`` placed at ``poses (K, 4, 4)``."""
    from .gripper import transform_gripper_points

    poses_t = torch.as_tensor(np.asarray(poses) if not torch.is_tensor(poses) else poses)
    world = transform_gripper_points(poses_t.to(scene.params.dtype), gripper_pts)
    return check_collisions(scene, world)
