from sqmanip.v1 import common_pb2 as _common_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class SearchTarget(_message.Message):
    __slots__ = ("kind", "size")
    KIND_FIELD_NUMBER: _ClassVar[int]
    SIZE_FIELD_NUMBER: _ClassVar[int]
    kind: str
    size: _common_pb2.Vector3
    def __init__(self, kind: _Optional[str] = ..., size: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ...) -> None: ...

class ShelfGeometry(_message.Message):
    __slots__ = ("front_x", "depth", "inner_width", "inner_height", "bottom_z", "thickness")
    FRONT_X_FIELD_NUMBER: _ClassVar[int]
    DEPTH_FIELD_NUMBER: _ClassVar[int]
    INNER_WIDTH_FIELD_NUMBER: _ClassVar[int]
    INNER_HEIGHT_FIELD_NUMBER: _ClassVar[int]
    BOTTOM_Z_FIELD_NUMBER: _ClassVar[int]
    THICKNESS_FIELD_NUMBER: _ClassVar[int]
    front_x: float
    depth: float
    inner_width: float
    inner_height: float
    bottom_z: float
    thickness: float
    def __init__(self, front_x: _Optional[float] = ..., depth: _Optional[float] = ..., inner_width: _Optional[float] = ..., inner_height: _Optional[float] = ..., bottom_z: _Optional[float] = ..., thickness: _Optional[float] = ...) -> None: ...

class PinholeCamera(_message.Message):
    __slots__ = ("width", "height", "fx", "fy", "cx", "cy", "pose")
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    FX_FIELD_NUMBER: _ClassVar[int]
    FY_FIELD_NUMBER: _ClassVar[int]
    CX_FIELD_NUMBER: _ClassVar[int]
    CY_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    pose: _common_pb2.Pose
    def __init__(self, width: _Optional[int] = ..., height: _Optional[int] = ..., fx: _Optional[float] = ..., fy: _Optional[float] = ..., cx: _Optional[float] = ..., cy: _Optional[float] = ..., pose: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ...) -> None: ...

class EvaluateRequest(_message.Message):
    __slots__ = ("objects", "target", "shelf", "camera", "target_visible", "target_pose", "resolution", "n_theta")
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    TARGET_FIELD_NUMBER: _ClassVar[int]
    SHELF_FIELD_NUMBER: _ClassVar[int]
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    TARGET_VISIBLE_FIELD_NUMBER: _ClassVar[int]
    TARGET_POSE_FIELD_NUMBER: _ClassVar[int]
    RESOLUTION_FIELD_NUMBER: _ClassVar[int]
    N_THETA_FIELD_NUMBER: _ClassVar[int]
    objects: _containers.RepeatedCompositeFieldContainer[_common_pb2.Superquadric]
    target: SearchTarget
    shelf: ShelfGeometry
    camera: PinholeCamera
    target_visible: bool
    target_pose: _common_pb2.Pose
    resolution: float
    n_theta: int
    def __init__(self, objects: _Optional[_Iterable[_Union[_common_pb2.Superquadric, _Mapping]]] = ..., target: _Optional[_Union[SearchTarget, _Mapping]] = ..., shelf: _Optional[_Union[ShelfGeometry, _Mapping]] = ..., camera: _Optional[_Union[PinholeCamera, _Mapping]] = ..., target_visible: _Optional[bool] = ..., target_pose: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ..., resolution: _Optional[float] = ..., n_theta: _Optional[int] = ...) -> None: ...

class EvaluateResponse(_message.Message):
    __slots__ = ("shape", "f", "g", "g_m", "grid_xy", "resolution", "objective", "timings_ms")
    class TimingsMsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    SHAPE_FIELD_NUMBER: _ClassVar[int]
    F_FIELD_NUMBER: _ClassVar[int]
    G_FIELD_NUMBER: _ClassVar[int]
    G_M_FIELD_NUMBER: _ClassVar[int]
    GRID_XY_FIELD_NUMBER: _ClassVar[int]
    RESOLUTION_FIELD_NUMBER: _ClassVar[int]
    OBJECTIVE_FIELD_NUMBER: _ClassVar[int]
    TIMINGS_MS_FIELD_NUMBER: _ClassVar[int]
    shape: _containers.RepeatedScalarFieldContainer[int]
    f: bytes
    g: bytes
    g_m: bytes
    grid_xy: bytes
    resolution: float
    objective: float
    timings_ms: _containers.ScalarMap[str, float]
    def __init__(self, shape: _Optional[_Iterable[int]] = ..., f: _Optional[bytes] = ..., g: _Optional[bytes] = ..., g_m: _Optional[bytes] = ..., grid_xy: _Optional[bytes] = ..., resolution: _Optional[float] = ..., objective: _Optional[float] = ..., timings_ms: _Optional[_Mapping[str, float]] = ...) -> None: ...

