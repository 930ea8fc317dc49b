from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class SuperquadricKind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SUPERQUADRIC_KIND_UNSPECIFIED: _ClassVar[SuperquadricKind]
    SUPERQUADRIC_KIND_SUPERELLIPSOID: _ClassVar[SuperquadricKind]
    SUPERQUADRIC_KIND_SUPERPARABOLOID: _ClassVar[SuperquadricKind]
    SUPERQUADRIC_KIND_SUPERTOROID: _ClassVar[SuperquadricKind]
SUPERQUADRIC_KIND_UNSPECIFIED: SuperquadricKind
SUPERQUADRIC_KIND_SUPERELLIPSOID: SuperquadricKind
SUPERQUADRIC_KIND_SUPERPARABOLOID: SuperquadricKind
SUPERQUADRIC_KIND_SUPERTOROID: SuperquadricKind

class PointCloud(_message.Message):
    __slots__ = ("num_points", "xyz", "rgb", "labels")
    NUM_POINTS_FIELD_NUMBER: _ClassVar[int]
    XYZ_FIELD_NUMBER: _ClassVar[int]
    RGB_FIELD_NUMBER: _ClassVar[int]
    LABELS_FIELD_NUMBER: _ClassVar[int]
    num_points: int
    xyz: bytes
    rgb: bytes
    labels: bytes
    def __init__(self, num_points: _Optional[int] = ..., xyz: _Optional[bytes] = ..., rgb: _Optional[bytes] = ..., labels: _Optional[bytes] = ...) -> None: ...

class Vector3(_message.Message):
    __slots__ = ("x", "y", "z")
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    Z_FIELD_NUMBER: _ClassVar[int]
    x: float
    y: float
    z: float
    def __init__(self, x: _Optional[float] = ..., y: _Optional[float] = ..., z: _Optional[float] = ...) -> None: ...

class Quaternion(_message.Message):
    __slots__ = ("x", "y", "z", "w")
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    Z_FIELD_NUMBER: _ClassVar[int]
    W_FIELD_NUMBER: _ClassVar[int]
    x: float
    y: float
    z: float
    w: float
    def __init__(self, x: _Optional[float] = ..., y: _Optional[float] = ..., z: _Optional[float] = ..., w: _Optional[float] = ...) -> None: ...

class Pose(_message.Message):
    __slots__ = ("position", "orientation")
    POSITION_FIELD_NUMBER: _ClassVar[int]
    ORIENTATION_FIELD_NUMBER: _ClassVar[int]
    position: Vector3
    orientation: Quaternion
    def __init__(self, position: _Optional[_Union[Vector3, _Mapping]] = ..., orientation: _Optional[_Union[Quaternion, _Mapping]] = ...) -> None: ...

class Superquadric(_message.Message):
    __slots__ = ("kind", "a1", "a2", "a3", "a4", "e1", "e2", "taper", "bend", "bend_direction", "pose")
    KIND_FIELD_NUMBER: _ClassVar[int]
    A1_FIELD_NUMBER: _ClassVar[int]
    A2_FIELD_NUMBER: _ClassVar[int]
    A3_FIELD_NUMBER: _ClassVar[int]
    A4_FIELD_NUMBER: _ClassVar[int]
    E1_FIELD_NUMBER: _ClassVar[int]
    E2_FIELD_NUMBER: _ClassVar[int]
    TAPER_FIELD_NUMBER: _ClassVar[int]
    BEND_FIELD_NUMBER: _ClassVar[int]
    BEND_DIRECTION_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    kind: SuperquadricKind
    a1: float
    a2: float
    a3: float
    a4: float
    e1: float
    e2: float
    taper: float
    bend: float
    bend_direction: float
    pose: Pose
    def __init__(self, kind: _Optional[_Union[SuperquadricKind, str]] = ..., a1: _Optional[float] = ..., a2: _Optional[float] = ..., a3: _Optional[float] = ..., a4: _Optional[float] = ..., e1: _Optional[float] = ..., e2: _Optional[float] = ..., taper: _Optional[float] = ..., bend: _Optional[float] = ..., bend_direction: _Optional[float] = ..., pose: _Optional[_Union[Pose, _Mapping]] = ...) -> None: ...

class Color(_message.Message):
    __slots__ = ("r", "g", "b")
    R_FIELD_NUMBER: _ClassVar[int]
    G_FIELD_NUMBER: _ClassVar[int]
    B_FIELD_NUMBER: _ClassVar[int]
    r: float
    g: float
    b: float
    def __init__(self, r: _Optional[float] = ..., g: _Optional[float] = ..., b: _Optional[float] = ...) -> None: ...

class RecognizedObject(_message.Message):
    __slots__ = ("id", "parts", "point_indices", "mean_color", "residual", "confidence")
    ID_FIELD_NUMBER: _ClassVar[int]
    PARTS_FIELD_NUMBER: _ClassVar[int]
    POINT_INDICES_FIELD_NUMBER: _ClassVar[int]
    MEAN_COLOR_FIELD_NUMBER: _ClassVar[int]
    RESIDUAL_FIELD_NUMBER: _ClassVar[int]
    CONFIDENCE_FIELD_NUMBER: _ClassVar[int]
    id: int
    parts: _containers.RepeatedCompositeFieldContainer[Superquadric]
    point_indices: bytes
    mean_color: Color
    residual: float
    confidence: float
    def __init__(self, id: _Optional[int] = ..., parts: _Optional[_Iterable[_Union[Superquadric, _Mapping]]] = ..., point_indices: _Optional[bytes] = ..., mean_color: _Optional[_Union[Color, _Mapping]] = ..., residual: _Optional[float] = ..., confidence: _Optional[float] = ...) -> None: ...

class SupportPlane(_message.Message):
    __slots__ = ("normal", "offset")
    NORMAL_FIELD_NUMBER: _ClassVar[int]
    OFFSET_FIELD_NUMBER: _ClassVar[int]
    normal: Vector3
    offset: float
    def __init__(self, normal: _Optional[_Union[Vector3, _Mapping]] = ..., offset: _Optional[float] = ...) -> None: ...

class Workspace(_message.Message):
    __slots__ = ("min", "max")
    MIN_FIELD_NUMBER: _ClassVar[int]
    MAX_FIELD_NUMBER: _ClassVar[int]
    min: Vector3
    max: Vector3
    def __init__(self, min: _Optional[_Union[Vector3, _Mapping]] = ..., max: _Optional[_Union[Vector3, _Mapping]] = ...) -> None: ...

class Scene(_message.Message):
    __slots__ = ("objects", "support_plane", "timings_ms")
    class TimingsMsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    SUPPORT_PLANE_FIELD_NUMBER: _ClassVar[int]
    TIMINGS_MS_FIELD_NUMBER: _ClassVar[int]
    objects: _containers.RepeatedCompositeFieldContainer[RecognizedObject]
    support_plane: SupportPlane
    timings_ms: _containers.ScalarMap[str, float]
    def __init__(self, objects: _Optional[_Iterable[_Union[RecognizedObject, _Mapping]]] = ..., support_plane: _Optional[_Union[SupportPlane, _Mapping]] = ..., timings_ms: _Optional[_Mapping[str, float]] = ...) -> None: ...
