"""Configuration of the grasp planner: the default gripper, options, and kinematic feasibility.

Kinematic feasibility is a constructor argument of :class:`~sqmanip.grasping.planner.GraspPlanner`:
any callable ``is_reachable(poses (K, 4, 4)) -> bool (K,)`` (numpy in, numpy out). The Panda IK of
``sqmanip.sim.kinematics`` plugs in there; until then (and for tests) :class:`WorkspaceReachability`
is a *crude stand-in*: it only checks that the flange lies inside a spherical shell around the
Panda's shoulder, which rejects far-away and too-close grasps but knows nothing about joint limits
or orientation (a real IK rejects more).
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import numpy as np

from sqmanip.errors import ValidationError

from .types import GripperSpec, PlanOptions

PANDA_HAND = GripperSpec()
"""The Franka Emika hand (8 cm stroke), the gripper of every experiment in the thesis."""

PANDA_HAND_URDF = GripperSpec(
    finger_length=0.0462,
    finger_width=0.021,
    finger_thickness=0.0264,
    tip_offset=0.0072,
    palm_size=(0.0632, 0.2044, 0.066),
)
"""The same hand measured on the collision meshes the simulator uses (``franka_panda/panda.urdf``
of ``pybullet_data``: ``finger.obj`` 2.1 x 2.64 x 5.38 cm from the finger joint 5.84 cm below the
flange, ``hand.obj`` 6.32 x 20.44 cm reaching 6.6 cm below the flange), in the frame of the
simulator's ``panda_grasptarget`` (10.5 cm below the flange):

- fingertips 7.2 mm past the TCP (not 9.4); the hand body starts 3.9 cm behind the TCP (not
  4.46: the visible finger length is 4.62 cm), so ``flange_offset`` is exactly 0.105 and
  :func:`~sqmanip.grasping.reachability.sim_tool_pose` is the identity;
- each finger is 2.64 cm thick behind its pad at its root (1.4 cm near the tip; one box holds
  the thicker root, conservatively), 2.1 cm wide.

Grasps planned with :data:`PANDA_HAND` (1.2 cm thin fingers, 5 mm shallower hand) pass the
planner's check and are then refused by the simulator where a neighbouring part is that close.
"""


class Reachability(Protocol):
    """Kinematic feasibility of gripper poses: ``(K, 4, 4) -> bool (K,)``."""

    def __call__(self, poses: np.ndarray) -> np.ndarray: ...


@dataclasses.dataclass(frozen=True)
class WorkspaceReachability:
    """Default feasibility check: the flange within ``[min_reach, max_reach]`` of the shoulder.

    A workspace-radius approximation of the Panda (855 mm reach from the shoulder joint at
    0.333 m above the base), documented as such: it ignores joint limits and orientation. The
    flange is ``flange_offset`` behind the TCP along the approach axis, so approaching from far
    side of the object costs reach as on the real arm.
    """

    base: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Robot base position in the world (m); the base frame is assumed aligned with the world."""
    shoulder_height: float = 0.333
    max_reach: float = 0.855
    min_reach: float = 0.15
    flange_offset: float = PANDA_HAND.flange_offset

    def __post_init__(self) -> None:
        if not (0 <= self.min_reach < self.max_reach):
            raise ValidationError(
                f"need 0 <= min_reach < max_reach, got {self.min_reach}, {self.max_reach}"
            )

    def __call__(self, poses: np.ndarray) -> np.ndarray:
        T = np.asarray(poses, dtype=np.float64)
        if T.ndim != 3 or T.shape[-2:] != (4, 4):
            raise ValidationError(f"poses must have shape (K, 4, 4), got {T.shape}")
        flange = T[:, :3, 3] - self.flange_offset * T[:, :3, 2]
        shoulder = np.asarray(self.base, dtype=np.float64) + np.array(
            [0.0, 0.0, self.shoulder_height]
        )
        d = np.linalg.norm(flange - shoulder, axis=-1)
        return (d <= self.max_reach) & (d >= self.min_reach)


def always_reachable(poses: np.ndarray) -> np.ndarray:
    """Feasibility check that accepts every pose (for geometry-only studies)."""
    return np.ones(np.asarray(poses).shape[0], dtype=bool)


@dataclasses.dataclass(frozen=True)
class GraspConfig:
    """Defaults a grasp service starts with (requests may override options and gripper)."""

    gripper: GripperSpec = PANDA_HAND
    options: PlanOptions = dataclasses.field(default_factory=PlanOptions)
    workspace: WorkspaceReachability = dataclasses.field(default_factory=WorkspaceReachability)
    torch_threads: int | None = None
    """``torch.set_num_threads`` for the service process; None leaves torch's default."""
