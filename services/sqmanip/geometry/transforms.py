"""Rigid transforms: SO(3), SE(3) as ``(..., 4, 4)`` matrices, quaternions in (x, y, z, w) order,
the planar SE(2) transforms of (4.3.2) and the pose decomposition ``T = C U`` (Appendix B.1.1).

Conventions:
- quaternions are Hamilton, ``(x, y, z, w)`` (scalar last, as ROS and ``scipy``), and rotate
  column vectors actively: ``p' = R(q) p``. Functions returning quaternions pick ``w >= 0``;
  functions taking quaternions normalise them (a zero quaternion reads as the identity);
- an SE(3) matrix ``T = [[R, t], [0, 1]]`` maps object to world coordinates: ``x_w = R x_o + t``;
- every function broadcasts over leading batch dimensions ``(...)`` and works in float32 and
  float64; none produces NaN for finite input, and all are differentiable (autograd).
"""

from __future__ import annotations

import math

import torch

from .numerics import as_tensor

__all__ = [
    "check_se3",
    "decompose_pose",
    "is_se2",
    "matrix_to_quat",
    "pose_from_pq",
    "pose_to_pq",
    "quat_conjugate",
    "quat_multiply",
    "quat_normalize",
    "quat_to_matrix",
    "rot_z",
    "se2_matrix",
    "se2_params",
    "se2_transform_action",
    "se3_compose",
    "se3_inverse",
    "skew",
    "so3_exp",
    "so3_log",
    "transform_points",
    "transform_vectors",
]


# --- validation -----------------------------------------------------------------------------------


def check_se3(T: torch.Tensor, name: str = "T") -> None:
    if T.ndim < 2 or T.shape[-2:] != (4, 4):
        raise ValueError(f"{name} must have shape (..., 4, 4), got {tuple(T.shape)}")


def _check_last(x: torch.Tensor, n: int, name: str) -> None:
    if x.ndim < 1 or x.shape[-1] != n:
        raise ValueError(f"{name} must have shape (..., {n}), got {tuple(x.shape)}")


def _check_so3(R: torch.Tensor, name: str = "R") -> None:
    if R.ndim < 2 or R.shape[-2:] != (3, 3):
        raise ValueError(f"{name} must have shape (..., 3, 3), got {tuple(R.shape)}")


def _eps(dtype: torch.dtype) -> float:
    return float(torch.finfo(dtype).eps)


# --- SE(3) ----------------------------------------------------------------------------------------


def se3_inverse(T: torch.Tensor) -> torch.Tensor:
    """Inverse of rigid transforms ``(..., 4, 4)`` using ``R^T`` (no general matrix inversion)."""
    check_se3(T)
    R, t = T[..., :3, :3], T[..., :3, 3:]
    Rt = R.transpose(-1, -2)
    out = torch.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3:] = -Rt @ t
    out[..., 3, 3] = 1.0
    return out


def se3_compose(A: torch.Tensor, B: torch.Tensor) -> torch.Tensor:
    """``A B`` for rigid transforms ``(..., 4, 4)`` (batch dimensions broadcast)."""
    check_se3(A, "A")
    check_se3(B, "B")
    return A @ B


