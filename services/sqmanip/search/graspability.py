"""Graspability ``g`` and its dense variant ``g_c,m`` (5.4.1, 5.4.3, Appendix C.3) over ``X``.

Candidate grasps of the target come from the rule-based generator of
:mod:`sqmanip.grasping.rule_based` with the C.3 preset: side grasps pitched 20 deg towards the
floor, antipodal width <= 7.5 cm, approaching into the shelf (+x). A cylinder can be grasped from
any side (5.6.3), so the generator runs on the target turned by a few yaws (``grasp_yaws_deg``)
and ``grasp_heights`` heights each: ``N_gr = 20`` by default (thesis: 10 to 30).

For a grasp ``T_k`` the robot approaches 30 cm along the gripper z axis; the "afterimage" of the
open gripper and links 6-7 over that approach is ``n_gr = 2048`` points
(:func:`sqmanip.grasping.gripper_points` with ``include_wrist`` and ``approach_distance``). With
``n_k(x)`` the number of obstacles (objects and the five shelf boards) entered by the afterimage of
grasp ``k`` for the target at ``x``:

- ``g(x) = g_c(x) = 1(min_k n_k(x) = 0)`` (C.3.11-C.3.12, C.3.14);
- ``g_c,m(x) = 1 - min_k n_k(x)`` (C.3.13, C.3.15): 1, 0, -1, ... used by the objective.

The candidate set is the same for every grid position (only its yaw matters), so the grasps of
pose ``x`` are ``x T_k``; the shelf's contribution ``n_k^shelf(x)`` is computed once and cached,
and per scene only the objects are tested with the culled exact test of
:meth:`sqmanip.search.shelf.Obstacles.hits`.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from sqmanip.geometry.transforms import rot_z
from sqmanip.grasping import PANDA_HAND, GripperSpec, RuleOptions, gripper_points
from sqmanip.grasping.rule_based import rule_based_candidates

from .config import SearchConfig
from .shelf import Obstacles, PoseGrid, SceneState, ShelfSpec, TargetSpec, cluster_points


def target_grasps(
    target: TargetSpec, theta: float, config: SearchConfig, dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """Candidate grasp poses ``(K, 4, 4)`` in the frame of a target at the origin with yaw 0,
    for the target turned by ``theta`` about z (C.3 rule; ``[]`` when none fits the gripper)."""
    opt = RuleOptions(
        top_down=False,
        per_direction=config.grasp_heights,
        max_width=config.grasp_max_width,
        tilt=math.radians(config.grasp_tilt_deg),
        facing=(1.0, 0.0, 0.0),
        facing_angle=math.radians(config.facing_angle_deg),
    )
    yaws = config.grasp_yaws_deg if target.kind == "cylinder" else (0.0,)
    out = []
    Rth = rot_z(torch.tensor(theta, dtype=torch.float64))
    for yaw in yaws:
        R = rot_z(torch.tensor(theta + math.radians(yaw), dtype=torch.float64))
        pose = np.eye(4)
        pose[:3, :3] = R.numpy()
        cand = rule_based_candidates([target.superquadric(pose)], options=opt)
        if len(cand):
            T = cand.poses.clone()
            T[:, :3, :] = Rth.T @ T[:, :3, :]  # into the frame of the target with yaw theta
            out.append(T)
    if not out:
        return torch.zeros(0, 4, 4, dtype=dtype)
    return torch.cat(out).to(dtype)


class GraspabilityModel:
    """``g`` and ``g_c,m`` over a pose grid (C.3), with the shelf part cached."""

    def __init__(
        self,
        shelf: ShelfSpec,
        target: TargetSpec,
        grid: PoseGrid,
        config: SearchConfig | None = None,
        gripper: GripperSpec = PANDA_HAND,
    ) -> None:
        self.shelf, self.target, self.grid = shelf, target, grid
        self.config = cfg = config or SearchConfig()
        self.gripper = gripper
        self.dtype = grid.poses.dtype
        # afterimage of the open gripper + links 6-7 over the 30 cm approach (C.3.11)
        pts = gripper_points(
            gripper,
            cfg.n_gripper_points,
            include_wrist=True,
            approach_distance=cfg.approach_distance,
        )
        self.points, self.point_centers, self.point_radii = cluster_points(pts, 64, self.dtype)
        # candidates per distinct yaw of the grid, in the frame of the target (translation only)
        thetas = torch.unique(grid.theta)
        sets = [target_grasps(target, float(t), cfg, self.dtype) for t in thetas]
        k_max = max((len(s) for s in sets), default=0)
        self.n_candidates = k_max
        self.local_grasps = torch.zeros(len(thetas), k_max, 4, 4, dtype=self.dtype)
        self.local_valid = torch.zeros(len(thetas), k_max, dtype=torch.bool)
        for i, s in enumerate(sets):
            self.local_grasps[i, : len(s)] = s
            self.local_valid[i, : len(s)] = True
            self.local_grasps[i, len(s) :] = torch.eye(4, dtype=self.dtype)
        self._theta_index = torch.searchsorted(thetas, grid.theta)
        shelf_obs = Obstacles.from_parts(shelf.boxes(), self.dtype)
        self.n_shelf = self._counts(shelf_obs, torch.arange(len(grid)))  # (P, K) int

    def grasp_poses(self, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World grasp poses ``(len(idx), K, 4, 4)`` of grid poses ``idx`` and their validity."""
        ti = self._theta_index[idx]
        T = self.grid.poses[idx].unsqueeze(1) @ self.local_grasps[ti]
        return T, self.local_valid[ti]

    def _counts(self, obstacles: Obstacles, idx: torch.Tensor) -> torch.Tensor:
        """``(len(idx), K)`` number of obstacles each candidate's afterimage enters."""
        K = self.n_candidates
        if K == 0 or idx.numel() == 0 or len(obstacles) == 0:
            return torch.zeros(idx.numel(), K, dtype=torch.long)
        T, _ = self.grasp_poses(idx)
        hit = obstacles.hits(self.points, self.point_centers, self.point_radii, T.reshape(-1, 4, 4))
        return hit.sum(-1).reshape(idx.numel(), K)

    def evaluate(
        self, scene: SceneState, mask: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(g, g_m, best)`` over the grid: ``g (P,)`` in {0, 1}, ``g_m (P,)`` in {1, 0, -1, ...}
        (C.3.13) and the index of the grasp with the fewest collisions ``best (P,)`` (-1 if none).

        Only poses in ``mask`` are evaluated (the objective needs ``g`` where ``f = 1``, 5.3);
        elsewhere ``g = 0``, ``g_m = 1 - (N + 5)`` (every obstacle counted) and ``best = -1``.
        """
        P = len(self.grid)
        n_obs = len(scene) + 5
        g_m = torch.full((P,), float(1 - n_obs), dtype=self.dtype)
        best = torch.full((P,), -1, dtype=torch.long)
        m = torch.ones(P, dtype=torch.bool) if mask is None else mask.bool()
        idx = m.nonzero().squeeze(-1)
        if idx.numel() and self.n_candidates:
            n = self.n_shelf[idx] + self._counts(scene.obstacles(), idx)
            _, valid = self.grasp_poses(idx)
            n = torch.where(valid, n, torch.full_like(n, n_obs))
            n_min, k = n.min(-1)
            g_m[idx] = (1 - n_min).to(self.dtype)
            best[idx] = torch.where(n_min < n_obs, k, torch.full_like(k, -1))
        g = (g_m >= 1.0).to(self.dtype)
        return g, g_m, best
