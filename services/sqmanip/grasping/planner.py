"""The grasp planner: candidates, scores, collision and reachability filtering (3.4.2, 3.6.3, B.5).

``GraspPlanner.plan`` runs Algorithm 1 for one target object (a list of deformable superquadric
parts) and returns feasible grasps, best first:

1. candidates: antipodal pairs x 12 approach directions (:mod:`.antipodal`, 3.4), or the
   rule-based poses of B.5 / C.3 (:mod:`.rule_based`); widths over the opening are dropped;
2. scores: ``c = -z^T z_t`` (3.4.2, prefer top-down), or with observed points
   ``c = -z^T z_t - beta u`` (3.6.3), ``u`` the mean uncertainty of the two contacts;
3. order: by score, ties (e.g. many exactly top-down grasps) broken uniformly at random from
   ``options.seed``, as 3.4.2 picks randomly among equal maxima;
4. feasibility, lazily in that order, ``chunk_size`` candidates at a time until ``max_results``
   are found: collisions of the open gripper with the support plane, shelf boxes, the other
   objects and the target itself (3.7.15, B.5.12, :mod:`.collision`; one batched call), then
   kinematic feasibility (the constructor's ``reachability``, per pose) of the collision-free.
   The gripper in that check is the hand as it will be executed: opened to
   ``options.opening(width)`` (not to its full stroke), its boxes but the pads inflated by
   ``options.collision_margin``, swept back ``options.approach_distance`` along the approach.

Deterministic given ``options.seed``.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Sequence

import numpy as np
import torch

from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric, sample_parts

from .antipodal import AntipodalPairs, poses_about_axis, sample_antipodal_pairs
from .collision import CollisionResult, CollisionScene, build_scene, check_collisions
from .config import PANDA_HAND, Reachability, WorkspaceReachability
from .gripper import (
    gripper_points,
    gripper_points_and_sides,
    open_gripper_points,
    transform_gripper_points,
)
from .rule_based import rule_based_candidates
from .types import Candidates, Environment, Grasp, GripperSpec, PlanOptions, parts_tuple

log = logging.getLogger(__name__)

SCORE_DECIMALS = 6
"""Scores are compared at this many decimals, so float noise does not break 3.4.2's ties."""


# --- scores ---------------------------------------------------------------------------------------


def top_down_score(poses: torch.Tensor, z_t: np.ndarray | torch.Tensor) -> torch.Tensor:
    """``c = -z^T z_t`` (3.4.2) for ``poses (K, 4, 4)``: 1 straight down, -1 from below, ``(K,)``."""
    z_t = torch.as_tensor(np.asarray(z_t), dtype=poses.dtype)
    return -(poses[:, :3, 2] @ z_t)


