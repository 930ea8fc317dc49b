from sqmanip.v1 import common_pb2 as _common_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class MovingGoal(_message.Message):
    __slots__ = ("object_id", "goal")
    OBJECT_ID_FIELD_NUMBER: _ClassVar[int]
    GOAL_FIELD_NUMBER: _ClassVar[int]
    object_id: int
    goal: _common_pb2.Pose
    def __init__(self, object_id: _Optional[int] = ..., goal: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ...) -> None: ...

class MovingTask(_message.Message):
    __slots__ = ("goals", "beta")
    GOALS_FIELD_NUMBER: _ClassVar[int]
    BETA_FIELD_NUMBER: _ClassVar[int]
    goals: _containers.RepeatedCompositeFieldContainer[MovingGoal]
    beta: float
    def __init__(self, goals: _Optional[_Iterable[_Union[MovingGoal, _Mapping]]] = ..., beta: _Optional[float] = ...) -> None: ...

class SingulationTask(_message.Message):
    __slots__ = ("tau",)
    TAU_FIELD_NUMBER: _ClassVar[int]
    tau: float
    def __init__(self, tau: _Optional[float] = ...) -> None: ...

class GraspingTask(_message.Message):
    __slots__ = ("target_id",)
    TARGET_ID_FIELD_NUMBER: _ClassVar[int]
    target_id: int
    def __init__(self, target_id: _Optional[int] = ...) -> None: ...

class InteractiveMovingTask(_message.Message):
    __slots__ = ("target_id", "goal")
    TARGET_ID_FIELD_NUMBER: _ClassVar[int]
    GOAL_FIELD_NUMBER: _ClassVar[int]
    target_id: int
    goal: _common_pb2.Vector3
    def __init__(self, target_id: _Optional[int] = ..., goal: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ...) -> None: ...

class PlanTask(_message.Message):
    __slots__ = ("moving", "singulation", "grasping", "interactive_moving")
    MOVING_FIELD_NUMBER: _ClassVar[int]
    SINGULATION_FIELD_NUMBER: _ClassVar[int]
    GRASPING_FIELD_NUMBER: _ClassVar[int]
    INTERACTIVE_MOVING_FIELD_NUMBER: _ClassVar[int]
    moving: MovingTask
    singulation: SingulationTask
    grasping: GraspingTask
    interactive_moving: InteractiveMovingTask
    def __init__(self, moving: _Optional[_Union[MovingTask, _Mapping]] = ..., singulation: _Optional[_Union[SingulationTask, _Mapping]] = ..., grasping: _Optional[_Union[GraspingTask, _Mapping]] = ..., interactive_moving: _Optional[_Union[InteractiveMovingTask, _Mapping]] = ...) -> None: ...

class MPCOptions(_message.Message):
    __slots__ = ("num_sequences", "horizon", "seed", "dynamics_model")
    NUM_SEQUENCES_FIELD_NUMBER: _ClassVar[int]
    HORIZON_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    DYNAMICS_MODEL_FIELD_NUMBER: _ClassVar[int]
    num_sequences: int
    horizon: int
    seed: int
    dynamics_model: str
    def __init__(self, num_sequences: _Optional[int] = ..., horizon: _Optional[int] = ..., seed: _Optional[int] = ..., dynamics_model: _Optional[str] = ...) -> None: ...

class PlanRequest(_message.Message):
    __slots__ = ("objects", "task", "options")
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    TASK_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    objects: _containers.RepeatedCompositeFieldContainer[_common_pb2.RecognizedObject]
    task: PlanTask
    options: MPCOptions
    def __init__(self, objects: _Optional[_Iterable[_Union[_common_pb2.RecognizedObject, _Mapping]]] = ..., task: _Optional[_Union[PlanTask, _Mapping]] = ..., options: _Optional[_Union[MPCOptions, _Mapping]] = ...) -> None: ...

class ObjectPose(_message.Message):
    __slots__ = ("object_id", "pose")
    OBJECT_ID_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    object_id: int
    pose: _common_pb2.Pose
    def __init__(self, object_id: _Optional[int] = ..., pose: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ...) -> None: ...