def transform_points(T: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Apply ``T (..., 4, 4)`` to ``points (..., N, 3)``: ``R p + t``, returns ``(..., N, 3)``."""
    check_se3(T)
    if points.ndim < 2 or points.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., N, 3), got {tuple(points.shape)}")
    R, t = T[..., :3, :3], T[..., :3, 3]
    return points @ R.transpose(-1, -2) + t.unsqueeze(-2)


def transform_vectors(T: torch.Tensor, vectors: torch.Tensor) -> torch.Tensor:
    """Rotate direction vectors ``(..., N, 3)`` by the rotation part of ``T (..., 4, 4)``."""
    check_se3(T)
    if vectors.ndim < 2 or vectors.shape[-1] != 3:
        raise ValueError(f"vectors must have shape (..., N, 3), got {tuple(vectors.shape)}")
    return vectors @ T[..., :3, :3].transpose(-1, -2)


# --- quaternions (x, y, z, w) ---------------------------------------------------------------------


def quat_normalize(q: torch.Tensor) -> torch.Tensor:
    """Unit quaternions ``(..., 4)``; a zero quaternion becomes the identity ``(0, 0, 0, 1)``."""
    _check_last(q, 4, "quaternion")
    n = torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    ident = torch.zeros_like(q)
    ident[..., 3] = 1.0
    return torch.where(n > _eps(q.dtype) ** 2, q / n.clamp_min(_eps(q.dtype) ** 2), ident)


def quat_conjugate(q: torch.Tensor) -> torch.Tensor:
    """``(-x, -y, -z, w)``: the inverse rotation of a unit quaternion ``(..., 4)``."""
    _check_last(q, 4, "quaternion")
    return torch.cat([-q[..., :3], q[..., 3:]], dim=-1)


def quat_multiply(q1: torch.Tensor, q2: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``q1 q2`` (xyzw, ``R(q1 q2) = R(q1) R(q2)``), shapes broadcast to (..., 4)."""
    _check_last(q1, 4, "q1")
    _check_last(q2, 4, "q2")
    x1, y1, z1, w1 = q1.unbind(-1)
    x2, y2, z2, w2 = q2.unbind(-1)
    return torch.stack(
        [
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        ],
        dim=-1,
    )


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices ``(..., 3, 3)`` from quaternions ``(..., 4)`` in (x, y, z, w) order.

    The quaternion is normalised first (any non-zero scale gives the same rotation); a zero
    quaternion gives the identity.
    """
    x, y, z, w = quat_normalize(q).unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        torch.stack([1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)], -1),
        torch.stack([2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)], -1),
        torch.stack([2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)], -1),
    ]
    return torch.stack(rows, dim=-2)


def matrix_to_quat(R: torch.Tensor) -> torch.Tensor:
    """Unit quaternions ``(..., 4)`` (x, y, z, w; ``w >= 0``) from rotation matrices ``(..., 3, 3)``.

    Shepperd's method: of the four algebraically equal formulas, each dividing by one of
    ``|w|, |x|, |y|, |z|``, use the one with the largest divisor (>= 1/2), so the result stays
    accurate near 180 degrees where ``w -> 0``. Slightly non-orthonormal input is tolerated.
    """
    _check_so3(R)
    m00, m01, m02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    m10, m11, m12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    m20, m21, m22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    # 4 q_i^2 for i = x, y, z, w.
    four_sq = torch.stack(
        [
            1 + m00 - m11 - m22,
            1 - m00 + m11 - m22,
            1 - m00 - m11 + m22,
            1 + m00 + m11 + m22,
        ],
        dim=-1,
    )
    # Row i holds 4 q_i (x, y, z, w).
    sx, sy, sz = m21 - m12, m02 - m20, m10 - m01
    pxy, pxz, pyz = m01 + m10, m02 + m20, m12 + m21
    cand = torch.stack(
        [
            torch.stack([four_sq[..., 0], pxy, pxz, sx], -1),
            torch.stack([pxy, four_sq[..., 1], pyz, sy], -1),
            torch.stack([pxz, pyz, four_sq[..., 2], sz], -1),
            torch.stack([sx, sy, sz, four_sq[..., 3]], -1),
        ],
        dim=-2,
    )
    best = four_sq.argmax(dim=-1, keepdim=True)  # (..., 1)
    row = torch.gather(cand, -2, best.unsqueeze(-1).expand(*best.shape[:-1], 1, 4)).squeeze(-2)
    # row = 4 q_i q; normalising removes the 4 q_i factor (q_i > 0 by construction of the row).
    q = row / torch.linalg.vector_norm(row, dim=-1, keepdim=True).clamp_min(_eps(R.dtype))
    return torch.where(q[..., 3:] < 0, -q, q)


# --- SO(3) exponential and logarithm --------------------------------------------------------------


def skew(v: torch.Tensor) -> torch.Tensor:
    """The bracket ``[v]`` of (B.1.1): ``(..., 3) -> (..., 3, 3)`` with ``[v] u = v x u``."""
    _check_last(v, 3, "v")
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack(
        [torch.stack([o, -z, y], -1), torch.stack([z, o, -x], -1), torch.stack([-y, x, o], -1)],
        dim=-2,
    )


def so3_exp(v: torch.Tensor) -> torch.Tensor:
    """Rotation matrices ``exp([v])`` from rotation vectors ``v = axis * angle`` ``(..., 3)``.

    Rodrigues' formula ``I + A [v] + B [v]^2`` with ``A = sin(t)/t``, ``B = (1 - cos t)/t^2``;
    Taylor series for small ``t`` keep values and gradients finite at ``v = 0``.
    """
    _check_last(v, 3, "rotation vector")
    t2 = (v * v).sum(-1)[..., None, None]
    small = t2 < 1e-6 if v.dtype == torch.float32 else t2 < 1e-10
    t2s = torch.where(small, torch.ones_like(t2), t2)
    t = torch.sqrt(t2s)
    A = torch.where(small, 1 - t2 / 6 + t2 * t2 / 120, torch.sin(t) / t)
    B = torch.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - torch.cos(t)) / t2s)
    K = skew(v)
    eye = torch.eye(3, dtype=v.dtype, device=v.device).expand_as(K)
    return eye + A * K + B * (K @ K)


def so3_log(R: torch.Tensor) -> torch.Tensor:
    """Rotation vectors ``(..., 3)`` (angle in ``[0, pi]``) of rotation matrices ``(..., 3, 3)``.

    Goes through :func:`matrix_to_quat` (robust near 180 degrees): ``angle = 2 atan2(|v|, w)``
    and ``axis = v / |v|`` for the quaternion ``(v, w)`` with ``w >= 0``.
    """
    q = matrix_to_quat(R)
    v, w = q[..., :3], q[..., 3:]
    s2 = (v * v).sum(-1, keepdim=True)
    small = s2 < 1e-8 if R.dtype == torch.float32 else s2 < 1e-16
    s = torch.sqrt(torch.where(small, torch.ones_like(s2), s2))
    # angle / |v| -> 2 / w as |v| -> 0 (w -> 1 there, so no division by a small number).
    scale = torch.where(small, 2.0 / w.clamp_min(0.5), 2.0 * torch.atan2(s, w) / s)
    return v * scale


# --- poses from position + quaternion ---------------------------------------------------------------


def pose_from_pq(position: torch.Tensor, quaternion: torch.Tensor) -> torch.Tensor:
    """SE(3) matrices ``(..., 4, 4)`` from positions ``(..., 3)`` and xyzw quaternions ``(..., 4)``."""
    _check_last(position, 3, "position")
    _check_last(quaternion, 4, "quaternion")
    R = quat_to_matrix(quaternion)
    batch = torch.broadcast_shapes(position.shape[:-1], R.shape[:-2])
    dtype = torch.promote_types(position.dtype, R.dtype)
    T = torch.zeros(*batch, 4, 4, dtype=dtype, device=R.device)
    T[..., :3, :3] = R
    T[..., :3, 3] = position
    T[..., 3, 3] = 1.0
    return T


def pose_to_pq(T: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Positions ``(..., 3)`` and xyzw quaternions ``(..., 4)`` (``w >= 0``) of SE(3) ``(..., 4, 4)``."""
    check_se3(T)
    return T[..., :3, 3], matrix_to_quat(T[..., :3, :3])


# --- planar SE(2) transforms (4.3.2) --------------------------------------------------------------


def rot_z(theta) -> torch.Tensor:
    """``Rot(z, theta)``: rotations about the world z axis, ``(...) -> (..., 3, 3)``."""
    theta = as_tensor(theta)
    c, s = torch.cos(theta), torch.sin(theta)
    o, i = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack(
        [torch.stack([c, -s, o], -1), torch.stack([s, c, o], -1), torch.stack([o, o, i], -1)],
        dim=-2,
    )


def se2_matrix(theta, tx, ty) -> torch.Tensor:
    """``C = [[Rot(z, theta), (tx, ty, 0)], [0, 1]]`` of (4.3.2), shapes broadcast to ``(..., 4, 4)``.

    Scalars and tensors are accepted; the result is float64 if any input is float64, else float32.
    """
    theta, tx, ty = (as_tensor(v) for v in (theta, tx, ty))
    dtype = torch.promote_types(torch.promote_types(theta.dtype, tx.dtype), ty.dtype)
    theta, tx, ty = torch.broadcast_tensors(theta.to(dtype), tx.to(dtype), ty.to(dtype))
    C = torch.zeros(*theta.shape, 4, 4, dtype=dtype, device=theta.device)
    C[..., :3, :3] = rot_z(theta)
    C[..., 0, 3] = tx
    C[..., 1, 3] = ty
    C[..., 3, 3] = 1.0
    return C


def se2_params(C: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(theta, tx, ty)`` of transforms of the form (4.3.2) ``(..., 4, 4)``; theta in (-pi, pi]."""
    check_se3(C, "C")
    return torch.atan2(C[..., 1, 0], C[..., 0, 0]), C[..., 0, 3], C[..., 1, 3]


def is_se2(C: torch.Tensor, atol: float = 1e-6) -> torch.Tensor:
    """Whether each ``C (..., 4, 4)`` has the form (4.3.2) within ``atol``: boolean ``(...)``."""
    check_se3(C, "C")
    theta, tx, ty = se2_params(C)
    ref = se2_matrix(theta, tx, ty).to(C.dtype)
    return ((C - ref).abs() <= atol).flatten(-2).all(-1)


def se2_transform_action(
    C: torch.Tensor, p: torch.Tensor, v: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Transform a push action ``(p, v)`` by ``C`` as in Definition 4.1 (4.3.1).

    ``p -> Rot(z, theta) p + t_xy`` (a point), ``v -> Rot(z, theta) v`` (a displacement).
    ``C (..., 4, 4)``, ``p, v (..., 3)``; returns two ``(..., 3)`` tensors. Works for any rigid
    ``C``; the equivariance of Definition 4.1 holds for ``C`` of the form (4.3.2).
    """
    check_se3(C, "C")
    _check_last(p, 3, "p")
    _check_last(v, 3, "v")
    R, t = C[..., :3, :3], C[..., :3, 3]
    return (R @ p.unsqueeze(-1)).squeeze(-1) + t, (R @ v.unsqueeze(-1)).squeeze(-1)


# --- pose decomposition T = C U (Appendix B.1.1) ----------------------------------------------------


def decompose_pose(T: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Decompose object poses ``T = C U`` (Appendix B.1.1): ``(..., 4, 4) -> (C, U)``.

    ``C = T M1 M2`` is the pose projected onto the table: ``M1`` (B.1.1) rotates the object frame
    by the smallest angle ``phi`` that aligns its z axis ``z`` with the world z axis ``z0``
    (axis ``w = z x z0 / |z x z0|``), and ``M2`` (B.1.2) moves it down to ``z = 0``. ``C`` has the
    form (B.1.3) exactly (its rotation is rebuilt as ``Rot(z, theta)`` and its height set to 0);
    ``U = C^{-1} T``, so ``T = C U`` holds to rounding.

    Degenerate cases: if ``z`` is parallel to ``z0`` then ``M1 = I``; if it is anti-parallel
    (``phi = pi``, ``w`` undefined) the object's own x axis (horizontal there) is used as ``w``.
    Both choices commute with rotations about z, so property (iii) of B.1.1 holds everywhere:
    ``decompose_pose(C_a T) = (C_a C, U)`` for any ``C_a`` of the form (4.3.2).
    """
    check_se3(T)
    R = T[..., :3, :3]
    z = R[..., :, 2]
    cos_phi = z[..., 2]
    # z x z0 with z0 = (0, 0, 1).
    cross = torch.stack([z[..., 1], -z[..., 0], torch.zeros_like(cos_phi)], -1)
    sin_phi = torch.linalg.vector_norm(cross, dim=-1)
    tol = math.sqrt(_eps(T.dtype))
    flipped = (sin_phi < tol) & (cos_phi < 0)
    aligned = (sin_phi < tol) & (cos_phi >= 0)
    safe_sin = torch.where(sin_phi < tol, torch.ones_like(sin_phi), sin_phi)
    phi = torch.atan2(sin_phi, cos_phi)
    axis = torch.where(flipped[..., None], R[..., :, 0], cross / safe_sin[..., None])
    angle = torch.where(flipped, torch.full_like(phi, math.pi), phi)
    angle = torch.where(aligned, torch.zeros_like(phi), angle)
    # M1 applied on the right rotates about R^{-1} w in the object frame, which equals rotating
    # about w in the world frame on the left: R exp([R^T w] phi) = exp([w] phi) R.
    R_c = so3_exp(axis * angle[..., None]) @ R
    theta = torch.atan2(R_c[..., 1, 0], R_c[..., 0, 0])
    C = se2_matrix(theta, T[..., 0, 3], T[..., 1, 3]).to(T.dtype)
    U = se3_inverse(C) @ T
    return C, U
