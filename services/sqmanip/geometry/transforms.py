"""Rigid transforms: SE(3) as ``(..., 4, 4)`` matrices, quaternions in (x, y, z, w) order."""

from __future__ import annotations

import torch


def check_se3(T: torch.Tensor, name: str = "T") -> None:
    if T.shape[-2:] != (4, 4):
        raise ValueError(f"{name} must have shape (..., 4, 4), got {tuple(T.shape)}")


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


def transform_points(T: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Apply ``T (..., 4, 4)`` to ``points (..., N, 3)``: ``R p + t``, returns ``(..., N, 3)``."""
    check_se3(T)
    if points.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., N, 3), got {tuple(points.shape)}")
    R, t = T[..., :3, :3], T[..., :3, 3]
    return points @ R.transpose(-1, -2) + t.unsqueeze(-2)