class PlanResponse(_message.Message):
    __slots__ = ("has_action", "action", "pushed_id", "predicted_next", "cost", "current_cost", "num_candidates", "num_sampled", "num_rejected_start", "num_rejected_workspace", "sequence", "timings_ms", "dynamics_model", "solved")
    class TimingsMsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    HAS_ACTION_FIELD_NUMBER: _ClassVar[int]
    ACTION_FIELD_NUMBER: _ClassVar[int]
    PUSHED_ID_FIELD_NUMBER: _ClassVar[int]
    PREDICTED_NEXT_FIELD_NUMBER: _ClassVar[int]
    COST_FIELD_NUMBER: _ClassVar[int]
    CURRENT_COST_FIELD_NUMBER: _ClassVar[int]
    NUM_CANDIDATES_FIELD_NUMBER: _ClassVar[int]
    NUM_SAMPLED_FIELD_NUMBER: _ClassVar[int]
    NUM_REJECTED_START_FIELD_NUMBER: _ClassVar[int]
    NUM_REJECTED_WORKSPACE_FIELD_NUMBER: _ClassVar[int]
    SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    TIMINGS_MS_FIELD_NUMBER: _ClassVar[int]
    DYNAMICS_MODEL_FIELD_NUMBER: _ClassVar[int]
    SOLVED_FIELD_NUMBER: _ClassVar[int]
    has_action: bool
    action: _containers.RepeatedScalarFieldContainer[float]
    pushed_id: int
    predicted_next: _containers.RepeatedCompositeFieldContainer[ObjectPose]
    cost: float
    current_cost: float
    num_candidates: int
    num_sampled: int
    num_rejected_start: int
    num_rejected_workspace: int
    sequence: _containers.RepeatedScalarFieldContainer[float]
    timings_ms: _containers.ScalarMap[str, float]
    dynamics_model: str
    solved: bool
    def __init__(self, has_action: _Optional[bool] = ..., action: _Optional[_Iterable[float]] = ..., pushed_id: _Optional[int] = ..., predicted_next: _Optional[_Iterable[_Union[ObjectPose, _Mapping]]] = ..., cost: _Optional[float] = ..., current_cost: _Optional[float] = ..., num_candidates: _Optional[int] = ..., num_sampled: _Optional[int] = ..., num_rejected_start: _Optional[int] = ..., num_rejected_workspace: _Optional[int] = ..., sequence: _Optional[_Iterable[float]] = ..., timings_ms: _Optional[_Mapping[str, float]] = ..., dynamics_model: _Optional[str] = ..., solved: _Optional[bool] = ...) -> None: ...

class EpisodeRequest(_message.Message):
    __slots__ = ("kind", "index", "seed", "objects", "options", "max_steps")
    KIND_FIELD_NUMBER: _ClassVar[int]
    INDEX_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    MAX_STEPS_FIELD_NUMBER: _ClassVar[int]
    kind: str
    index: int
    seed: int
    objects: str
    options: MPCOptions
    max_steps: int
    def __init__(self, kind: _Optional[str] = ..., index: _Optional[int] = ..., seed: _Optional[int] = ..., objects: _Optional[str] = ..., options: _Optional[_Union[MPCOptions, _Mapping]] = ..., max_steps: _Optional[int] = ...) -> None: ...

class ObjectXYZYaw(_message.Message):
    __slots__ = ("object_id", "x", "y", "z", "yaw")
    OBJECT_ID_FIELD_NUMBER: _ClassVar[int]
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    Z_FIELD_NUMBER: _ClassVar[int]
    YAW_FIELD_NUMBER: _ClassVar[int]
    object_id: int
    x: float
    y: float
    z: float
    yaw: float
    def __init__(self, object_id: _Optional[int] = ..., x: _Optional[float] = ..., y: _Optional[float] = ..., z: _Optional[float] = ..., yaw: _Optional[float] = ...) -> None: ...

