from sqmanip.v1 import common_pb2 as _common_pb2
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class RecognizeOptions(_message.Message):
    __slots__ = ("method", "segmentation", "points_per_segment", "remove_support", "amodal", "deformable", "seed")
    METHOD_FIELD_NUMBER: _ClassVar[int]
    SEGMENTATION_FIELD_NUMBER: _ClassVar[int]
    POINTS_PER_SEGMENT_FIELD_NUMBER: _ClassVar[int]
    REMOVE_SUPPORT_FIELD_NUMBER: _ClassVar[int]
    AMODAL_FIELD_NUMBER: _ClassVar[int]
    DEFORMABLE_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    method: str
    segmentation: str
    points_per_segment: int
    remove_support: bool
    amodal: bool
    deformable: bool
    seed: int
    def __init__(self, method: _Optional[str] = ..., segmentation: _Optional[str] = ..., points_per_segment: _Optional[int] = ..., remove_support: _Optional[bool] = ..., amodal: _Optional[bool] = ..., deformable: _Optional[bool] = ..., seed: _Optional[int] = ...) -> None: ...

class RecognizeRequest(_message.Message):
    __slots__ = ("cloud", "viewpoint", "workspace", "options")
    CLOUD_FIELD_NUMBER: _ClassVar[int]
    VIEWPOINT_FIELD_NUMBER: _ClassVar[int]
    WORKSPACE_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    cloud: _common_pb2.PointCloud
    viewpoint: _common_pb2.Vector3
    workspace: _common_pb2.Workspace
    options: RecognizeOptions
    def __init__(self, cloud: _Optional[_Union[_common_pb2.PointCloud, _Mapping]] = ..., viewpoint: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., workspace: _Optional[_Union[_common_pb2.Workspace, _Mapping]] = ..., options: _Optional[_Union[RecognizeOptions, _Mapping]] = ...) -> None: ...

class RecognizeResponse(_message.Message):
    __slots__ = ("scene",)
    SCENE_FIELD_NUMBER: _ClassVar[int]
    scene: _common_pb2.Scene
    def __init__(self, scene: _Optional[_Union[_common_pb2.Scene, _Mapping]] = ...) -> None: ...