class SearchEpisodeRequest(_message.Message):
    __slots__ = ("scenario_json", "n_objects", "seed", "method", "shapes", "actions", "dynamics_model", "max_steps", "num_sequences", "plan_seed")
    SCENARIO_JSON_FIELD_NUMBER: _ClassVar[int]
    N_OBJECTS_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    METHOD_FIELD_NUMBER: _ClassVar[int]
    SHAPES_FIELD_NUMBER: _ClassVar[int]
    ACTIONS_FIELD_NUMBER: _ClassVar[int]
    DYNAMICS_MODEL_FIELD_NUMBER: _ClassVar[int]
    MAX_STEPS_FIELD_NUMBER: _ClassVar[int]
    NUM_SEQUENCES_FIELD_NUMBER: _ClassVar[int]
    PLAN_SEED_FIELD_NUMBER: _ClassVar[int]
    scenario_json: str
    n_objects: int
    seed: int
    method: str
    shapes: str
    actions: str
    dynamics_model: str
    max_steps: int
    num_sequences: int
    plan_seed: int
    def __init__(self, scenario_json: _Optional[str] = ..., n_objects: _Optional[int] = ..., seed: _Optional[int] = ..., method: _Optional[str] = ..., shapes: _Optional[str] = ..., actions: _Optional[str] = ..., dynamics_model: _Optional[str] = ..., max_steps: _Optional[int] = ..., num_sequences: _Optional[int] = ..., plan_seed: _Optional[int] = ...) -> None: ...

class SearchResult(_message.Message):
    __slots__ = ("found", "grasped", "find_steps", "grasp_steps", "steps", "reason", "wall_s", "scenario_json")
    FOUND_FIELD_NUMBER: _ClassVar[int]
    GRASPED_FIELD_NUMBER: _ClassVar[int]
    FIND_STEPS_FIELD_NUMBER: _ClassVar[int]
    GRASP_STEPS_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    WALL_S_FIELD_NUMBER: _ClassVar[int]
    SCENARIO_JSON_FIELD_NUMBER: _ClassVar[int]
    found: bool
    grasped: bool
    find_steps: int
    grasp_steps: int
    steps: int
    reason: str
    wall_s: float
    scenario_json: str
    def __init__(self, found: _Optional[bool] = ..., grasped: _Optional[bool] = ..., find_steps: _Optional[int] = ..., grasp_steps: _Optional[int] = ..., steps: _Optional[int] = ..., reason: _Optional[str] = ..., wall_s: _Optional[float] = ..., scenario_json: _Optional[str] = ...) -> None: ...

class SearchEvent(_message.Message):
    __slots__ = ("step", "action", "params_json", "f_sum", "fg_sum", "visible", "graspable", "target_pixels", "executed", "message", "timings_ms", "result")
    class TimingsMsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    STEP_FIELD_NUMBER: _ClassVar[int]
    ACTION_FIELD_NUMBER: _ClassVar[int]
    PARAMS_JSON_FIELD_NUMBER: _ClassVar[int]
    F_SUM_FIELD_NUMBER: _ClassVar[int]
    FG_SUM_FIELD_NUMBER: _ClassVar[int]
    VISIBLE_FIELD_NUMBER: _ClassVar[int]
    GRASPABLE_FIELD_NUMBER: _ClassVar[int]
    TARGET_PIXELS_FIELD_NUMBER: _ClassVar[int]
    EXECUTED_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    TIMINGS_MS_FIELD_NUMBER: _ClassVar[int]
    RESULT_FIELD_NUMBER: _ClassVar[int]
    step: int
    action: str
    params_json: str
    f_sum: float
    fg_sum: float
    visible: bool
    graspable: bool
    target_pixels: int
    executed: bool
    message: str
    timings_ms: _containers.ScalarMap[str, float]
    result: SearchResult
    def __init__(self, step: _Optional[int] = ..., action: _Optional[str] = ..., params_json: _Optional[str] = ..., f_sum: _Optional[float] = ..., fg_sum: _Optional[float] = ..., visible: _Optional[bool] = ..., graspable: _Optional[bool] = ..., target_pixels: _Optional[int] = ..., executed: _Optional[bool] = ..., message: _Optional[str] = ..., timings_ms: _Optional[_Mapping[str, float]] = ..., result: _Optional[_Union[SearchResult, _Mapping]] = ...) -> None: ...
