"""Simulator constants and configuration: world layout, physics, camera defaults.

World frame (REP 103: x forward, z up, gravity -z). The table top is the plane ``z = 0``; the
Panda base stands on a 0.10 m pedestal at ``(0, 0, 0.10)``, behind the table edge (the floor is
``TABLE_FLOOR_DEPTH`` below the table top), so the whole
0.512 x 0.512 x 0.192 m workspace of Ch. 4.5, centred at ``(0.45, 0, 0)`` (x in [0.194, 0.706],
y in [-0.256, 0.256], z in [0, 0.192]), is reachable with the push orientation of Fig. 4.6 at
every yaw (checked with the pinocchio IK; the 0.10 m base height keeps the near edge and far
corners inside the Panda's reach).

The shelf scene (Ch. 5.5, Appendix C.3) uses the same robot placement with the floor at
``z = 0`` and a five-box shelf whose opening faces the robot (-x).
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

ROBOT_BASE_POSITION = (0.0, 0.0, 0.10)
"""Panda base (``panda_link0``) in the world (m)."""

WORKSPACE_CENTER = (0.45, 0.0)
"""Workspace centre on the table top (m)."""
WORKSPACE_SIZE = (0.512, 0.512, 0.192)
"""Workspace extent x, y, z (m), Ch. 4.5."""
TABLE_SIZE = (0.80, 0.80, 0.05)
"""Table box (m); its top face is at ``z = 0``, centred 0.1 m beyond the workspace centre in x.
Its side edges (``|y| = 0.40``) are 14 cm past the push workspace, near enough for pushes to
carry a large flat box over them ("grasping large", 4.6.3); with a 1 m wide table no push could."""

TABLE_FLOOR_DEPTH = 0.72
"""The tabletop world's floor lies this far below the table top (a standard table height). The
camera sees it past the table's edges: without it nothing comes back there, and an object
overhanging an edge has no free-space evidence beyond its end (perception fits it too long)."""

GRIPPER_MAX_WIDTH = 0.08
"""Panda gripper maximum opening (m): each finger joint 0..0.04."""

# Instance-segmentation labels for pixels that are not objects (objects are 0, 1, 2, ...).
LABEL_BACKGROUND = -1
LABEL_STATIC = -2
"""Table, shelf, floor."""
LABEL_ROBOT = -3
"""The Panda and the pedestal it stands on."""

# Panda joint velocity limits (rad/s) from the URDF; motions use a fraction of them.
ARM_VELOCITY_LIMITS = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])
ARM_FORCE_LIMITS = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])

HOME_TABLETOP = np.array([0.0, -0.4687, 0.0, -2.0074, 0.0, 1.5387, 0.785398])
"""Arm configuration that holds the wrist camera 0.72 m above the workspace centre (0.45, 0),
looking straight down (the observation pose)."""
HOME_SHELF = np.array([1.4, -1.2, 0.0, -2.8, 0.0, 1.8, 0.785398])
"""Arm tucked up and swung to +y so that it hides nothing from the shelf camera."""


@dataclasses.dataclass(frozen=True)
class ShelfGeometry:
    """Five-box shelf (Appendix C.3): bottom, top, back, left and right boards.

    The opening faces -x (the robot). ``front_x`` is the x of the opening, ``bottom_z`` the
    height of the bottom board's top face (the surface objects stand on).
    """

    front_x: float = 0.50
    depth: float = 0.36
    inner_width: float = 0.70
    inner_height: float = 0.40
    bottom_z: float = 0.20
    thickness: float = 0.02

    def boxes(self) -> list[tuple[str, tuple[float, float, float], tuple[float, float, float]]]:
        """``(name, half_extents, centre)`` of the five boards in the world frame."""
        t, d, w, h = self.thickness, self.depth, self.inner_width, self.inner_height
        cx = self.front_x + d / 2
        z0 = self.bottom_z
        return [
            ("shelf_bottom", (d / 2, w / 2 + t, t / 2), (cx, 0.0, z0 - t / 2)),
            ("shelf_top", (d / 2, w / 2 + t, t / 2), (cx, 0.0, z0 + h + t / 2)),
            (
                "shelf_back",
                (t / 2, w / 2 + t, h / 2 + t),
                (self.front_x + d + t / 2, 0.0, z0 + h / 2),
            ),
            ("shelf_left", (d / 2, t / 2, h / 2), (cx, w / 2 + t / 2, z0 + h / 2)),
            ("shelf_right", (d / 2, t / 2, h / 2), (cx, -w / 2 - t / 2, z0 + h / 2)),
        ]

    def inner_bounds(self) -> np.ndarray:
        """``(2, 3)`` lower/upper corners of the free space inside the shelf."""
        return np.array(
            [
                [self.front_x, -self.inner_width / 2, self.bottom_z],
                [
                    self.front_x + self.depth,
                    self.inner_width / 2,
                    self.bottom_z + self.inner_height,
                ],
            ]
        )


@dataclasses.dataclass(frozen=True)
class SimConfig:
    """Physics and motion settings. Fixed time step and solver iterations make runs repeatable."""

    time_step: float = 1.0 / 240.0
    solver_iterations: int = 50
    gravity: float = -9.81
    speed_scale: float = 0.5
    """Fraction of the joint velocity limits used by free-space motions."""
    push_speed: float = 0.10
    """Tool speed along a push (m/s): slow, for quasi-static object motion (Ch. 4.5)."""
    push_via_points: int = 10
    push_approach_step: float = 0.02
    """Spacing (m) of the IK'd tool poses on the straight lines from the pre-push pose to the
    start and from the end to the post-push pose (shelf pushes)."""
    push_transit_speed: float = 0.20
    """Tool speed (m/s) on those two lines."""
    push_transit: Literal["move", "teleport"] = "move"
    """How a push gets from home to the pre-push pose above its start and back: ``move`` drives
    the arm (about 7 of a push's 9 s of simulated time); ``teleport`` sets the joints (the path
    is collision-checked either way), then lets the objects come to rest. The descent, the push
    and the lift are simulated alike, so the objects end where ``move`` leaves them; the pushing
    data generator uses ``teleport`` (about 3x fewer physics steps per tuple)."""
    approach_distance: float = 0.10
    """Pre-grasp offset back along the gripper z axis and lift height after closing (m)."""
    grasp_via_distance: float = 0.30
    """When the free-space line to a pre-grasp pose collides, the grasp may go to the tool this
    far back along its approach axis first and move in along it (the 30 cm approach of C.3);
    0 (or at most ``approach_distance``): the direct line only."""
    grasp_ik_seeds: int = 13
    """More IK seeds a grasp plan tries after home and the ready configuration (the IK's first
    random restart, then fixed offsets from home drawn once; 0: home only): a pose deep in a
    shelf has several IK solutions and often only some keep the elbow off the boards."""
    hold_time: float = 1.0
    """Time the lifted object must stay in the hand for a successful grasp (s)."""
    grip_force: float = 40.0
    """Finger motor force (N)."""
    settle_time: float = 1.0
    """Maximum time to let dropped objects settle (s)."""
    point_noise_std: float = 0.001
    """Std. dev. of the point-cloud noise magnitude (m), Appendix A.1."""
    collision_margin: float = 0.002
    """Configurations closer than this to the table/shelf count as colliding (m)."""
    shelf: ShelfGeometry = dataclasses.field(default_factory=ShelfGeometry)
