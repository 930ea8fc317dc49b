from sqmanip.v1 import common_pb2 as _common_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class CameraIntrinsics(_message.Message):
    __slots__ = ("width", "height", "fx", "fy", "cx", "cy", "near", "far")
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    FX_FIELD_NUMBER: _ClassVar[int]
    FY_FIELD_NUMBER: _ClassVar[int]
    CX_FIELD_NUMBER: _ClassVar[int]
    CY_FIELD_NUMBER: _ClassVar[int]
    NEAR_FIELD_NUMBER: _ClassVar[int]
    FAR_FIELD_NUMBER: _ClassVar[int]
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    near: float
    far: float
    def __init__(self, width: _Optional[int] = ..., height: _Optional[int] = ..., fx: _Optional[float] = ..., fy: _Optional[float] = ..., cx: _Optional[float] = ..., cy: _Optional[float] = ..., near: _Optional[float] = ..., far: _Optional[float] = ...) -> None: ...

class ObjectState(_message.Message):
    __slots__ = ("id", "name", "kind", "pose", "superquadric")
    ID_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    SUPERQUADRIC_FIELD_NUMBER: _ClassVar[int]
    id: int
    name: str
    kind: str
    pose: _common_pb2.Pose
    superquadric: _common_pb2.Superquadric
    def __init__(self, id: _Optional[int] = ..., name: _Optional[str] = ..., kind: _Optional[str] = ..., pose: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ..., superquadric: _Optional[_Union[_common_pb2.Superquadric, _Mapping]] = ...) -> None: ...

class SimState(_message.Message):
    __slots__ = ("time", "scene_kind", "objects", "joint_positions", "gripper_width", "tcp_pose", "held_object")
    TIME_FIELD_NUMBER: _ClassVar[int]
    SCENE_KIND_FIELD_NUMBER: _ClassVar[int]
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    JOINT_POSITIONS_FIELD_NUMBER: _ClassVar[int]
    GRIPPER_WIDTH_FIELD_NUMBER: _ClassVar[int]
    TCP_POSE_FIELD_NUMBER: _ClassVar[int]
    HELD_OBJECT_FIELD_NUMBER: _ClassVar[int]
    time: float
    scene_kind: str
    objects: _containers.RepeatedCompositeFieldContainer[ObjectState]
    joint_positions: _containers.RepeatedScalarFieldContainer[float]
    gripper_width: float
    tcp_pose: _common_pb2.Pose
    held_object: int
    def __init__(self, time: _Optional[float] = ..., scene_kind: _Optional[str] = ..., objects: _Optional[_Iterable[_Union[ObjectState, _Mapping]]] = ..., joint_positions: _Optional[_Iterable[float]] = ..., gripper_width: _Optional[float] = ..., tcp_pose: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ..., held_object: _Optional[int] = ...) -> None: ...

class ResetRequest(_message.Message):
    __slots__ = ("scene_json", "seed", "n_objects", "kind", "object_kinds")
    SCENE_JSON_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    N_OBJECTS_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    OBJECT_KINDS_FIELD_NUMBER: _ClassVar[int]
    scene_json: str
    seed: int
    n_objects: int
    kind: str
    object_kinds: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, scene_json: _Optional[str] = ..., seed: _Optional[int] = ..., n_objects: _Optional[int] = ..., kind: _Optional[str] = ..., object_kinds: _Optional[_Iterable[str]] = ...) -> None: ...

class ResetResponse(_message.Message):
    __slots__ = ("state", "scene_json")
    STATE_FIELD_NUMBER: _ClassVar[int]
    SCENE_JSON_FIELD_NUMBER: _ClassVar[int]
    state: SimState
    scene_json: str
    def __init__(self, state: _Optional[_Union[SimState, _Mapping]] = ..., scene_json: _Optional[str] = ...) -> None: ...