def nearest_distances(queries: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Distance from each query ``(Q, 3)`` to its nearest observed point ``(N, 3)``: ``(Q,)``."""
    from scipy.spatial import cKDTree

    if len(queries) == 0:
        return np.zeros(0)
    d, _ = cKDTree(observed).query(queries, k=1)
    return np.asarray(d, dtype=np.float64)


def uncertainty(
    surface_points: np.ndarray, queries: np.ndarray, observed: np.ndarray
) -> np.ndarray:
    """Shape-uncertainty scores in [0, 1] of ``queries (..., 3)`` (3.6.3).

    The distance to the nearest observed point, linearly rescaled so the surface samples
    ``surface_points (S, 3)`` nearest to / farthest from the observation score 0 / 1 (queries
    outside that range are clipped). All surface points equally near gives 0 everywhere.
    """
    q = np.asarray(queries, dtype=np.float64)
    d_s = nearest_distances(np.asarray(surface_points, dtype=np.float64), observed)
    d_q = nearest_distances(q.reshape(-1, 3), observed).reshape(q.shape[:-1])
    if d_s.size == 0:
        return np.zeros(q.shape[:-1])
    lo, hi = float(d_s.min()), float(d_s.max())
    if hi - lo <= 1e-12:
        return np.zeros(q.shape[:-1])
    return np.clip((d_q - lo) / (hi - lo), 0.0, 1.0)


def rank_order(scores: torch.Tensor, seed: int) -> torch.Tensor:
    """Indices sorting ``scores (K,)`` descending, ties in a seeded uniformly random order."""
    g = torch.Generator().manual_seed(int(seed))
    perm = torch.randperm(scores.shape[0], generator=g)
    keys = torch.round(scores[perm].to(torch.float64), decimals=SCORE_DECIMALS)
    return perm[torch.argsort(-keys, stable=True)]


# --- results --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class PlanStats:
    """What happened in one :meth:`GraspPlanner.plan_detailed` call."""

    n_samples: int = 0
    """Surface samples ``x1`` on the target (antipodal method)."""
    n_pairs: int = 0
    """Antipodal pairs found (before the width limit)."""
    n_candidates: int = 0
    """Grasp poses generated (pairs within the opening x approach directions)."""
    n_checked: int = 0
    n_unreachable: int = 0
    n_colliding: int = 0
    collisions: dict[str, int] = dataclasses.field(default_factory=dict)
    """Colliding candidates per obstacle label (the deepest hit)."""
    timings_ms: dict[str, float] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class PlanResult:
    grasps: list[Grasp]
    stats: PlanStats


@dataclasses.dataclass(frozen=True)
class Feasibility:
    """Outcome of :meth:`GraspPlanner.check_poses` for ``K`` poses."""

    feasible: np.ndarray
    """(K,) bool: reachable and collision-free (B.5.14)."""
    reachable: np.ndarray
    """(K,) bool."""
    collision: CollisionResult


# --- planner --------------------------------------------------------------------------------------


def _check_points(name: str, value) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[-1] != 3 or arr.shape[0] == 0:
        raise ValidationError(f"{name} must have shape (N, 3) with N >= 1, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValidationError(f"{name} must be finite")
    return arr


class GraspPlanner:
    """Plans parallel-jaw grasps on recognized superquadric objects (Ch. 3.4).

    ``reachability`` is any ``(K, 4, 4) -> bool (K,)`` callable (the Panda IK in the stack); the
    default :class:`~sqmanip.grasping.config.WorkspaceReachability` is a workspace-radius stand-in.
    ``dtype`` is the precision of the collision checks (antipodal geometry runs in float64).
    """

    def __init__(
        self,
        reachability: Reachability | None = None,
        *,
        gripper: GripperSpec = PANDA_HAND,
        options: PlanOptions | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        self.reachability: Reachability = reachability or WorkspaceReachability()
        self.gripper = gripper
        self.options = options or PlanOptions()
        self.dtype = dtype

    # -- public API --------------------------------------------------------------------------------

    def plan(
        self,
        target: Sequence[Superquadric],
        obstacles: Sequence[Sequence[Superquadric]] = (),
        environment: Environment | None = None,
        gripper: GripperSpec | None = None,
        options: PlanOptions | None = None,
        observed_points: np.ndarray | None = None,
    ) -> list[Grasp]:
        """Feasible grasps on ``target`` (its parts), best first; empty when none is feasible.

        ``obstacles`` are the other recognized objects (parts each); ``observed_points (N, 3)``
        is the target's observed cloud, required by ``options.score == "uncertainty"``.
        """
        return self.plan_detailed(
            target, obstacles, environment, gripper, options, observed_points
        ).grasps

    def plan_detailed(
        self,
        target: Sequence[Superquadric],
        obstacles: Sequence[Sequence[Superquadric]] = (),
        environment: Environment | None = None,
        gripper: GripperSpec | None = None,
        options: PlanOptions | None = None,
        observed_points: np.ndarray | None = None,
    ) -> PlanResult:
        """:meth:`plan` plus counts and per-stage timings (:class:`PlanStats`)."""
        t0 = time.perf_counter()
        target = parts_tuple("target", target)
        if len(target) == 0:
            raise ValidationError("target must have at least one part, got 0")
        obstacles = tuple(parts_tuple(f"obstacles[{i}]", o) for i, o in enumerate(obstacles))
        env = environment or Environment()
        grip = gripper or self.gripper
        opt = options or self.options
        observed = None
        if opt.score == "uncertainty":
            if observed_points is None:
                raise ValidationError(
                    "observed_points (N, 3) is required when options.score == 'uncertainty'"
                )
            observed = _check_points("observed_points", observed_points)
        timings: dict[str, float] = {}

        # 1. candidates
        cands, pairs = self.candidates(target, env, grip, opt)
        t1 = time.perf_counter()
        timings["candidates"] = 1e3 * (t1 - t0)
        # 2. scores
        scores = top_down_score(cands.poses, env.z_t)
        u = None
        if observed is not None and len(cands) > 0:
            if pairs is not None:
                surface = pairs.samples.numpy()
            else:
                surface, _, _ = sample_parts(list(target), opt.n_samples, generator=opt.seed)
            u_c = uncertainty(surface, cands.contacts.numpy(), observed)  # (K, 2)
            u = torch.as_tensor(u_c.mean(-1), dtype=scores.dtype)
            scores = scores - opt.beta * u
        order = rank_order(scores, opt.seed)
        t2 = time.perf_counter()
        timings["score"] = 1e3 * (t2 - t1)
        # 3. feasibility, lazily in score order
        scene = build_scene(
            env,
            obstacles,
            target if opt.check_target else None,
            clearance=opt.support_clearance,
            dtype=self.dtype,
        )
        pts, sides = gripper_points_and_sides(
            grip,
            opt.gripper_points,
            include_wrist=opt.include_wrist,
            approach_distance=opt.approach_distance,
            margin=opt.collision_margin,
        )
        openings = opt.opening(cands.widths, grip.max_opening)
        limit = opt.max_results if opt.max_results is not None else len(cands)
        chosen: list[int] = []
        n_checked = n_unreach = n_coll = 0
        coll_counts: dict[str, int] = {}
        for start in range(0, len(order), opt.chunk_size):
            if len(chosen) >= limit:
                break
            idx = order[start : start + opt.chunk_size]
            n_checked += idx.numel()
            # Collisions first: one batched implicit-function call; IK (per pose) only on the rest.
            res = check_collisions(
                scene,
                open_gripper_points(
                    cands.poses[idx].to(self.dtype), pts, sides, openings[idx], grip.max_opening
                ),
            )
            n_coll += int(res.collides.sum())
            for label in res.obstacle_labels():
                if label is not None:
                    coll_counts[label] = coll_counts.get(label, 0) + 1
            idx = idx[~res.collides]
            if idx.numel() == 0:
                continue
            reach = self._reachable(cands.poses[idx])
            n_unreach += int((~reach).sum())
            chosen.extend(idx[torch.as_tensor(reach)].tolist())
        chosen = chosen[:limit]
        t3 = time.perf_counter()
        timings["feasibility"] = 1e3 * (t3 - t2)
        timings["total"] = 1e3 * (t3 - t0)

        grasps = [
            Grasp(
                pose=cands.poses[i].numpy().astype(np.float64),
                width=float(cands.widths[i]),
                score=float(scores[i]),
                contacts=cands.contacts[i].numpy().astype(np.float64),
                uncertainty=None if u is None else float(u[i]),
            )
            for i in chosen
        ]
        stats = PlanStats(
            n_samples=0 if pairs is None else int(pairs.samples.shape[0]),
            n_pairs=0 if pairs is None else len(pairs),
            n_candidates=len(cands),
            n_checked=n_checked,
            n_unreachable=n_unreach,
            n_colliding=n_coll,
            collisions=coll_counts,
            timings_ms=timings,
        )
        log.debug(
            "plan: %d parts, %d candidates, %d grasps in %.1f ms",
            len(target),
            len(cands),
            len(grasps),
            timings["total"],
        )
        return PlanResult(grasps, stats)

    def candidates(
        self,
        target: Sequence[Superquadric],
        environment: Environment | None = None,
        gripper: GripperSpec | None = None,
        options: PlanOptions | None = None,
    ) -> tuple[Candidates, AntipodalPairs | None]:
        """All candidates before feasibility checks (and the antipodal pairs they came from)."""
        env = environment or Environment()
        grip = gripper or self.gripper
        opt = options or self.options
        if opt.method == "rule_based":
            rule = opt.rule
            if rule.max_width > grip.max_opening:
                rule = dataclasses.replace(rule, max_width=grip.max_opening)
            return rule_based_candidates(target, up=env.z_t, options=rule), None
        pairs = sample_antipodal_pairs(
            target, opt.n_samples, threshold=opt.antipodal_threshold, generator=opt.seed
        )
        keep = (pairs.width <= grip.max_opening - opt.opening_clearance) & (
            pairs.width >= opt.min_width
        )
        x1, x2 = pairs.x1[keep], pairs.x2[keep]
        if x1.shape[0] == 0:
            return Candidates.empty(), pairs
        A = opt.n_approach
        poses = poses_about_axis(0.5 * (x1 + x2), x2 - x1, env.z_t, A)  # (P, A, 4, 4)
        P = x1.shape[0]
        contacts = torch.stack([x1, x2], 1)  # (P, 2, 3)
        return (
            Candidates(
                poses=poses.reshape(P * A, 4, 4),
                widths=pairs.width[keep].repeat_interleave(A),
                contacts=contacts.repeat_interleave(A, dim=0),
            ),
            pairs,
        )

    def check_poses(
        self,
        poses: np.ndarray | torch.Tensor,
        target: Sequence[Superquadric] | None = None,
        obstacles: Sequence[Sequence[Superquadric]] = (),
        environment: Environment | None = None,
        gripper: GripperSpec | None = None,
        options: PlanOptions | None = None,
    ) -> Feasibility:
        """Reachability and collisions of given gripper ``poses (K, 4, 4)`` (B.5.13, B.5.14).

        The batched graspability test the MPC and the shelf search run on rule-based candidates.
        """
        env = environment or Environment()
        grip = gripper or self.gripper
        opt = options or self.options
        T = torch.as_tensor(np.asarray(poses) if not torch.is_tensor(poses) else poses)
        if T.ndim != 3 or T.shape[-2:] != (4, 4):
            raise ValidationError(f"poses must have shape (K, 4, 4), got {tuple(T.shape)}")
        tgt = parts_tuple("target", target) if target is not None else None
        scene: CollisionScene = build_scene(
            env,
            tuple(parts_tuple(f"obstacles[{i}]", o) for i, o in enumerate(obstacles)),
            tgt if opt.check_target else None,
            clearance=opt.support_clearance,
            dtype=self.dtype,
        )
        pts = gripper_points(
            grip,
            opt.gripper_points,
            include_wrist=opt.include_wrist,
            approach_distance=opt.approach_distance,
            margin=opt.collision_margin,
        )
        res = check_collisions(scene, transform_gripper_points(T.to(self.dtype), pts))
        reach = self._reachable(T)
        feasible = reach & ~res.collides.numpy()
        return Feasibility(feasible, reach, res)

    # -- helpers -----------------------------------------------------------------------------------

    def _reachable(self, poses: torch.Tensor) -> np.ndarray:
        if poses.shape[0] == 0:
            return np.zeros(0, dtype=bool)
        out = np.asarray(self.reachability(poses.detach().cpu().numpy().astype(np.float64)))
        if out.shape != (poses.shape[0],):
            raise ValueError(f"reachability must return shape ({poses.shape[0]},), got {out.shape}")
        return out.astype(bool)
