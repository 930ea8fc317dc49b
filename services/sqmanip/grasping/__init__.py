"""Grasp planning on recognized superquadric objects (Ch. 3.4, 3.6.3, B.5, C.3).

Pure Python domain package: antipodal (Algorithm 1) and rule-based candidates, implicit-function
collision checks of the open gripper, pluggable kinematic feasibility, top-down and
uncertainty-aware scores. The gRPC server wraps :class:`GraspPlanner`.

:class:`PandaIKReachability` (the simulator's pinocchio IK as the planner's kinematic feasibility)
and :func:`sim_tool_pose` are imported lazily: they pull in pinocchio and ``sqmanip.sim``.
"""

from .antipodal import AntipodalPairs, poses_about_axis, sample_antipodal_pairs
from .collision import CollisionResult, CollisionScene, build_scene, check_collisions
from .config import (
    PANDA_HAND,
    PANDA_HAND_URDF,
    GraspConfig,
    Reachability,
    WorkspaceReachability,
    always_reachable,
)
from .gripper import gripper_boxes, gripper_points, transform_gripper_points
from .planner import (
    Feasibility,
    GraspPlanner,
    PlanResult,
    PlanStats,
    rank_order,
    top_down_score,
    uncertainty,
)
from .rule_based import rule_based_candidates
from .types import Candidates, Environment, Grasp, GripperSpec, PlanOptions, RuleOptions

__all__ = [
    "PANDA_HAND",
    "PANDA_HAND_URDF",
    "AntipodalPairs",
    "Candidates",
    "CollisionResult",
    "CollisionScene",
    "Environment",
    "Feasibility",
    "Grasp",
    "GraspConfig",
    "GraspPlanner",
    "GripperSpec",
    "PlanOptions",
    "PlanResult",
    "PandaIKReachability",
    "PlanStats",
    "Reachability",
    "RuleOptions",
    "WorkspaceReachability",
    "always_reachable",
    "build_scene",
    "check_collisions",
    "gripper_boxes",
    "gripper_points",
    "poses_about_axis",
    "rank_order",
    "rule_based_candidates",
    "sample_antipodal_pairs",
    "sim_tool_pose",
    "top_down_score",
    "transform_gripper_points",
    "uncertainty",
]


_LAZY = {"PandaIKReachability", "sim_tool_pose"}


def __getattr__(name: str):
    if name in _LAZY:
        from . import reachability

        return getattr(reachability, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
