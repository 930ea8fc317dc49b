from sqmanip.v1 import common_pb2 as _common_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class GripperSpec(_message.Message):
    __slots__ = ("max_opening", "finger_length", "finger_width", "finger_thickness", "tip_offset", "palm_size", "wrist_radius", "wrist_length")
    MAX_OPENING_FIELD_NUMBER: _ClassVar[int]
    FINGER_LENGTH_FIELD_NUMBER: _ClassVar[int]
    FINGER_WIDTH_FIELD_NUMBER: _ClassVar[int]
    FINGER_THICKNESS_FIELD_NUMBER: _ClassVar[int]
    TIP_OFFSET_FIELD_NUMBER: _ClassVar[int]
    PALM_SIZE_FIELD_NUMBER: _ClassVar[int]
    WRIST_RADIUS_FIELD_NUMBER: _ClassVar[int]
    WRIST_LENGTH_FIELD_NUMBER: _ClassVar[int]
    max_opening: float
    finger_length: float
    finger_width: float
    finger_thickness: float
    tip_offset: float
    palm_size: _common_pb2.Vector3
    wrist_radius: float
    wrist_length: float
    def __init__(self, max_opening: _Optional[float] = ..., finger_length: _Optional[float] = ..., finger_width: _Optional[float] = ..., finger_thickness: _Optional[float] = ..., tip_offset: _Optional[float] = ..., palm_size: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., wrist_radius: _Optional[float] = ..., wrist_length: _Optional[float] = ...) -> None: ...

class GraspEnvironment(_message.Message):
    __slots__ = ("support_plane", "boxes", "up")
    SUPPORT_PLANE_FIELD_NUMBER: _ClassVar[int]
    BOXES_FIELD_NUMBER: _ClassVar[int]
    UP_FIELD_NUMBER: _ClassVar[int]
    support_plane: _common_pb2.SupportPlane
    boxes: _containers.RepeatedCompositeFieldContainer[_common_pb2.Superquadric]
    up: _common_pb2.Vector3
    def __init__(self, support_plane: _Optional[_Union[_common_pb2.SupportPlane, _Mapping]] = ..., boxes: _Optional[_Iterable[_Union[_common_pb2.Superquadric, _Mapping]]] = ..., up: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ...) -> None: ...

class RuleOptions(_message.Message):
    __slots__ = ("top_down", "side", "per_direction", "max_candidates", "max_width", "spread", "grasp_depth", "tilt", "facing", "facing_angle", "round_threshold", "antipodal_threshold")
    TOP_DOWN_FIELD_NUMBER: _ClassVar[int]
    SIDE_FIELD_NUMBER: _ClassVar[int]
    PER_DIRECTION_FIELD_NUMBER: _ClassVar[int]
    MAX_CANDIDATES_FIELD_NUMBER: _ClassVar[int]
    MAX_WIDTH_FIELD_NUMBER: _ClassVar[int]
    SPREAD_FIELD_NUMBER: _ClassVar[int]
    GRASP_DEPTH_FIELD_NUMBER: _ClassVar[int]
    TILT_FIELD_NUMBER: _ClassVar[int]
    FACING_FIELD_NUMBER: _ClassVar[int]
    FACING_ANGLE_FIELD_NUMBER: _ClassVar[int]
    ROUND_THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    ANTIPODAL_THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    top_down: bool
    side: bool
    per_direction: int
    max_candidates: int
    max_width: float
    spread: float
    grasp_depth: float
    tilt: float
    facing: _common_pb2.Vector3
    facing_angle: float
    round_threshold: float
    antipodal_threshold: float
    def __init__(self, top_down: _Optional[bool] = ..., side: _Optional[bool] = ..., per_direction: _Optional[int] = ..., max_candidates: _Optional[int] = ..., max_width: _Optional[float] = ..., spread: _Optional[float] = ..., grasp_depth: _Optional[float] = ..., tilt: _Optional[float] = ..., facing: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., facing_angle: _Optional[float] = ..., round_threshold: _Optional[float] = ..., antipodal_threshold: _Optional[float] = ...) -> None: ...

class GraspPlanOptions(_message.Message):
    __slots__ = ("n_samples", "n_approach", "antipodal_threshold", "beta", "max_results", "seed", "score", "method", "gripper_points", "include_wrist", "approach_distance", "support_clearance", "min_width", "check_target", "check_reachability", "rule")
    N_SAMPLES_FIELD_NUMBER: _ClassVar[int]
    N_APPROACH_FIELD_NUMBER: _ClassVar[int]
    ANTIPODAL_THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    BETA_FIELD_NUMBER: _ClassVar[int]
    MAX_RESULTS_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    SCORE_FIELD_NUMBER: _ClassVar[int]
    METHOD_FIELD_NUMBER: _ClassVar[int]
    GRIPPER_POINTS_FIELD_NUMBER: _ClassVar[int]
    INCLUDE_WRIST_FIELD_NUMBER: _ClassVar[int]
    APPROACH_DISTANCE_FIELD_NUMBER: _ClassVar[int]
    SUPPORT_CLEARANCE_FIELD_NUMBER: _ClassVar[int]
    MIN_WIDTH_FIELD_NUMBER: _ClassVar[int]
    CHECK_TARGET_FIELD_NUMBER: _ClassVar[int]
    CHECK_REACHABILITY_FIELD_NUMBER: _ClassVar[int]
    RULE_FIELD_NUMBER: _ClassVar[int]
    n_samples: int
    n_approach: int
    antipodal_threshold: float
    beta: float
    max_results: int
    seed: int
    score: str
    method: str
    gripper_points: int
    include_wrist: bool
    approach_distance: float
    support_clearance: float
    min_width: float
    check_target: bool
    check_reachability: bool
    rule: RuleOptions
    def __init__(self, n_samples: _Optional[int] = ..., n_approach: _Optional[int] = ..., antipodal_threshold: _Optional[float] = ..., beta: _Optional[float] = ..., max_results: _Optional[int] = ..., seed: _Optional[int] = ..., score: _Optional[str] = ..., method: _Optional[str] = ..., gripper_points: _Optional[int] = ..., include_wrist: _Optional[bool] = ..., approach_distance: _Optional[float] = ..., support_clearance: _Optional[float] = ..., min_width: _Optional[float] = ..., check_target: _Optional[bool] = ..., check_reachability: _Optional[bool] = ..., rule: _Optional[_Union[RuleOptions, _Mapping]] = ...) -> None: ...

