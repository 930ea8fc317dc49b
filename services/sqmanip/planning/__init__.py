"""Pushing manipulation planning (Ch. 4.4.2, 4.7.3, Appendices B.4, B.5): sampling-based MPC over a
pluggable pushing dynamics model, and the task costs (moving, singulation, grasping, interactive
moving). Pure Python domain package; the gRPC servicer and the episode runner wrap
:class:`PushMPC`.
"""

from .config import GraspCostSpec, MPCConfig, SamplerSpec, TableSpec
from .costs import (
    GraspFeasibility,
    PackedScene,
    edge_grasp_candidates,
    grasping_cost,
    gripper_part_values,
    interactive_moving_cost,
    moving_cost,
    objects_off_table,
    rotation_distance,
    singulation_cost,
    table_contacts,
)
from .mpc import (
    ActionSampler,
    CandidateSampler,
    Dynamics,
    PlanResult,
    PushMPC,
    draw_uniform_per_object,
    map_actions,
    predict_scenes,
    pusher_frames,
    rollout,
    table_workspace,
)
from .tasks import (
    GraspingTask,
    InteractiveMovingTask,
    MovingTask,
    SingulationTask,
    Task,
    validate_task,
)

__all__ = [
    "ActionSampler",
    "Dynamics",
    "GraspCostSpec",
    "GraspFeasibility",
    "GraspingTask",
    "InteractiveMovingTask",
    "MPCConfig",
    "MovingTask",
    "PackedScene",
    "PlanResult",
    "PushMPC",
    "SamplerSpec",
    "SingulationTask",
    "TableSpec",
    "Task",
    "edge_grasp_candidates",
    "grasping_cost",
    "gripper_part_values",
    "interactive_moving_cost",
    "map_actions",
    "moving_cost",
    "objects_off_table",
    "predict_scenes",
    "pusher_frames",
    "CandidateSampler",
    "draw_uniform_per_object",
    "table_workspace",
    "rollout",
    "rotation_distance",
    "singulation_cost",
    "table_contacts",
    "validate_task",
]
