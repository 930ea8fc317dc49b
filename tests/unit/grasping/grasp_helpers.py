"""Shared scene builders for the grasping tests (imported by module name, like the other packages)."""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial.transform import Rotation
from sqmanip.geometry import Superquadric, pack, world_implicit
from sqmanip.grasping import GripperSpec, gripper_points, transform_gripper_points


def pose(
    x: float, y: float, z: float, euler: tuple[float, float, float] | None = None
) -> np.ndarray:
    """A 4 x 4 pose at ``(x, y, z)`` rotated by extrinsic xyz Euler angles (rad)."""
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    if euler is not None:
        T[:3, :3] = Rotation.from_euler("xyz", euler).as_matrix()
    return T


def box(half: tuple[float, float, float], at: np.ndarray, e: float = 0.2) -> Superquadric:
    return Superquadric(half, (e, e), at)


def lying_cylinder(radius: float = 0.025, half_length: float = 0.08, yaw: float = 0.3):
    """A cylinder (e1 = 0.2, e2 = 1) lying on the table z = 0 with its axis horizontal."""
    return Superquadric(
        (radius, radius, half_length), (0.2, 1.0), pose(0.5, 0.05, radius, (np.pi / 2, 0.0, yaw))
    )


def dense_min_implicit(
    grasp_poses: np.ndarray, parts: list[Superquadric], spec: GripperSpec, n_points: int = 512
) -> np.ndarray:
    """Reference collision values: ``min_j min_i S_i`` over all gripper points, no culling, (K,)."""
    pts = gripper_points(spec, n_points)
    world = transform_gripper_points(torch.as_tensor(grasp_poses, dtype=torch.float64), pts)
    packed = pack(parts, dtype=torch.float64)
    S = world_implicit(world, packed.params, packed.poses, packed.kinds)  # (K, M, P)
    return S.amin(-1).amin(-1).numpy()