class PlanGraspsRequest(_message.Message):
    __slots__ = ("objects", "target_id", "environment", "gripper", "options", "observed_points")
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    TARGET_ID_FIELD_NUMBER: _ClassVar[int]
    ENVIRONMENT_FIELD_NUMBER: _ClassVar[int]
    GRIPPER_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    OBSERVED_POINTS_FIELD_NUMBER: _ClassVar[int]
    objects: _containers.RepeatedCompositeFieldContainer[_common_pb2.RecognizedObject]
    target_id: int
    environment: GraspEnvironment
    gripper: GripperSpec
    options: GraspPlanOptions
    observed_points: _common_pb2.PointCloud
    def __init__(self, objects: _Optional[_Iterable[_Union[_common_pb2.RecognizedObject, _Mapping]]] = ..., target_id: _Optional[int] = ..., environment: _Optional[_Union[GraspEnvironment, _Mapping]] = ..., gripper: _Optional[_Union[GripperSpec, _Mapping]] = ..., options: _Optional[_Union[GraspPlanOptions, _Mapping]] = ..., observed_points: _Optional[_Union[_common_pb2.PointCloud, _Mapping]] = ...) -> None: ...

class Grasp(_message.Message):
    __slots__ = ("pose", "width", "score", "contacts", "uncertainty")
    POSE_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    SCORE_FIELD_NUMBER: _ClassVar[int]
    CONTACTS_FIELD_NUMBER: _ClassVar[int]
    UNCERTAINTY_FIELD_NUMBER: _ClassVar[int]
    pose: _common_pb2.Pose
    width: float
    score: float
    contacts: _containers.RepeatedCompositeFieldContainer[_common_pb2.Vector3]
    uncertainty: float
    def __init__(self, pose: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ..., width: _Optional[float] = ..., score: _Optional[float] = ..., contacts: _Optional[_Iterable[_Union[_common_pb2.Vector3, _Mapping]]] = ..., uncertainty: _Optional[float] = ...) -> None: ...

class GraspPlanStats(_message.Message):
    __slots__ = ("n_samples", "n_pairs", "n_candidates", "n_checked", "n_unreachable", "n_colliding", "collisions", "timings_ms")
    class CollisionsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    class TimingsMsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    N_SAMPLES_FIELD_NUMBER: _ClassVar[int]
    N_PAIRS_FIELD_NUMBER: _ClassVar[int]
    N_CANDIDATES_FIELD_NUMBER: _ClassVar[int]
    N_CHECKED_FIELD_NUMBER: _ClassVar[int]
    N_UNREACHABLE_FIELD_NUMBER: _ClassVar[int]
    N_COLLIDING_FIELD_NUMBER: _ClassVar[int]
    COLLISIONS_FIELD_NUMBER: _ClassVar[int]
    TIMINGS_MS_FIELD_NUMBER: _ClassVar[int]
    n_samples: int
    n_pairs: int
    n_candidates: int
    n_checked: int
    n_unreachable: int
    n_colliding: int
    collisions: _containers.ScalarMap[str, int]
    timings_ms: _containers.ScalarMap[str, float]
    def __init__(self, n_samples: _Optional[int] = ..., n_pairs: _Optional[int] = ..., n_candidates: _Optional[int] = ..., n_checked: _Optional[int] = ..., n_unreachable: _Optional[int] = ..., n_colliding: _Optional[int] = ..., collisions: _Optional[_Mapping[str, int]] = ..., timings_ms: _Optional[_Mapping[str, float]] = ...) -> None: ...

class PlanGraspsResponse(_message.Message):
    __slots__ = ("target_id", "grasps", "stats")
    TARGET_ID_FIELD_NUMBER: _ClassVar[int]
    GRASPS_FIELD_NUMBER: _ClassVar[int]
    STATS_FIELD_NUMBER: _ClassVar[int]
    target_id: int
    grasps: _containers.RepeatedCompositeFieldContainer[Grasp]
    stats: GraspPlanStats
    def __init__(self, target_id: _Optional[int] = ..., grasps: _Optional[_Iterable[_Union[Grasp, _Mapping]]] = ..., stats: _Optional[_Union[GraspPlanStats, _Mapping]] = ...) -> None: ...
