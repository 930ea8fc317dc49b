"""PyBullet Franka Panda simulator: tabletop and shelf scenes, cameras, push/grasp/pick-and-place.

Domain API (in-process; the gRPC servicer wraps it): :class:`Simulator`, the scene specs
:class:`SceneSpec` / :class:`ObjectSpec`, and the result types in :mod:`.actions`.
"""

from .actions import ActionResult, ObjectState, Observation, SimState
from .camera import Intrinsics
from .config import (
    GRIPPER_MAX_WIDTH,
    LABEL_BACKGROUND,
    LABEL_ROBOT,
    LABEL_STATIC,
    WORKSPACE_CENTER,
    WORKSPACE_SIZE,
    ShelfGeometry,
    SimConfig,
)
from .kinematics import PandaKinematics
from .scene import ObjectSpec, SceneSpec
from .simulator import Simulator, workspace_bounds
