"""The PyBullet Panda: joint bookkeeping, position-controlled joint-space motions, gripper.

Motions interpolate in joint space (smoothstep profile) and stream position targets every
physics step, then let the controller settle; the simulation is stepped by the caller's
``step`` so that every motion is physical (objects are pushed, never teleported).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pybullet as p

from .config import ARM_FORCE_LIMITS, ARM_VELOCITY_LIMITS, GRIPPER_MAX_WIDTH, SimConfig
from .kinematics import PANDA_URDF

ARM_INDICES = list(range(7))
FINGER_INDICES = [9, 10]
HAND_LINK = 8
TCP_LINK = 11
FINGER_DYNAMICS = {"lateralFriction": 1.5, "spinningFriction": 0.01}
"""``changeDynamics`` settings of the two finger links (over the URDF's contact values)."""


def joint_motion_steps(
    dq: np.ndarray, speed: float, config: SimConfig, min_time: float = 0.15
) -> int:
    """Physics steps of a :meth:`PandaRobot.move_joints` motion by ``dq (7,)``: the slowest
    joint at ``speed`` x its velocity limit, x 1.5 (the smoothstep peak velocity is 1.5x the
    mean), at least ``min_time``."""
    T = max(float(np.max(np.abs(dq) / (speed * ARM_VELOCITY_LIMITS))) * 1.5, min_time)
    return max(int(np.ceil(T / config.time_step)), 1)


def smoothstep(s: np.ndarray | float) -> np.ndarray | float:
    """The ``3 s^2 - 2 s^3`` profile of joint-space motions, ``s`` in [0, 1]."""
    return s * s * (3 - 2 * s)


class PandaRobot:
    """One Panda body in a PyBullet client (fixed base), driven by position control."""

    def __init__(self, client: int, base_position, config: SimConfig, step: Callable[[], None]):
        self.client = client
        self.config = config
        self._step = step
        self.body = p.loadURDF(
            PANDA_URDF,
            list(base_position),
            [0, 0, 0, 1],
            useFixedBase=True,
            flags=p.URDF_USE_INERTIA_FROM_FILE,
            physicsClientId=client,
        )
        names = [
            p.getJointInfo(self.body, j, physicsClientId=client)[1].decode()
            for j in range(p.getNumJoints(self.body, physicsClientId=client))
        ]
        expected = {0: "panda_joint1", 9: "panda_finger_joint1", 10: "panda_finger_joint2"}
        for idx, name in expected.items():
            if names[idx] != name:
                raise RuntimeError(f"unexpected Panda URDF joint order: {names}")
        for j in FINGER_INDICES:
            p.changeDynamics(self.body, j, **FINGER_DYNAMICS, physicsClientId=client)
        self.links = list(range(-1, p.getNumJoints(self.body, physicsClientId=client)))

    # --- state --------------------------------------------------------------------------------

    def q(self) -> np.ndarray:
        st = p.getJointStates(self.body, ARM_INDICES, physicsClientId=self.client)
        return np.array([s[0] for s in st])

    def finger_positions(self) -> np.ndarray:
        st = p.getJointStates(self.body, FINGER_INDICES, physicsClientId=self.client)
        return np.array([s[0] for s in st])

    def gripper_width(self) -> float:
        return float(self.finger_positions().sum())

    def link_pose(self, link: int) -> np.ndarray:
        ls = p.getLinkState(
            self.body, link, computeForwardKinematics=True, physicsClientId=self.client
        )
        T = np.eye(4)
        T[:3, :3] = np.asarray(p.getMatrixFromQuaternion(ls[5])).reshape(3, 3)
        T[:3, 3] = ls[4]
        return T

    def reset_q(self, q: np.ndarray, width: float) -> None:
        """Teleport (no physics) to ``q`` with the gripper at ``width``; used by ``reset`` only."""
        for j, v in zip(ARM_INDICES, q, strict=True):
            p.resetJointState(self.body, j, float(v), 0.0, physicsClientId=self.client)
        for j in FINGER_INDICES:
            p.resetJointState(self.body, j, width / 2, 0.0, physicsClientId=self.client)
        self.command_arm(q)
        self.command_gripper(width)

    def snapshot(self) -> list[tuple[float, float]]:
        js = p.getJointStates(self.body, ARM_INDICES + FINGER_INDICES, physicsClientId=self.client)
        return [(s[0], s[1]) for s in js]

    def restore(self, snap: list[tuple[float, float]]) -> None:
        for j, (pos, vel) in zip(ARM_INDICES + FINGER_INDICES, snap, strict=True):
            p.resetJointState(self.body, j, pos, vel, physicsClientId=self.client)

    def pose_config(self, q: np.ndarray, width: float) -> None:
        """Place the links at ``q`` (kinematic, for collision queries; restore afterwards)."""
        for j, v in zip(ARM_INDICES, q, strict=True):
            p.resetJointState(self.body, j, float(v), 0.0, physicsClientId=self.client)
        for j in FINGER_INDICES:
            p.resetJointState(self.body, j, width / 2, 0.0, physicsClientId=self.client)

    # --- control ------------------------------------------------------------------------------

    def command_arm(self, q: np.ndarray) -> None:
        p.setJointMotorControlArray(
            self.body,
            ARM_INDICES,
            p.POSITION_CONTROL,
            targetPositions=[float(x) for x in q],
            forces=ARM_FORCE_LIMITS.tolist(),
            positionGains=[0.3] * 7,
            velocityGains=[1.0] * 7,
            physicsClientId=self.client,
        )

    def command_gripper(self, width: float, force: float | None = None) -> None:
        w = float(np.clip(width, 0.0, GRIPPER_MAX_WIDTH)) / 2
        f = self.config.grip_force if force is None else force
        p.setJointMotorControlArray(
            self.body,
            FINGER_INDICES,
            p.POSITION_CONTROL,
            targetPositions=[w, w],
            forces=[f, f],
            positionGains=[0.2, 0.2],
            physicsClientId=self.client,
        )

    def move_joints(
        self, q_goal: np.ndarray, speed: float | None = None, min_time: float = 0.15
    ) -> None:
        """Drive the arm from its current configuration to ``q_goal`` along a joint-space line.

        Duration follows the slowest joint at ``speed`` x its velocity limit (smoothstep peak
        velocity is 1.5x the mean), then up to 0.25 s of settling until every joint is within
        2 mrad.
        """
        cfg = self.config
        speed = cfg.speed_scale if speed is None else speed
        q0 = self.q()
        dq = np.asarray(q_goal, np.float64) - q0
        n = joint_motion_steps(dq, speed, cfg, min_time)
        for i in range(1, n + 1):
            self.command_arm(q0 + smoothstep(i / n) * dq)
            self._step()
        self.settle(q_goal)

    def settle(self, q_goal: np.ndarray, tol: float = 2e-3, max_time: float = 0.25) -> None:
        self.command_arm(q_goal)
        for _ in range(int(max_time / self.config.time_step)):
            if np.max(np.abs(self.q() - q_goal)) < tol:
                return
            self._step()

    def follow(self, qs: list[np.ndarray], durations: list[float]) -> None:
        """Track a sequence of joint waypoints with a linear profile between them (quasi-static
        Cartesian paths such as the 10 via points of a push)."""
        dt = self.config.time_step
        q_prev = self.q()
        for q_next, dur in zip(qs, durations, strict=True):
            n = max(int(np.ceil(dur / dt)), 1)
            for i in range(1, n + 1):
                self.command_arm(q_prev + (i / n) * (q_next - q_prev))
                self._step()
            q_prev = q_next
        self.settle(qs[-1])

    def actuate_gripper(self, width: float, max_time: float = 0.6) -> None:
        """Open/close to ``width`` and step until the fingers stop (contact) or reach it."""
        self.command_gripper(width)
        dt = self.config.time_step
        last = self.finger_positions()
        for i in range(int(max_time / dt)):
            self._step()
            if i % 12 == 11:
                cur = self.finger_positions()
                if np.max(np.abs(cur - last)) < 2e-4:
                    return
                last = cur
