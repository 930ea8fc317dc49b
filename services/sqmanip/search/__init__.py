"""Shelf search domain core (Ch. 5): the existence function f, the graspability function g, their
dynamics, the search-for-grasp objective and the sampling MPC. No transport code."""

from .actions import (
    ActionSampler,
    GraspSource,
    KinematicPushDynamics,
    PickAndPlace,
    Push,
    PushDynamics,
    SQPDNetDynamics,
    apply_actions,
)
from .config import SearchConfig
from .existence import ExistenceModel, depth_condition, existence_reference
from .graspability import GraspabilityModel, target_grasps
from .mpc import Decision, GraspCheck, SearchPlanner
from .objective import FGEvaluator, Maps, objective_value, sequence_cost
from .shelf import Obstacles, PoseGrid, SceneState, ShelfSpec, TargetSpec, make_pose_grid

__all__ = [
    "ActionSampler",
    "Decision",
    "ExistenceModel",
    "FGEvaluator",
    "GraspCheck",
    "GraspSource",
    "GraspabilityModel",
    "KinematicPushDynamics",
    "Maps",
    "Obstacles",
    "PickAndPlace",
    "PoseGrid",
    "Push",
    "PushDynamics",
    "SQPDNetDynamics",
    "SceneState",
    "SearchConfig",
    "SearchPlanner",
    "ShelfSpec",
    "TargetSpec",
    "apply_actions",
    "depth_condition",
    "existence_reference",
    "make_pose_grid",
    "objective_value",
    "sequence_cost",
    "target_grasps",
]
