"""Action and state value types, argument validation, and the tool poses of the actions.

All results are frozen dataclasses holding numpy arrays; lengths in metres, angles in radians,
quaternions (x, y, z, w), poses 4 x 4 object-to-world. A thin gRPC servicer converts them.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import ValidationError
from ..geometry.types import Superquadric
from .camera import Intrinsics
from .config import GRIPPER_MAX_WIDTH


@dataclasses.dataclass(frozen=True)
class ObjectState:
    """Ground truth of one object: id (index in the scene spec), pose and shape."""

    id: int
    name: str
    kind: str
    pose: np.ndarray
    """Object-to-world, 4 x 4."""
    position: np.ndarray
    quaternion: np.ndarray
    """(x, y, z, w)."""
    superquadric: Superquadric | None
    """The spawned (or box/cylinder-equivalent) superquadric at the current pose; None for meshes."""


@dataclasses.dataclass(frozen=True)
class SimState:
    """Everything needed to inspect the simulator between actions."""

    time: float
    """Simulated time since reset (s)."""
    scene_kind: str
    objects: tuple[ObjectState, ...]
    joint_positions: np.ndarray
    """Panda arm joints (7,) (rad)."""
    gripper_width: float
    tcp_pose: np.ndarray
    """Tool centre point (between the fingertips) to world, 4 x 4."""
    held_object: int | None


@dataclasses.dataclass(frozen=True)
class Observation:
    """One camera frame.

    ``depth (H, W)`` float32 metres along the optical axis, 0 where nothing was hit;
    ``rgb (H, W, 3)`` uint8; ``segmentation (H, W)`` int32 with object ids >= 0 and
    ``LABEL_BACKGROUND`` (-1), ``LABEL_STATIC`` (-2: table/shelf), ``LABEL_ROBOT`` (-3);
    ``points (N, 3)`` float64 world-frame back-projection of the valid depth pixels with the
    Appendix A.1 noise, ``point_labels (N,)`` their segmentation ids and ``point_pixels (N,)``
    their flat pixel indices; ``camera_pose`` the optical frame (x right, y down, z forward)
    to world.
    """

    camera: str
    intrinsics: Intrinsics
    camera_pose: np.ndarray
    depth: np.ndarray
    rgb: np.ndarray
    segmentation: np.ndarray
    points: np.ndarray
    point_labels: np.ndarray
    point_pixels: np.ndarray
    objects: tuple[ObjectState, ...]
    time: float

    def point_colors(self) -> np.ndarray:
        """``(N, 3)`` float32 colours in [0, 1] of ``points`` (their pixels in ``rgb``)."""
        return self.rgb.reshape(-1, 3)[self.point_pixels].astype(np.float32) / 255.0


@dataclasses.dataclass(frozen=True)
class ActionResult:
    """Outcome of an executed action (refused actions raise instead)."""

    success: bool
    message: str
    before: SimState
    after: SimState
    held_object: int | None = None
    """The object in the hand at the end (grasp), if any."""
    sim_time: float = 0.0
    """Simulated duration of the action (s)."""


# --- validation -----------------------------------------------------------------------------------


def as_point(value, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,):
        raise ValidationError(f"{name} must have shape (3,), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValidationError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def as_pose(value, name: str) -> np.ndarray:
    T = np.asarray(value, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValidationError(f"{name} must have shape (4, 4), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValidationError(f"{name} must be finite")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0.999:
        raise ValidationError(f"{name} rotation must be orthonormal with det +1")
    if not np.allclose(T[3], [0, 0, 0, 1]):
        raise ValidationError(f"{name} last row must be (0, 0, 0, 1)")
    if np.linalg.norm(T[:3, 3]) > 3.0:
        raise ValidationError(f"{name} position {T[:3, 3].tolist()} is out of workspace (> 3 m)")
    return T


def as_width(value) -> float:
    w = float(value)
    if not np.isfinite(w) or not 0.0 < w <= GRIPPER_MAX_WIDTH + 1e-9:
        raise ValidationError(
            f"width must be in (0, {GRIPPER_MAX_WIDTH}] m (the Panda's opening), got {value}"
        )
    return w


# --- tool poses -----------------------------------------------------------------------------------


def push_tool_rotation(
    v: np.ndarray, yaw_offset: float = 0.0, down: bool = True, upright: bool = False
) -> np.ndarray:
    """Tool orientation of a push (Fig. 4.6): closed gripper, tool z pointing down, tool x along
    the horizontal push direction (the fingers' broad side faces the motion), ``yaw_offset``
    (0 or pi, same finger geometry) chosen by the caller for the joint limits.

    With ``down=False`` (shelf) the tool z points level into the shelf (+x), tool x down (up for
    ``yaw_offset = pi``), so the closing axis (tool y) lies across the shelf along the push. The
    search planner's pusher model pitches this tool 30 deg down (5.4.4); executing that tilt
    here was tried: the refused actions quadrupled (IK flips, collisions; see the issue 10 note).

    With ``upright`` (shelf only) the hand is turned 90 deg about its approach: tool y (the
    closing axis) points up (down for ``yaw_offset = pi``) and tool x along the push, so the
    hand's 20 cm runs vertically and only its 6.3 cm thickness lies across the push. It fits
    where the level hand does not: beside an object 10 cm from a side board, against 15 cm.
    """
    if upright and not down:
        z = np.array([1.0, 0.0, 0.0])
        y = np.array([0.0, 0.0, 1.0]) * (1 if yaw_offset == 0 else -1)
        return np.stack([np.cross(y, z), y, z], axis=1)
    if down:
        d = np.array([v[0], v[1], 0.0])
        yaw = (np.arctan2(d[1], d[0]) if np.linalg.norm(d) > 1e-9 else 0.0) + yaw_offset
        c, s = np.cos(yaw), np.sin(yaw)
        x = np.array([c, s, 0.0])
        z = np.array([0.0, 0.0, -1.0])
    else:
        z = np.array([1.0, 0.0, 0.0])
        x = np.array([0.0, 0.0, -1.0]) * (1 if yaw_offset == 0 else -1)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def tool_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def offset_along_z(T: np.ndarray, d: float) -> np.ndarray:
    """``T`` moved by ``d`` along its own z axis (negative = back along the approach)."""
    out = T.copy()
    out[:3, 3] = T[:3, 3] + d * T[:3, 2]
    return out


def lifted(T: np.ndarray, dz: float) -> np.ndarray:
    out = T.copy()
    out[2, 3] += dz
    return out
