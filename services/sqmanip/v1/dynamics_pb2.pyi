from sqmanip.v1 import common_pb2 as _common_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class PredictRequest(_message.Message):
    __slots__ = ("objects", "num_actions", "actions", "model", "scene_poses")
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    NUM_ACTIONS_FIELD_NUMBER: _ClassVar[int]
    ACTIONS_FIELD_NUMBER: _ClassVar[int]
    MODEL_FIELD_NUMBER: _ClassVar[int]
    SCENE_POSES_FIELD_NUMBER: _ClassVar[int]
    objects: _containers.RepeatedCompositeFieldContainer[_common_pb2.Superquadric]
    num_actions: int
    actions: bytes
    model: str
    scene_poses: bytes
    def __init__(self, objects: _Optional[_Iterable[_Union[_common_pb2.Superquadric, _Mapping]]] = ..., num_actions: _Optional[int] = ..., actions: _Optional[bytes] = ..., model: _Optional[str] = ..., scene_poses: _Optional[bytes] = ...) -> None: ...

class PredictResponse(_message.Message):
    __slots__ = ("num_actions", "num_objects", "poses", "model", "failed", "latency_ms")
    NUM_ACTIONS_FIELD_NUMBER: _ClassVar[int]
    NUM_OBJECTS_FIELD_NUMBER: _ClassVar[int]
    POSES_FIELD_NUMBER: _ClassVar[int]
    MODEL_FIELD_NUMBER: _ClassVar[int]
    FAILED_FIELD_NUMBER: _ClassVar[int]
    LATENCY_MS_FIELD_NUMBER: _ClassVar[int]
    num_actions: int
    num_objects: int
    poses: bytes
    model: str
    failed: bytes
    latency_ms: float
    def __init__(self, num_actions: _Optional[int] = ..., num_objects: _Optional[int] = ..., poses: _Optional[bytes] = ..., model: _Optional[str] = ..., failed: _Optional[bytes] = ..., latency_ms: _Optional[float] = ...) -> None: ...