class EpisodeResult(_message.Message):
    __slots__ = ("kind", "index", "success", "steps", "reason", "grasp_found", "metric", "wall_s")
    KIND_FIELD_NUMBER: _ClassVar[int]
    INDEX_FIELD_NUMBER: _ClassVar[int]
    SUCCESS_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    GRASP_FOUND_FIELD_NUMBER: _ClassVar[int]
    METRIC_FIELD_NUMBER: _ClassVar[int]
    WALL_S_FIELD_NUMBER: _ClassVar[int]
    kind: str
    index: int
    success: bool
    steps: int
    reason: str
    grasp_found: bool
    metric: float
    wall_s: float
    def __init__(self, kind: _Optional[str] = ..., index: _Optional[int] = ..., success: _Optional[bool] = ..., steps: _Optional[int] = ..., reason: _Optional[str] = ..., grasp_found: _Optional[bool] = ..., metric: _Optional[float] = ..., wall_s: _Optional[float] = ...) -> None: ...

class EpisodeEvent(_message.Message):
    __slots__ = ("step", "status", "message", "num_points", "recognized_ids", "missing_ids", "action", "pushed_id", "predicted", "recognized", "observed", "cost", "current_cost", "metric_after", "num_candidates", "timings_ms", "result")
    class TimingsMsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    STEP_FIELD_NUMBER: _ClassVar[int]
    STATUS_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    NUM_POINTS_FIELD_NUMBER: _ClassVar[int]
    RECOGNIZED_IDS_FIELD_NUMBER: _ClassVar[int]
    MISSING_IDS_FIELD_NUMBER: _ClassVar[int]
    ACTION_FIELD_NUMBER: _ClassVar[int]
    PUSHED_ID_FIELD_NUMBER: _ClassVar[int]
    PREDICTED_FIELD_NUMBER: _ClassVar[int]
    RECOGNIZED_FIELD_NUMBER: _ClassVar[int]
    OBSERVED_FIELD_NUMBER: _ClassVar[int]
    COST_FIELD_NUMBER: _ClassVar[int]
    CURRENT_COST_FIELD_NUMBER: _ClassVar[int]
    METRIC_AFTER_FIELD_NUMBER: _ClassVar[int]
    NUM_CANDIDATES_FIELD_NUMBER: _ClassVar[int]
    TIMINGS_MS_FIELD_NUMBER: _ClassVar[int]
    RESULT_FIELD_NUMBER: _ClassVar[int]
    step: int
    status: str
    message: str
    num_points: int
    recognized_ids: _containers.RepeatedScalarFieldContainer[int]
    missing_ids: _containers.RepeatedScalarFieldContainer[int]
    action: _containers.RepeatedScalarFieldContainer[float]
    pushed_id: int
    predicted: _containers.RepeatedCompositeFieldContainer[ObjectXYZYaw]
    recognized: _containers.RepeatedCompositeFieldContainer[ObjectXYZYaw]
    observed: _containers.RepeatedCompositeFieldContainer[ObjectXYZYaw]
    cost: float
    current_cost: float
    metric_after: float
    num_candidates: int
    timings_ms: _containers.ScalarMap[str, float]
    result: EpisodeResult
    def __init__(self, step: _Optional[int] = ..., status: _Optional[str] = ..., message: _Optional[str] = ..., num_points: _Optional[int] = ..., recognized_ids: _Optional[_Iterable[int]] = ..., missing_ids: _Optional[_Iterable[int]] = ..., action: _Optional[_Iterable[float]] = ..., pushed_id: _Optional[int] = ..., predicted: _Optional[_Iterable[_Union[ObjectXYZYaw, _Mapping]]] = ..., recognized: _Optional[_Iterable[_Union[ObjectXYZYaw, _Mapping]]] = ..., observed: _Optional[_Iterable[_Union[ObjectXYZYaw, _Mapping]]] = ..., cost: _Optional[float] = ..., current_cost: _Optional[float] = ..., metric_after: _Optional[float] = ..., num_candidates: _Optional[int] = ..., timings_ms: _Optional[_Mapping[str, float]] = ..., result: _Optional[_Union[EpisodeResult, _Mapping]] = ...) -> None: ...
