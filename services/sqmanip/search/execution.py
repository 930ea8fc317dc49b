"""What the simulated robot can execute, asked of an in-process simulator without moving it.

The planner's graspability ``g`` (C.3) checks the afterimage of the gripper and links 6-7 over a
30 cm approach; the simulator (``Simulator.grasp``) also solves the IK of its pre-grasp, grasp
and lift poses from its home configuration and checks the whole arm against the shelf and the
objects. :class:`SimGraspCheck` asks the simulator for that same plan so that the grasps the
search counts (``g(x*)``), and the scenarios it is given (5.5.1: discarded when the target cannot
be grasped because of the shelf), agree with what the robot will do.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np

from sqmanip.errors import PreconditionError
from sqmanip.perception.preprocess import voxel_downsample
from sqmanip.sim import GRIPPER_MAX_WIDTH, Simulator
from sqmanip.sim.kinematics import ARM_LINKS, HAND_FRAME
from sqmanip.sim.simulator import grasp_path_samples, joint_path

SWEPT_SPACING = 0.01
"""Spacing (m) of the arm's surface points in :meth:`SimGraspCheck.swept` (one per 1 cm voxel)."""


class SimGraspCheck:
    """:class:`~sqmanip.search.mpc.GraspCheck` with an in-process :class:`Simulator`: its own
    grasp plan (:meth:`Simulator.plan_grasp`: the IK chain from home over its fixed seeds and
    the collision queries of ``Simulator.grasp``), without moving. A grasp passes when the
    simulator would execute it. The ``objects=False`` answers (the arm against the shelf
    only) depend on the pose only and are memoised."""

    def __init__(self, sim: Simulator, width: float = GRIPPER_MAX_WIDTH) -> None:
        self.sim, self.width = sim, float(width)
        self._arm: dict[bytes, bool] = {}
        self.object_index: dict[int, int] = {}
        """Simulator object id -> index in the planner's object list (set by the runner for
        each observation); ids not in it are objects the planner does not know (-1)."""
        self.last_blockers: list[frozenset[int]] = []
        """Per pose of the last ``objects=True`` call: the planner's indices of the objects the
        refused plan hit (empty when it passed or hit only the shelf)."""
        self._swept: dict[bytes, np.ndarray] = {}

    def _one(self, pose: np.ndarray, objects: bool) -> bool:
        try:
            self.sim.plan_grasp(pose, self.width, self.sim.home, objects=objects)
        except PreconditionError as exc:
            if objects:
                self.last_blockers.append(self._blockers(exc))
            return False
        if objects:
            self.last_blockers.append(frozenset())
        return True

    def _blockers(self, exc: PreconditionError) -> frozenset[int]:
        out = set()
        for name in getattr(exc, "bodies", ()):
            if name.startswith("object "):
                out.add(self.object_index.get(int(name.split()[1]), -1))
        return frozenset(out)

    def swept(self, poses: np.ndarray) -> list[np.ndarray]:
        """Per grasp pose ``(K, 4, 4)``: the world points ``(S, 3)`` the arm's surface (links
        1-7 and the hand) passes through inside the shelf on the robot's plan without objects
        (the joint path from home, through the approach start when the plan has one, to the
        pre-grasp, then the approach to the grasp), one per :data:`SWEPT_SPACING` voxel; empty
        when the arm cannot execute the grasp. An object of a predicted scene that enters these
        points blocks the grasp the way the simulator's check would (memoised per pose)."""
        return [_memoised(self._swept, 4096, p, self._swept_one) for p in _tool_poses(poses)]

    def _swept_one(self, pose: np.ndarray) -> np.ndarray:
        sim = self.sim
        try:
            plan = sim.plan_grasp(pose, self.width, sim.home, objects=False)
        except PreconditionError:
            return np.zeros((0, 3))
        stops = [sim.home] + ([plan.via] if plan.via is not None else []) + [plan.pre]
        qs = [plan.pre, plan.grasp, *joint_path(plan.pre, plan.grasp, 4)]
        for a, b in zip(stops[:-1], stops[1:], strict=True):
            qs += joint_path(a, b, grasp_path_samples(a, b))
        links = (*ARM_LINKS, HAND_FRAME)
        pts = np.concatenate([sim.kin.link_points(q, links, SWEPT_SPACING) for q in qs])
        lo, hi = sim.config.shelf.inner_bounds()
        pts = pts[np.all((pts >= lo - 0.01) & (pts <= hi + 0.01), axis=-1)]
        return pts[np.sort(voxel_downsample(pts, SWEPT_SPACING)[0])]

    def __call__(self, poses: np.ndarray, objects: bool) -> np.ndarray:
        T = _tool_poses(poses)
        if objects:
            self.last_blockers = []
            return np.array([self._one(pose, True) for pose in T], dtype=bool)
        arm_only = functools.partial(self._one, objects=False)
        return np.array([_memoised(self._arm, 65536, pose, arm_only) for pose in T], dtype=bool)


def _tool_poses(poses: np.ndarray) -> np.ndarray:
    """The planner's grasp poses ``(K, 4, 4)`` as the simulator's tool poses."""
    from sqmanip.grasping.reachability import sim_tool_pose

    return sim_tool_pose(np.asarray(poses, np.float64).reshape(-1, 4, 4))


def _memoised(cache: dict[bytes, Any], limit: int, pose: np.ndarray, compute: Callable) -> Any:
    """``compute(pose)``, memoised per pose rounded to 0.1 mm; ``cache`` starts over past
    ``limit`` entries."""
    key = np.round(pose, 4).tobytes()
    if key not in cache:
        if len(cache) > limit:
            cache.clear()
        cache[key] = compute(pose)
    return cache[key]
