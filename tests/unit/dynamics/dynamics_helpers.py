"""Shared helpers for the pushing-dynamics tests: random scenes in float64 (imported directly)."""

from __future__ import annotations

import math

import numpy as np
import torch
from sqmanip.geometry.transforms import so3_exp


def random_scene(
    seed: int, n: int, *, tilt: float = 0.6, dtype: torch.dtype = torch.float64
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``n`` objects with general SE(3) poses (tilted up to ``tilt`` rad, never upside down),
    mixed box / cylinder / ellipsoid-like shapes; returns ``poses, params, kinds``."""
    rng = np.random.default_rng(seed)
    yaw = torch.as_tensor(rng.uniform(-math.pi, math.pi, n))
    axis = torch.as_tensor(rng.normal(size=(n, 3)))
    axis[:, 2] = 0
    axis = axis / axis.norm(dim=-1, keepdim=True)
    tilt_angle = torch.as_tensor(rng.uniform(0, tilt, n)).unsqueeze(-1)
    R = so3_exp(axis * tilt_angle) @ so3_exp(torch.stack([0 * yaw, 0 * yaw, yaw], -1))
    poses = torch.eye(4, dtype=torch.float64).repeat(n, 1, 1)
    poses[:, :3, :3] = R
    poses[:, :3, 3] = torch.as_tensor(rng.uniform([-0.2, -0.2, 0.0], [0.2, 0.2, 0.1], (n, 3)))
    params = torch.zeros(n, 9, dtype=torch.float64)
    params[:, :3] = torch.as_tensor(rng.uniform(0.02, 0.06, (n, 3)))
    e = rng.choice([0.2, 1.0], size=(n, 2))
    params[:, 3:5] = torch.as_tensor(e)
    kinds = torch.zeros(n, dtype=torch.long)
    return poses.to(dtype), params.to(dtype), kinds


def random_actions(seed: int, k: int, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    rng = np.random.default_rng(seed + 1000)
    p = rng.uniform([-0.25, -0.25, 0.01], [0.25, 0.25, 0.1], (k, 3))
    ang = rng.uniform(-math.pi, math.pi, k)
    v = np.stack([0.1 * np.cos(ang), 0.1 * np.sin(ang), np.zeros(k)], -1)
    return torch.as_tensor(np.concatenate([p, v], -1), dtype=dtype)