class ObserveRequest(_message.Message):
    __slots__ = ("camera", "intrinsics", "camera_pose", "noise")
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    INTRINSICS_FIELD_NUMBER: _ClassVar[int]
    CAMERA_POSE_FIELD_NUMBER: _ClassVar[int]
    NOISE_FIELD_NUMBER: _ClassVar[int]
    camera: str
    intrinsics: CameraIntrinsics
    camera_pose: _common_pb2.Pose
    noise: bool
    def __init__(self, camera: _Optional[str] = ..., intrinsics: _Optional[_Union[CameraIntrinsics, _Mapping]] = ..., camera_pose: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ..., noise: _Optional[bool] = ...) -> None: ...

class Observation(_message.Message):
    __slots__ = ("camera", "intrinsics", "camera_pose", "height", "width", "depth", "rgb", "segmentation", "cloud", "point_pixels", "objects", "time")
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    INTRINSICS_FIELD_NUMBER: _ClassVar[int]
    CAMERA_POSE_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    DEPTH_FIELD_NUMBER: _ClassVar[int]
    RGB_FIELD_NUMBER: _ClassVar[int]
    SEGMENTATION_FIELD_NUMBER: _ClassVar[int]
    CLOUD_FIELD_NUMBER: _ClassVar[int]
    POINT_PIXELS_FIELD_NUMBER: _ClassVar[int]
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    TIME_FIELD_NUMBER: _ClassVar[int]
    camera: str
    intrinsics: CameraIntrinsics
    camera_pose: _common_pb2.Pose
    height: int
    width: int
    depth: bytes
    rgb: bytes
    segmentation: bytes
    cloud: _common_pb2.PointCloud
    point_pixels: bytes
    objects: _containers.RepeatedCompositeFieldContainer[ObjectState]
    time: float
    def __init__(self, camera: _Optional[str] = ..., intrinsics: _Optional[_Union[CameraIntrinsics, _Mapping]] = ..., camera_pose: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ..., height: _Optional[int] = ..., width: _Optional[int] = ..., depth: _Optional[bytes] = ..., rgb: _Optional[bytes] = ..., segmentation: _Optional[bytes] = ..., cloud: _Optional[_Union[_common_pb2.PointCloud, _Mapping]] = ..., point_pixels: _Optional[bytes] = ..., objects: _Optional[_Iterable[_Union[ObjectState, _Mapping]]] = ..., time: _Optional[float] = ...) -> None: ...

class PushRequest(_message.Message):
    __slots__ = ("p", "v", "upright")
    P_FIELD_NUMBER: _ClassVar[int]
    V_FIELD_NUMBER: _ClassVar[int]
    UPRIGHT_FIELD_NUMBER: _ClassVar[int]
    p: _common_pb2.Vector3
    v: _common_pb2.Vector3
    upright: bool
    def __init__(self, p: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., v: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., upright: _Optional[bool] = ...) -> None: ...

class GraspRequest(_message.Message):
    __slots__ = ("pose", "width")
    POSE_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    pose: _common_pb2.Pose
    width: float
    def __init__(self, pose: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ..., width: _Optional[float] = ...) -> None: ...

class PickAndPlaceRequest(_message.Message):
    __slots__ = ("grasp_pose", "width", "place_pose")
    GRASP_POSE_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    PLACE_POSE_FIELD_NUMBER: _ClassVar[int]
    grasp_pose: _common_pb2.Pose
    width: float
    place_pose: _common_pb2.Pose
    def __init__(self, grasp_pose: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ..., width: _Optional[float] = ..., place_pose: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ...) -> None: ...

class ReleaseRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class GetStateRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ActionResult(_message.Message):
    __slots__ = ("success", "message", "before", "after", "held_object", "sim_time")
    SUCCESS_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    BEFORE_FIELD_NUMBER: _ClassVar[int]
    AFTER_FIELD_NUMBER: _ClassVar[int]
    HELD_OBJECT_FIELD_NUMBER: _ClassVar[int]
    SIM_TIME_FIELD_NUMBER: _ClassVar[int]
    success: bool
    message: str
    before: SimState
    after: SimState
    held_object: int
    sim_time: float
    def __init__(self, success: _Optional[bool] = ..., message: _Optional[str] = ..., before: _Optional[_Union[SimState, _Mapping]] = ..., after: _Optional[_Union[SimState, _Mapping]] = ..., held_object: _Optional[int] = ..., sim_time: _Optional[float] = ...) -> None: ...
