"""What the simulated robot can execute, asked of an in-process simulator without moving it.

The planner's graspability ``g`` (C.3) checks the afterimage of the gripper and links 6-7 over a
30 cm approach; the simulator (``Simulator.grasp``) also solves the IK of its pre-grasp, grasp
and lift poses from its home configuration and checks the whole arm against the shelf and the
objects. :class:`SimGraspCheck` asks the simulator those same questions so that the grasps the
search counts (``g(x*)``), and the scenarios it is given (5.5.1: discarded when the target cannot
be grasped because of the shelf), agree with what the robot will do.
"""

from __future__ import annotations

import numpy as np

from sqmanip.sim import GRIPPER_MAX_WIDTH, Simulator


class SimGraspCheck:
    """:class:`~sqmanip.search.mpc.GraspCheck` with an in-process :class:`Simulator`: the checks
    ``Simulator.grasp`` makes before it moves, without moving.

    For a planner grasp pose (converted by :func:`sim_tool_pose`): IK of the pre-grasp pose
    (``approach_distance`` back along z, seeded at home), the grasp pose (seeded at the
    pre-grasp solution) and the lift pose, each with the simulator's kinematics but only its
    two deterministic seeds (the seed, then the ready pose: the simulator tries these first and
    lands on the same joint angles; a pose only its random restarts reach is rejected); then the
    collision queries of ``Simulator.grasp``: pre-grasp and grasp configurations against the
    static bodies (and the objects, with ``objects=True``), the lift configuration and the
    joint path from home to the pre-grasp configuration against the static bodies. The
    ``objects=False`` answers depend on the pose only and are memoised."""

    def __init__(self, sim: Simulator, width: float = GRIPPER_MAX_WIDTH) -> None:
        self.sim, self.width = sim, float(width)
        self._arm: dict[bytes, bool] = {}

    def _ik(self, T: np.ndarray, seed: np.ndarray) -> np.ndarray | None:
        res = self.sim.kin.ik(T, seed, restarts=2, rng=np.random.default_rng(0))
        return res.q if res.success else None

    def _one(self, pose: np.ndarray, objects: bool) -> bool:
        from sqmanip.sim.actions import lifted, offset_along_z

        sim, w = self.sim, self.width
        a = sim.config.approach_distance
        home = sim.home
        q_pre = self._ik(offset_along_z(pose, -a), home)
        if q_pre is None:
            return False
        q_grasp = self._ik(pose, q_pre)
        if q_grasp is None:
            return False
        q_lift = self._ik(lifted(pose, a), q_grasp)
        if q_lift is None:
            return False
        if sim._collisions(q_pre, w, objects=objects) or sim._collisions(
            q_grasp, w, objects=objects
        ):
            return False
        if sim._collisions(q_lift, 0.0):
            return False
        for s in np.linspace(0, 1, 10)[1:-1]:
            if sim._collisions(home + s * (q_pre - home), w):
                return False
        return True

    def __call__(self, poses: np.ndarray, objects: bool) -> np.ndarray:
        from sqmanip.grasping.reachability import sim_tool_pose

        T = sim_tool_pose(np.asarray(poses, np.float64).reshape(-1, 4, 4))
        out = np.zeros(len(T), dtype=bool)
        for k, pose in enumerate(T):
            if objects:
                out[k] = self._one(pose, True)
                continue
            key = np.round(pose, 4).tobytes()
            if key not in self._arm:
                if len(self._arm) > 65536:
                    self._arm.clear()
                self._arm[key] = self._one(pose, False)
            out[k] = self._arm[key]
        return out
