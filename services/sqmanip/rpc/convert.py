"""The only mapping between domain types and ``sqmanip.v1`` protobuf messages.

Point clouds travel as packed little-endian byte planes with an explicit count (ARCHITECTURE.md,
"Wire formats"): ``xyz`` float32 N x 3, ``rgb`` uint8 N x 3, ``labels`` int32 N. Colors are floats
in [0, 1] in the domain and in JSON, and ``round(255 c)`` on the wire (so a round trip changes
a color by at most 1/510). Every size mismatch raises :class:`sqmanip.errors.ValidationError`
naming the field, the expected and the received size; range checks on the values themselves
(finite, count limits) are the domain's (``sqmanip.perception.validate``).

The simulator section (``sim.proto``) maps :mod:`sqmanip.sim` states, observations and action
results; scene specs travel as ``SceneSpec.to_dict()`` JSON text. The grasp section
(``grasp.proto``) maps :mod:`sqmanip.grasping` requests, grasps and plan statistics; the dynamics
section (``dynamics.proto``) maps the arguments and result of ``SQPDNet.predict``.
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from sqmanip.errors import NotFoundError, ValidationError
from sqmanip.geometry import Superquadric
from sqmanip.geometry.superquadric import KINDS
from sqmanip.geometry.transforms import matrix_to_quat, quat_to_matrix
from sqmanip.grasping.config import PANDA_HAND
from sqmanip.grasping.planner import PlanResult, PlanStats
from sqmanip.grasping.types import Environment, Grasp, GripperSpec, PlanOptions, RuleOptions
from sqmanip.perception.types import (
    RecognizedObject,
    RecognizeOptions,
    RecognizeRequest,
    Scene,
    SupportPlane,
    Workspace,
)
from sqmanip.sim.actions import ActionResult, ObjectState, Observation, SimState
from sqmanip.sim.camera import Intrinsics
from sqmanip.v1 import common_pb2 as pb
from sqmanip.v1 import dynamics_pb2 as dynamics_pb
from sqmanip.v1 import grasp_pb2 as grasp_pb
from sqmanip.v1 import perception_pb2 as perception_pb
from sqmanip.v1 import sim_pb2 as sim_pb

if TYPE_CHECKING:  # sqmanip.sim.scene imports pybullet (and prints a banner): only where needed
    from sqmanip.sim.scene import SceneSpec

F32 = np.dtype("<f4")
I32 = np.dtype("<i4")

KIND_TO_PROTO = {
    "superellipsoid": pb.SUPERQUADRIC_KIND_SUPERELLIPSOID,
    "superparaboloid": pb.SUPERQUADRIC_KIND_SUPERPARABOLOID,
    "supertoroid": pb.SUPERQUADRIC_KIND_SUPERTOROID,
}
KIND_FROM_PROTO = {v: k for k, v in KIND_TO_PROTO.items()}
KIND_FROM_PROTO[pb.SUPERQUADRIC_KIND_UNSPECIFIED] = "superellipsoid"

__all__ = [
    "cloud_from_proto",
    "cloud_to_proto",
    "colors_from_uint8",
    "colors_to_uint8",
    "options_from_proto",
    "options_to_proto",
    "pose_from_proto",
    "pose_to_proto",
    "recognize_request_from_proto",
    "recognize_request_to_proto",
    "scene_from_proto",
    "scene_to_proto",
    "superquadric_from_proto",
    "superquadric_to_proto",
    # simulator
    "action_result_from_proto",
    "action_result_to_proto",
    "intrinsics_from_proto",
    "intrinsics_to_proto",
    "object_state_from_proto",
    "object_state_to_proto",
    "observation_from_proto",
    "observation_to_proto",
    "observe_request_from_proto",
    "observe_request_to_proto",
    "pick_and_place_request_from_proto",
    "pick_and_place_request_to_proto",
    "push_request_from_proto",
    "push_request_to_proto",
    "grasp_request_from_proto",
    "grasp_request_to_proto",
    "reset_request_from_proto",
    "reset_request_to_proto",
    "scene_spec_from_dict",
    "scene_spec_from_json",
    "scene_spec_to_json",
    "sim_state_from_proto",
    "sim_state_to_proto",
    # grasp planner
    "PlanGraspsArgs",
    "field_message",
    "environment_from_proto",
    "environment_to_proto",
    "grasp_from_proto",
    "grasp_to_proto",
    "gripper_spec_from_proto",
    "gripper_spec_to_proto",
    "plan_grasps_request_from_proto",
    "plan_grasps_request_to_proto",
    "plan_options_from_proto",
    "plan_options_to_proto",
    "plan_result_from_proto",
    "plan_result_to_proto",
    "plan_stats_from_proto",
    "plan_stats_to_proto",
    "rule_options_from_proto",
    "rule_options_to_proto",
    # dynamics
    "DYNAMICS_MODELS",
    "PredictArgs",
    "predict_request_from_proto",
    "predict_request_to_proto",
    "predict_response_from_proto",
    "predict_response_to_proto",
]


# --- point clouds -------------------------------------------------------------------------------


def _as_points(points, name: str = "points") -> np.ndarray:
    try:
        arr = np.asarray(points, dtype=np.float64 if not isinstance(points, np.ndarray) else None)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name}: expected numbers of shape (N, 3) ({exc})") from None
    if arr.size == 0 and arr.ndim <= 2:
        arr = arr.reshape(0, 3)  # [] -> 0 points; the domain reports "at least 1 point"
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValidationError(f"{name}: expected shape (N, 3), got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or np.issubdtype(arr.dtype, np.complexfloating):
        raise ValidationError(f"{name}: expected real numbers, got dtype {arr.dtype}")
    return arr


def colors_to_uint8(colors: np.ndarray) -> np.ndarray:
    """``(N, 3)`` floats in [0, 1] -> ``(N, 3)`` uint8 (``round(255 c)``)."""
    c = _as_points(colors, "colors").astype(np.float64)
    if not np.all(np.isfinite(c)) or c.size and (c.min() < 0.0 or c.max() > 1.0):
        raise ValidationError("colors: expected finite floats in [0, 1]")
    return np.rint(c * 255.0).astype(np.uint8)


def colors_from_uint8(rgb: np.ndarray) -> np.ndarray:
    """``(N, 3)`` uint8 -> float32 in [0, 1]."""
    return (np.asarray(rgb, dtype=np.float32) / 255.0).astype(np.float32)


def cloud_to_proto(
    points: np.ndarray, colors: np.ndarray | None = None, labels: np.ndarray | None = None
) -> pb.PointCloud:
    """Pack ``points (N, 3)``, ``colors (N, 3)`` in [0, 1] and ``labels (N,)`` into a PointCloud."""
    pts = _as_points(points)
    n = pts.shape[0]
    msg = pb.PointCloud(num_points=n, xyz=np.ascontiguousarray(pts, dtype=F32).tobytes())
    if colors is not None:
        rgb = colors_to_uint8(colors)
        if rgb.shape[0] != n:
            raise ValidationError(f"colors: expected shape ({n}, 3) like points, got {rgb.shape}")
        msg.rgb = rgb.tobytes()
    if labels is not None:
        lab = np.asarray(labels)
        if lab.shape != (n,):
            raise ValidationError(f"labels: expected shape ({n},) like points, got {lab.shape}")
        if (
            lab.size
            and not np.issubdtype(lab.dtype, np.integer)
            and (not np.all(np.isfinite(lab)) or np.any(lab != np.round(lab)))
        ):
            raise ValidationError("labels: expected integers (-1 = background)")
        if lab.size and (lab.min() < np.iinfo(I32).min or lab.max() > np.iinfo(I32).max):
            raise ValidationError("labels: expected values that fit in int32")
        msg.labels = np.ascontiguousarray(lab, dtype=I32).tobytes()
    return msg


def cloud_from_proto(
    msg: pb.PointCloud,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Unpack a PointCloud: ``points (N, 3)`` float32, ``colors (N, 3)`` float32 | None,
    ``labels (N,)`` int32 | None. Byte lengths must match ``num_points``."""
    n = int(msg.num_points)
    if len(msg.xyz) != 12 * n:
        raise ValidationError(
            f"cloud.xyz: expected num_points x 3 float32 = {12 * n} bytes, got {len(msg.xyz)} bytes"
        )
    points = np.frombuffer(msg.xyz, dtype=F32).reshape(n, 3)
    colors = labels = None
    if msg.rgb:
        if len(msg.rgb) != 3 * n:
            raise ValidationError(
                f"cloud.rgb: expected num_points x 3 uint8 = {3 * n} bytes, got {len(msg.rgb)}"
            )
        colors = colors_from_uint8(np.frombuffer(msg.rgb, dtype=np.uint8).reshape(n, 3))
    if msg.labels:
        if len(msg.labels) != 4 * n:
            raise ValidationError(
                f"cloud.labels: expected num_points int32 = {4 * n} bytes, got {len(msg.labels)}"
            )
        labels = np.frombuffer(msg.labels, dtype=I32).astype(np.int32)
    return points.astype(np.float32), colors, labels


# --- small geometry types -------------------------------------------------------------------------


def vec3_to_proto(v) -> pb.Vector3:
    x, y, z = (float(c) for c in np.asarray(v, dtype=np.float64).reshape(3))
    return pb.Vector3(x=x, y=y, z=z)


def vec3_from_proto(msg: pb.Vector3) -> tuple[float, float, float]:
    return (msg.x, msg.y, msg.z)


def poses_to_proto(matrices) -> list[pb.Pose]:
    """4 x 4 object-to-world matrices ``(N, 4, 4)`` -> Poses (xyzw quaternion, w >= 0).

    All rotations go through one batched :func:`matrix_to_quat` call: per-pose calls on tiny
    tensors cost ~0.3 ms each, a noticeable share of a /recognize response.
    """
    T = np.asarray(matrices, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValidationError(f"pose: expected shape (4, 4), got {T.shape[1:]}")
    if not len(T):
        return []
    q = matrix_to_quat(torch.as_tensor(T[:, :3, :3])).tolist()
    return [
        pb.Pose(
            position=vec3_to_proto(t[:3, 3]),
            orientation=pb.Quaternion(x=x, y=y, z=z, w=w),
        )
        for t, (x, y, z, w) in zip(T, q, strict=True)
    ]


def pose_to_proto(matrix: np.ndarray) -> pb.Pose:
    """4 x 4 object-to-world matrix -> Pose (position, xyzw quaternion with w >= 0)."""
    T = np.asarray(matrix, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValidationError(f"pose: expected shape (4, 4), got {T.shape}")
    return poses_to_proto(T[None])[0]


def poses_from_proto(msgs: Sequence[pb.Pose]) -> np.ndarray:
    """Poses -> ``(N, 4, 4)`` matrices (one batched :func:`quat_to_matrix` call); an unset
    orientation (all zero) is the identity rotation."""
    quat = np.array(
        [(m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w) for m in msgs],
        dtype=np.float64,
    ).reshape(-1, 4)
    if not np.all(np.isfinite(quat)):
        raise ValidationError("pose.orientation: expected finite values")
    T = np.tile(np.eye(4), (len(msgs), 1, 1))
    rotated = np.linalg.norm(quat, axis=1) > 0
    if rotated.any():
        T[rotated, :3, :3] = quat_to_matrix(torch.as_tensor(quat[rotated])).numpy()
    T[:, :3, 3] = np.array([vec3_from_proto(m.position) for m in msgs]).reshape(-1, 3)
    return T


def pose_from_proto(msg: pb.Pose) -> np.ndarray:
    """Pose -> 4 x 4 matrix; an unset orientation (all zero) is the identity rotation."""
    return poses_from_proto([msg])[0]


def superquadrics_to_proto(parts: Sequence[Superquadric]) -> list[pb.Superquadric]:
    """Superquadrics -> protos, the poses converted in one batch."""
    poses = poses_to_proto(np.array([sq.pose for sq in parts]).reshape(-1, 4, 4))
    return [
        pb.Superquadric(
            kind=KIND_TO_PROTO[sq.kind],
            a1=sq.size[0],
            a2=sq.size[1],
            a3=sq.size[2],
            a4=sq.a4,
            e1=sq.shape[0],
            e2=sq.shape[1],
            taper=sq.taper,
            bend=sq.bend,
            bend_direction=sq.bend_direction,
            pose=pose,
        )
        for sq, pose in zip(parts, poses, strict=True)
    ]


def superquadric_to_proto(sq: Superquadric) -> pb.Superquadric:
    return superquadrics_to_proto([sq])[0]


def superquadrics_from_proto(msgs: Sequence[pb.Superquadric]) -> list[Superquadric]:
    """Protos -> superquadrics, the poses converted in one batch."""
    for msg in msgs:
        if msg.kind not in KIND_FROM_PROTO:
            raise ValidationError(f"superquadric.kind: expected one of {sorted(KIND_TO_PROTO)}")
    poses = poses_from_proto([m.pose for m in msgs])
    try:
        return [
            Superquadric(
                size=(msg.a1, msg.a2, msg.a3),
                shape=(msg.e1, msg.e2),
                pose=pose,
                kind=KIND_FROM_PROTO[msg.kind],
                taper=msg.taper,
                bend=msg.bend,
                bend_direction=msg.bend_direction,
                a4=msg.a4,
            )
            for msg, pose in zip(msgs, poses, strict=True)
        ]
    except ValueError as exc:
        raise ValidationError(f"superquadric: {exc}") from None


def superquadric_from_proto(msg: pb.Superquadric) -> Superquadric:
    return superquadrics_from_proto([msg])[0]


def workspace_to_proto(ws: Workspace) -> pb.Workspace:
    return pb.Workspace(min=vec3_to_proto(ws.min), max=vec3_to_proto(ws.max))


def workspace_from_proto(msg: pb.Workspace) -> Workspace:
    return Workspace(min=vec3_from_proto(msg.min), max=vec3_from_proto(msg.max))


# --- recognition --------------------------------------------------------------------------------


def options_to_proto(opts: RecognizeOptions) -> perception_pb.RecognizeOptions:
    return perception_pb.RecognizeOptions(
        method=opts.method,
        segmentation=opts.segmentation,
        points_per_segment=opts.points_per_segment,
        remove_support=opts.remove_support,
        amodal=opts.amodal,
        deformable=opts.deformable,
        seed=opts.seed,
    )


def options_from_proto(
    msg: perception_pb.RecognizeOptions, *, has_labels: bool = False
) -> RecognizeOptions:
    """Unset fields take the :class:`RecognizeOptions` defaults; segmentation defaults to
    ``labels`` when the request carries labels."""
    default = RecognizeOptions()
    kwargs: dict[str, object] = {}
    if msg.method:
        kwargs["method"] = msg.method
    if msg.segmentation:
        kwargs["segmentation"] = msg.segmentation
    elif has_labels:
        kwargs["segmentation"] = "labels"
    for name in ("points_per_segment", "remove_support", "amodal", "deformable", "seed"):
        if msg.HasField(name):
            kwargs[name] = getattr(msg, name)
    if not kwargs:
        return default
    return RecognizeOptions(**kwargs)  # type: ignore[arg-type]


def recognize_request_to_proto(req: RecognizeRequest) -> perception_pb.RecognizeRequest:
    msg = perception_pb.RecognizeRequest(
        cloud=cloud_to_proto(req.points, req.colors, req.labels),
        options=options_to_proto(req.options),
    )
    if req.viewpoint is not None:
        vp = np.asarray(req.viewpoint, dtype=np.float64)
        if vp.shape != (3,):
            raise ValidationError(f"viewpoint: expected shape (3,), got {vp.shape}")
        msg.viewpoint.CopyFrom(vec3_to_proto(vp))
    if req.workspace is not None:
        msg.workspace.CopyFrom(workspace_to_proto(req.workspace))
    return msg


def recognize_request_from_proto(msg: perception_pb.RecognizeRequest) -> RecognizeRequest:
    points, colors, labels = cloud_from_proto(msg.cloud)
    return RecognizeRequest(
        points=points,
        colors=colors,
        labels=labels,
        viewpoint=np.array(vec3_from_proto(msg.viewpoint)) if msg.HasField("viewpoint") else None,
        workspace=workspace_from_proto(msg.workspace) if msg.HasField("workspace") else None,
        options=options_from_proto(msg.options, has_labels=labels is not None),
    )


def recognized_object_to_proto(
    obj: RecognizedObject, parts: Sequence[pb.Superquadric] | None = None
) -> pb.RecognizedObject:
    """``parts``: the object's parts already converted (a whole scene's in one batch)."""
    idx = np.asarray(obj.point_indices).reshape(-1)
    msg = pb.RecognizedObject(
        id=int(obj.id),
        parts=superquadrics_to_proto(obj.parts) if parts is None else parts,
        point_indices=np.ascontiguousarray(idx, dtype=I32).tobytes(),
        residual=float(obj.residual),
        confidence=float(obj.confidence),
    )
    if obj.mean_color is not None:
        r, g, b = (float(c) for c in obj.mean_color)
        msg.mean_color.CopyFrom(pb.Color(r=r, g=g, b=b))
    return msg


def recognized_object_from_proto(
    msg: pb.RecognizedObject, parts: Sequence[Superquadric] | None = None
) -> RecognizedObject:
    """``parts``: the object's parts already converted (a whole scene's in one batch)."""
    if len(msg.point_indices) % 4:
        raise ValidationError(
            f"point_indices: expected int32 (a multiple of 4 bytes), got {len(msg.point_indices)}"
        )
    color = msg.mean_color
    return RecognizedObject(
        id=msg.id,
        parts=superquadrics_from_proto(msg.parts) if parts is None else list(parts),
        point_indices=np.frombuffer(msg.point_indices, dtype=I32).astype(np.int64),
        mean_color=(color.r, color.g, color.b) if msg.HasField("mean_color") else None,
        residual=msg.residual,
        confidence=msg.confidence,
    )


def split_by_counts(items: list, counts: list[int]) -> list[list]:
    """``items`` cut into consecutive runs of ``counts`` (a flat batch back per owner)."""
    ends = np.cumsum(counts).tolist()
    return [items[e - n : e] for n, e in zip(counts, ends, strict=True)]


def support_plane_to_proto(plane: SupportPlane) -> pb.SupportPlane:
    return pb.SupportPlane(normal=vec3_to_proto(plane.normal), offset=float(plane.offset))


def support_plane_from_proto(msg: pb.SupportPlane) -> SupportPlane:
    return SupportPlane(normal=vec3_from_proto(msg.normal), offset=msg.offset)


def scene_to_proto(scene: Scene) -> pb.Scene:
    counts = [len(o.parts) for o in scene.objects]
    parts = split_by_counts(
        superquadrics_to_proto([p for o in scene.objects for p in o.parts]), counts
    )
    msg = pb.Scene(
        objects=[
            recognized_object_to_proto(o, p) for o, p in zip(scene.objects, parts, strict=True)
        ]
    )
    if scene.support_plane is not None:
        msg.support_plane.CopyFrom(support_plane_to_proto(scene.support_plane))
    timings: Mapping[str, float] = scene.timings_ms or {}
    for k, v in timings.items():
        msg.timings_ms[str(k)] = float(v)
    return msg


def scene_from_proto(msg: pb.Scene) -> Scene:
    counts = [len(o.parts) for o in msg.objects]
    parts = split_by_counts(
        superquadrics_from_proto([p for o in msg.objects for p in o.parts]), counts
    )
    return Scene(
        objects=[
            recognized_object_from_proto(o, p) for o, p in zip(msg.objects, parts, strict=True)
        ],
        support_plane=(
            support_plane_from_proto(msg.support_plane) if msg.HasField("support_plane") else None
        ),
        timings_ms=dict(msg.timings_ms),
    )


# --- simulator (sim.proto) -------------------------------------------------------------------------
#
# Scene specs travel as JSON text (``SceneSpec.to_dict()``); images and clouds as packed
# little-endian planes: depth float32 H x W, rgb uint8 H x W x 3, segmentation int32 H x W, the
# cloud as the common PointCloud (float32 xyz, int32 labels = per-point object ids) plus int32
# ``point_pixels``. Points are float64 in the domain and float32 on the wire.

SIM_RANDOM_OBJECT_KINDS = ("box", "cylinder", "superquadric")
"""Object kinds the random scene generator can draw (meshes need a path: give a spec)."""


def scene_spec_to_json(spec: SceneSpec) -> str:
    """SceneSpec -> the JSON text of ``scene_json`` fields (``SceneSpec.to_dict()``)."""
    return json.dumps(spec.to_dict(), allow_nan=False)


def scene_spec_from_json(text: str, field: str = "scene_json") -> SceneSpec:
    """JSON text -> SceneSpec; bad JSON or unknown fields raise ValidationError naming ``field``."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValidationError(f"{field}: not valid JSON ({exc})") from None
    return scene_spec_from_dict(data, field)


def scene_spec_from_dict(data: Any, field: str = "scene") -> SceneSpec:
    """``SceneSpec.to_dict()`` form -> SceneSpec; every problem is a ValidationError naming
    ``field`` (wrong types included, which the dataclasses would raise as TypeError)."""
    if not isinstance(data, Mapping):
        raise ValidationError(f"{field}: expected a JSON object, got {type(data).__name__}")
    from sqmanip.sim.scene import SceneSpec

    try:
        return SceneSpec.from_dict(dict(data))
    except ValidationError as exc:
        raise ValidationError(f"{field}: {exc.message}") from None
    except (TypeError, ValueError, AttributeError) as exc:
        raise ValidationError(f"{field}: {exc}") from None


def intrinsics_to_proto(k: Intrinsics) -> sim_pb.CameraIntrinsics:
    return sim_pb.CameraIntrinsics(
        width=int(k.width),
        height=int(k.height),
        fx=float(k.fx),
        fy=float(k.fy),
        cx=float(k.cx),
        cy=float(k.cy),
        near=float(k.near),
        far=float(k.far),
    )


def intrinsics_from_proto(msg: sim_pb.CameraIntrinsics) -> Intrinsics:
    """Intrinsics (validated by the domain: sizes 1..4096 px, fx, fy > 0, 0 < near < far)."""
    return Intrinsics(msg.width, msg.height, msg.fx, msg.fy, msg.cx, msg.cy, msg.near, msg.far)


def object_state_to_proto(obj: ObjectState) -> sim_pb.ObjectState:
    msg = sim_pb.ObjectState(
        id=int(obj.id), name=obj.name, kind=obj.kind, pose=pose_to_proto(obj.pose)
    )
    if obj.superquadric is not None:
        msg.superquadric.CopyFrom(superquadric_to_proto(obj.superquadric))
    return msg


def object_state_from_proto(msg: sim_pb.ObjectState) -> ObjectState:
    T = pose_from_proto(msg.pose)
    q = msg.pose.orientation
    quat = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    quat = quat / np.linalg.norm(quat) if np.linalg.norm(quat) > 0 else np.array([0, 0, 0, 1.0])
    return ObjectState(
        id=msg.id,
        name=msg.name,
        kind=msg.kind,
        pose=T,
        position=T[:3, 3].copy(),
        quaternion=quat,
        superquadric=(
            superquadric_from_proto(msg.superquadric) if msg.HasField("superquadric") else None
        ),
    )


def sim_state_to_proto(state: SimState) -> sim_pb.SimState:
    msg = sim_pb.SimState(
        time=float(state.time),
        scene_kind=state.scene_kind,
        objects=[object_state_to_proto(o) for o in state.objects],
        joint_positions=np.asarray(state.joint_positions, dtype=np.float64).reshape(-1).tolist(),
        gripper_width=float(state.gripper_width),
        tcp_pose=pose_to_proto(state.tcp_pose),
    )
    if state.held_object is not None:
        msg.held_object = int(state.held_object)
    return msg


def sim_state_from_proto(msg: sim_pb.SimState) -> SimState:
    return SimState(
        time=msg.time,
        scene_kind=msg.scene_kind,
        objects=tuple(object_state_from_proto(o) for o in msg.objects),
        joint_positions=np.asarray(msg.joint_positions, dtype=np.float64),
        gripper_width=msg.gripper_width,
        tcp_pose=pose_from_proto(msg.tcp_pose),
        held_object=msg.held_object if msg.HasField("held_object") else None,
    )


def action_result_to_proto(result: ActionResult) -> sim_pb.ActionResult:
    msg = sim_pb.ActionResult(
        success=bool(result.success),
        message=result.message,
        before=sim_state_to_proto(result.before),
        after=sim_state_to_proto(result.after),
        sim_time=float(result.sim_time),
    )
    if result.held_object is not None:
        msg.held_object = int(result.held_object)
    return msg


def action_result_from_proto(msg: sim_pb.ActionResult) -> ActionResult:
    return ActionResult(
        success=msg.success,
        message=msg.message,
        before=sim_state_from_proto(msg.before),
        after=sim_state_from_proto(msg.after),
        held_object=msg.held_object if msg.HasField("held_object") else None,
        sim_time=msg.sim_time,
    )


def _plane(data: bytes, dtype: np.dtype, shape: tuple[int, ...], field: str) -> np.ndarray:
    expected = int(np.prod(shape)) * dtype.itemsize
    if len(data) != expected:
        shape_text = " x ".join(str(s) for s in shape)
        raise ValidationError(
            f"{field}: expected {shape_text} {dtype.name} = {expected} bytes, got {len(data)} bytes"
        )
    return np.frombuffer(data, dtype=dtype).reshape(shape)


def observation_to_proto(obs: Observation) -> sim_pb.Observation:
    """Pack an Observation: images as byte planes, the cloud with its object ids as labels."""
    h, w = obs.depth.shape
    for name, arr, shape in (
        ("rgb", obs.rgb, (h, w, 3)),
        ("segmentation", obs.segmentation, (h, w)),
    ):
        if arr.shape != shape:
            raise ValidationError(f"observation.{name}: expected shape {shape}, got {arr.shape}")
    n = obs.points.shape[0]
    if obs.point_pixels.shape != (n,):
        raise ValidationError(
            f"observation.point_pixels: expected shape ({n},) like points, "
            f"got {obs.point_pixels.shape}"
        )
    return sim_pb.Observation(
        camera=obs.camera,
        intrinsics=intrinsics_to_proto(obs.intrinsics),
        camera_pose=pose_to_proto(obs.camera_pose),
        height=h,
        width=w,
        depth=np.ascontiguousarray(obs.depth, dtype=F32).tobytes(),
        rgb=np.ascontiguousarray(obs.rgb, dtype=np.uint8).tobytes(),
        segmentation=np.ascontiguousarray(obs.segmentation, dtype=I32).tobytes(),
        cloud=cloud_to_proto(obs.points, labels=obs.point_labels),
        point_pixels=np.ascontiguousarray(obs.point_pixels, dtype=I32).tobytes(),
        objects=[object_state_to_proto(o) for o in obs.objects],
        time=float(obs.time),
    )


def observation_from_proto(msg: sim_pb.Observation) -> Observation:
    """Unpack an Observation (arrays are copies: writable, native dtypes; points float64)."""
    h, w = int(msg.height), int(msg.width)
    points, _, labels = cloud_from_proto(msg.cloud)
    n = points.shape[0]
    if labels is None:
        labels = np.full(n, -1, dtype=np.int32)
    return Observation(
        camera=msg.camera,
        intrinsics=intrinsics_from_proto(msg.intrinsics),
        camera_pose=pose_from_proto(msg.camera_pose),
        depth=_plane(msg.depth, F32, (h, w), "observation.depth").astype(np.float32),
        rgb=_plane(msg.rgb, np.dtype(np.uint8), (h, w, 3), "observation.rgb").copy(),
        segmentation=_plane(msg.segmentation, I32, (h, w), "observation.segmentation").astype(
            np.int32
        ),
        points=points.astype(np.float64),
        point_labels=labels,
        point_pixels=_plane(msg.point_pixels, I32, (n,), "observation.point_pixels").astype(
            np.int64
        ),
        objects=tuple(object_state_from_proto(o) for o in msg.objects),
        time=msg.time,
    )


def reset_request_to_proto(
    scene: SceneSpec | Mapping | None = None,
    *,
    seed: int | None = None,
    n_objects: int | None = None,
    kind: str = "",
    object_kinds: tuple[str, ...] | list[str] = (),
) -> sim_pb.ResetRequest:
    """Arguments of :meth:`Simulator.reset` -> ResetRequest (``scene`` as spec or its dict)."""
    msg = sim_pb.ResetRequest(kind=kind, object_kinds=list(object_kinds))
    if scene is not None:
        from sqmanip.sim.scene import SceneSpec

        spec = scene if isinstance(scene, SceneSpec) else scene_spec_from_dict(scene)
        msg.scene_json = scene_spec_to_json(spec)
    if seed is not None:
        msg.seed = int(seed)
    if n_objects is not None:
        if n_objects < 0:
            raise ValidationError(f"n_objects must be in 0..20, got {n_objects}")
        msg.n_objects = int(n_objects)
    return msg


def reset_request_from_proto(msg: sim_pb.ResetRequest) -> dict[str, Any]:
    """ResetRequest -> keyword arguments of :meth:`Simulator.reset` (unset fields: defaults)."""
    kwargs: dict[str, Any] = {
        "scene": scene_spec_from_json(msg.scene_json) if msg.scene_json else None,
        "seed": msg.seed if msg.HasField("seed") else None,
    }
    if msg.HasField("n_objects"):
        kwargs["n_objects"] = int(msg.n_objects)
    if msg.kind:
        from sqmanip.sim.scene import SCENE_KINDS

        if msg.kind not in SCENE_KINDS:
            raise ValidationError(f"kind: expected one of {SCENE_KINDS}, got {msg.kind!r}")
        kwargs["kind"] = msg.kind
    if msg.object_kinds:
        bad = [k for k in msg.object_kinds if k not in SIM_RANDOM_OBJECT_KINDS]
        if bad:
            raise ValidationError(
                f"object_kinds: expected values from {SIM_RANDOM_OBJECT_KINDS}, got {bad}"
            )
        kwargs["object_kinds"] = tuple(msg.object_kinds)
    return kwargs


def observe_request_to_proto(
    camera: str = "default",
    *,
    intrinsics: Intrinsics | None = None,
    camera_pose: np.ndarray | None = None,
    noise: bool = True,
) -> sim_pb.ObserveRequest:
    msg = sim_pb.ObserveRequest(camera=camera, noise=bool(noise))
    if intrinsics is not None:
        msg.intrinsics.CopyFrom(intrinsics_to_proto(intrinsics))
    if camera_pose is not None:
        msg.camera_pose.CopyFrom(pose_to_proto(camera_pose))
    return msg


def observe_request_from_proto(msg: sim_pb.ObserveRequest) -> dict[str, Any]:
    """ObserveRequest -> keyword arguments of :meth:`Simulator.observe`."""
    return {
        "camera": msg.camera or "default",
        "intrinsics": intrinsics_from_proto(msg.intrinsics) if msg.HasField("intrinsics") else None,
        "camera_pose": pose_from_proto(msg.camera_pose) if msg.HasField("camera_pose") else None,
        "noise": msg.noise if msg.HasField("noise") else True,
    }


def _required_pose(msg: Any, field: str) -> np.ndarray:
    if not msg.HasField(field):
        raise ValidationError(f"{field}: required (a tool pose: position and orientation)")
    return pose_from_proto(getattr(msg, field))


def push_request_to_proto(p, v, upright: bool = False) -> sim_pb.PushRequest:
    return sim_pb.PushRequest(p=vec3_to_proto(p), v=vec3_to_proto(v), upright=bool(upright))


def push_request_from_proto(msg: sim_pb.PushRequest) -> tuple[np.ndarray, np.ndarray, bool]:
    """PushRequest -> ``(p (3,), v (3,), upright)``; ``p`` and ``v`` are required."""
    for field in ("p", "v"):
        if not msg.HasField(field):
            raise ValidationError(f"{field}: required (x, y, z in metres, world frame)")
    return np.array(vec3_from_proto(msg.p)), np.array(vec3_from_proto(msg.v)), msg.upright


def grasp_request_to_proto(pose: np.ndarray, width: float) -> sim_pb.GraspRequest:
    return sim_pb.GraspRequest(pose=pose_to_proto(pose), width=float(width))


def grasp_request_from_proto(msg: sim_pb.GraspRequest) -> tuple[np.ndarray, float]:
    """GraspRequest -> ``(tool pose 4 x 4, width)``."""
    return _required_pose(msg, "pose"), msg.width


def pick_and_place_request_to_proto(
    grasp_pose: np.ndarray, width: float, place_pose: np.ndarray
) -> sim_pb.PickAndPlaceRequest:
    return sim_pb.PickAndPlaceRequest(
        grasp_pose=pose_to_proto(grasp_pose),
        width=float(width),
        place_pose=pose_to_proto(place_pose),
    )


def pick_and_place_request_from_proto(
    msg: sim_pb.PickAndPlaceRequest,
) -> tuple[np.ndarray, float, np.ndarray]:
    """PickAndPlaceRequest -> ``(grasp pose, width, place pose)``."""
    return (
        _required_pose(msg, "grasp_pose"),
        msg.width,
        _required_pose(msg, "place_pose"),
    )


# --- grasp planner (grasp.proto) ----------------------------------------------------------------
#
# A PlanGraspsRequest carries the scene's objects and the id of the target; the domain call takes
# the target's parts and the others' parts as obstacles. Unset option/gripper fields take the
# domain defaults (PlanOptions, PANDA_HAND); ``max_results`` 0 on the wire is "all" (None).


_LEADING_NAME = re.compile(r"^([A-Za-z_][A-Za-z0-9_.\[\]]*)(:?)\s+(.*)$", re.S)


def field_message(prefix: str, message: str) -> str:
    """``"n_samples must be >= 1"`` -> ``"options.n_samples: must be >= 1"``: a domain message that
    starts with a field name, rewritten to name the field under ``prefix`` first (the gateway
    reads the field from ``"<field>: ..."``)."""
    m = _LEADING_NAME.match(message)
    if m is None:
        return f"{prefix}: {message}"
    return f"{prefix}.{m.group(1)}: {m.group(3)}"


def _finite_superquadric(msg: pb.Superquadric, field: str) -> Superquadric:
    """A Superquadric with every number finite; errors name ``field`` (e.g. ``objects[1].parts[0]``)."""
    p, q = msg.pose.position, msg.pose.orientation
    values = (msg.a1, msg.a2, msg.a3, msg.a4, msg.e1, msg.e2, msg.taper, msg.bend,
              msg.bend_direction, p.x, p.y, p.z, q.x, q.y, q.z, q.w)  # fmt: skip
    if not all(np.isfinite(values)):
        raise ValidationError(f"{field}: expected finite numbers (size, shape, pose)")
    try:
        return superquadric_from_proto(msg)
    except ValidationError as exc:
        raise ValidationError(f"{field}: {exc.message.removeprefix('superquadric: ')}") from None


def gripper_spec_to_proto(spec: GripperSpec) -> grasp_pb.GripperSpec:
    return grasp_pb.GripperSpec(
        max_opening=spec.max_opening,
        finger_length=spec.finger_length,
        finger_width=spec.finger_width,
        finger_thickness=spec.finger_thickness,
        tip_offset=spec.tip_offset,
        palm_size=vec3_to_proto(spec.palm_size),
        wrist_radius=spec.wrist_radius,
        wrist_length=spec.wrist_length,
    )


_GRIPPER_SCALARS = ("max_opening", "finger_length", "finger_width", "finger_thickness",
                    "tip_offset", "wrist_radius", "wrist_length")  # fmt: skip


def gripper_spec_from_proto(msg: grasp_pb.GripperSpec) -> GripperSpec:
    """Unset fields take the Franka hand's values; invalid ones raise naming ``gripper.<field>``."""
    kwargs: dict[str, Any] = {n: getattr(msg, n) for n in _GRIPPER_SCALARS if msg.HasField(n)}
    if msg.HasField("palm_size"):
        kwargs["palm_size"] = vec3_from_proto(msg.palm_size)
    if not kwargs:
        return PANDA_HAND
    try:
        return dataclasses.replace(PANDA_HAND, **kwargs)
    except ValidationError as exc:
        raise ValidationError(field_message("gripper", exc.message)) from None


def environment_to_proto(env: Environment) -> grasp_pb.GraspEnvironment:
    msg = grasp_pb.GraspEnvironment(
        boxes=[superquadric_to_proto(b) for b in env.boxes], up=vec3_to_proto(env.up)
    )
    if env.support_normal is not None:
        msg.support_plane.CopyFrom(
            pb.SupportPlane(normal=vec3_to_proto(env.support_normal), offset=env.support_offset)
        )
    return msg


def environment_from_proto(
    msg: grasp_pb.GraspEnvironment, objects: tuple[tuple[Superquadric, ...], ...] = ()
) -> Environment:
    """GraspEnvironment (+ the obstacle objects) -> Environment; unset plane = no plane."""
    kwargs: dict[str, Any] = {
        "boxes": tuple(
            _finite_superquadric(b, f"environment.boxes[{i}]") for i, b in enumerate(msg.boxes)
        ),
        "objects": objects,
    }
    if msg.HasField("support_plane"):
        kwargs["support_normal"] = vec3_from_proto(msg.support_plane.normal)
        kwargs["support_offset"] = msg.support_plane.offset
    else:
        kwargs["support_normal"] = None
    if msg.HasField("up"):
        kwargs["up"] = vec3_from_proto(msg.up)
    try:
        return Environment(**kwargs)
    except ValidationError as exc:
        raise ValidationError(field_message("environment", exc.message)) from None


_RULE_FIELDS = ("top_down", "side", "per_direction", "max_candidates", "max_width", "spread",
                "grasp_depth", "tilt", "facing_angle", "round_threshold",
                "antipodal_threshold")  # fmt: skip
_PLAN_FIELDS = ("n_samples", "n_approach", "antipodal_threshold", "beta", "seed",
                "gripper_points", "include_wrist", "approach_distance", "support_clearance",
                "min_width", "check_target")  # fmt: skip


def rule_options_to_proto(rule: RuleOptions) -> grasp_pb.RuleOptions:
    msg = grasp_pb.RuleOptions(**{n: getattr(rule, n) for n in _RULE_FIELDS})
    if rule.facing is not None:
        msg.facing.CopyFrom(vec3_to_proto(rule.facing))
    return msg


def rule_options_from_proto(msg: grasp_pb.RuleOptions) -> RuleOptions:
    kwargs: dict[str, Any] = {n: getattr(msg, n) for n in _RULE_FIELDS if msg.HasField(n)}
    if msg.HasField("facing"):
        kwargs["facing"] = vec3_from_proto(msg.facing)
    try:
        return RuleOptions(**kwargs)
    except ValidationError as exc:
        raise ValidationError(field_message("options.rule", exc.message)) from None


def plan_options_to_proto(
    opts: PlanOptions, *, check_reachability: bool = True
) -> grasp_pb.GraspPlanOptions:
    msg = grasp_pb.GraspPlanOptions(
        **{n: getattr(opts, n) for n in _PLAN_FIELDS},
        max_results=0 if opts.max_results is None else int(opts.max_results),
        score=opts.score,
        method=opts.method,
        check_reachability=bool(check_reachability),
        rule=rule_options_to_proto(opts.rule),
    )
    return msg


def plan_options_from_proto(msg: grasp_pb.GraspPlanOptions) -> PlanOptions:
    """Unset fields take :class:`PlanOptions` defaults (``max_results`` 0 = all)."""
    kwargs: dict[str, Any] = {n: getattr(msg, n) for n in _PLAN_FIELDS if msg.HasField(n)}
    if msg.HasField("max_results"):
        kwargs["max_results"] = None if msg.max_results == 0 else int(msg.max_results)
    if msg.score:
        kwargs["score"] = msg.score
    if msg.method:
        kwargs["method"] = msg.method
    if msg.HasField("rule"):
        kwargs["rule"] = rule_options_from_proto(msg.rule)
    if not kwargs:
        return PlanOptions()
    try:
        return PlanOptions(**kwargs)
    except ValidationError as exc:
        raise ValidationError(field_message("options", exc.message)) from None


def _parts_object(object_id: int, parts: Sequence[Superquadric]) -> pb.RecognizedObject:
    return pb.RecognizedObject(id=int(object_id), parts=[superquadric_to_proto(p) for p in parts])


def plan_grasps_request_to_proto(
    target: Sequence[Superquadric] | RecognizedObject,
    obstacles: Sequence[Sequence[Superquadric] | RecognizedObject] = (),
    environment: Environment | None = None,
    gripper: GripperSpec | None = None,
    options: PlanOptions | None = None,
    observed_points: np.ndarray | None = None,
    *,
    check_reachability: bool = True,
) -> grasp_pb.PlanGraspsRequest:
    """Arguments of :meth:`GraspPlanner.plan` -> PlanGraspsRequest.

    ``target`` and each obstacle are a list of parts or a RecognizedObject. Recognized objects
    keep their ids (the target's is ``target_id``); bare part lists get ids 0 (target), 1, 2...
    """

    def as_object(obj, default_id: int) -> pb.RecognizedObject:
        if isinstance(obj, RecognizedObject):
            return recognized_object_to_proto(obj)
        return _parts_object(default_id, obj)

    tgt = as_object(target, 0)
    objs = [tgt]
    used = {tgt.id}
    next_id = 1
    for obs in obstacles:
        msg = as_object(obs, next_id)
        if not isinstance(obs, RecognizedObject):
            while msg.id in used:
                msg.id += 1
        if msg.id in used:
            raise ValidationError(f"obstacles: object id {msg.id} is used twice")
        used.add(msg.id)
        next_id = msg.id + 1
        objs.append(msg)
    env = environment if environment is not None else Environment()
    req = grasp_pb.PlanGraspsRequest(
        objects=objs,
        target_id=tgt.id,
        environment=environment_to_proto(env),
        gripper=gripper_spec_to_proto(gripper or PANDA_HAND),
        options=plan_options_to_proto(
            options or PlanOptions(), check_reachability=check_reachability
        ),
    )
    if observed_points is not None:
        req.observed_points.CopyFrom(cloud_to_proto(_as_points(observed_points, "observed_points")))
    return req


@dataclasses.dataclass(frozen=True)
class PlanGraspsArgs:
    """A decoded PlanGraspsRequest: the arguments of :meth:`GraspPlanner.plan_detailed`."""

    target_id: int
    target: tuple[Superquadric, ...]
    obstacles: tuple[tuple[Superquadric, ...], ...]
    environment: Environment
    gripper: GripperSpec
    options: PlanOptions
    observed_points: np.ndarray | None
    check_reachability: bool


def plan_grasps_request_from_proto(msg: grasp_pb.PlanGraspsRequest) -> PlanGraspsArgs:
    """PlanGraspsRequest -> :class:`PlanGraspsArgs`.

    Raises ValidationError (bad values, duplicate ids, a target without parts) naming the field,
    NotFoundError when ``target_id`` is not among ``objects``.
    """
    ids = [o.id for o in msg.objects]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise ValidationError(f"objects: ids must be unique, {dup} appear more than once")
    if msg.target_id not in ids:
        raise NotFoundError(f"target_id: no object with id {msg.target_id} (objects have {ids})")
    target: tuple[Superquadric, ...] = ()
    obstacles: list[tuple[Superquadric, ...]] = []
    for i, o in enumerate(msg.objects):
        parts = tuple(
            _finite_superquadric(p, f"objects[{i}].parts[{j}]") for j, p in enumerate(o.parts)
        )
        if o.id == msg.target_id:
            target = parts
        elif parts:
            obstacles.append(parts)
    if not target:
        raise ValidationError(f"objects[{ids.index(msg.target_id)}].parts: the target has no parts")
    observed = None
    if msg.HasField("observed_points"):
        observed = cloud_from_proto(msg.observed_points)[0].astype(np.float64)
        if not np.isfinite(observed).all():
            raise ValidationError("observed_points: expected finite numbers")
    opts = msg.options
    return PlanGraspsArgs(
        target_id=int(msg.target_id),
        target=target,
        obstacles=tuple(obstacles),
        environment=environment_from_proto(msg.environment),
        gripper=gripper_spec_from_proto(msg.gripper),
        options=plan_options_from_proto(opts),
        observed_points=observed,
        check_reachability=opts.check_reachability if opts.HasField("check_reachability") else True,
    )


def grasp_to_proto(grasp: Grasp) -> grasp_pb.Grasp:
    msg = grasp_pb.Grasp(pose=pose_to_proto(grasp.pose), width=float(grasp.width),
                         score=float(grasp.score))  # fmt: skip
    if grasp.contacts is not None:
        msg.contacts.extend(vec3_to_proto(c) for c in np.asarray(grasp.contacts).reshape(-1, 3))
    if grasp.uncertainty is not None:
        msg.uncertainty = float(grasp.uncertainty)
    return msg


def grasp_from_proto(msg: grasp_pb.Grasp) -> Grasp:
    contacts = None
    if len(msg.contacts):
        contacts = np.array([vec3_from_proto(c) for c in msg.contacts], dtype=np.float64)
    return Grasp(
        pose=pose_from_proto(msg.pose),
        width=msg.width,
        score=msg.score,
        contacts=contacts,
        uncertainty=msg.uncertainty if msg.HasField("uncertainty") else None,
    )


def plan_stats_to_proto(stats: PlanStats) -> grasp_pb.GraspPlanStats:
    msg = grasp_pb.GraspPlanStats(
        n_samples=stats.n_samples,
        n_pairs=stats.n_pairs,
        n_candidates=stats.n_candidates,
        n_checked=stats.n_checked,
        n_unreachable=stats.n_unreachable,
        n_colliding=stats.n_colliding,
    )
    for k, v in stats.collisions.items():
        msg.collisions[str(k)] = int(v)
    for k, v in stats.timings_ms.items():
        msg.timings_ms[str(k)] = float(v)
    return msg


def plan_stats_from_proto(msg: grasp_pb.GraspPlanStats) -> PlanStats:
    return PlanStats(
        n_samples=msg.n_samples,
        n_pairs=msg.n_pairs,
        n_candidates=msg.n_candidates,
        n_checked=msg.n_checked,
        n_unreachable=msg.n_unreachable,
        n_colliding=msg.n_colliding,
        collisions=dict(msg.collisions),
        timings_ms=dict(msg.timings_ms),
    )


def plan_result_to_proto(result: PlanResult, target_id: int = 0) -> grasp_pb.PlanGraspsResponse:
    return grasp_pb.PlanGraspsResponse(
        target_id=int(target_id),
        grasps=[grasp_to_proto(g) for g in result.grasps],
        stats=plan_stats_to_proto(result.stats),
    )


def plan_result_from_proto(msg: grasp_pb.PlanGraspsResponse) -> PlanResult:
    return PlanResult([grasp_from_proto(g) for g in msg.grasps], plan_stats_from_proto(msg.stats))


# --- dynamics (dynamics.proto) ------------------------------------------------------------------
#
# Objects travel as Superquadric messages (shape + current pose); actions as float32 K x 6 and the
# predicted poses as float32 K x N x 4 x 4 packed planes. The domain side is the arguments of
# ``SQPDNet.predict(poses (N, 4, 4), params (N, 9), actions (K, 6), kinds (N,))``.

DYNAMICS_MODELS = ("sqpdnet", "physics")
"""Built-in model names of the Dynamics service (any other name is a checkpoint directory)."""


def _array(value: Any, name: str, shape: tuple[int | None, ...]) -> np.ndarray:
    """``value`` as a finite float64 array of ``shape`` (None = any size); errors name ``name``."""
    try:
        arr = np.asarray(
            value.detach().cpu() if torch.is_tensor(value) else value, dtype=np.float64
        )
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name}: expected numbers of shape {shape} ({exc})") from None
    if arr.ndim != len(shape) or any(
        s is not None and a != s for a, s in zip(arr.shape, shape, strict=True)
    ):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise ValidationError(f"{name}: expected shape {want}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValidationError(f"{name}: expected finite numbers")
    return arr


def predict_request_to_proto(
    poses: Any,
    params: Any,
    actions: Any,
    kinds: Any = None,
    *,
    model: str = "sqpdnet",
    scene_poses: Any = None,
) -> dynamics_pb.PredictRequest:
    """``poses (N, 4, 4)``, ``params (N, 9)``, ``actions (K, 6)`` rows ``(p, v)``, ``kinds (N,)``
    (default superellipsoids) -> PredictRequest. ``scene_poses (K, N, 4, 4)``: push ``k`` acts
    on its own scene (``poses`` then only has to be valid object poses)."""
    T = _array(poses, "poses", (None, 4, 4))
    n = T.shape[0]
    P = _array(params, "params", (n, 9))
    A = _array(actions, "actions", (None, 6))
    K = np.zeros(n, dtype=np.int64) if kinds is None else np.asarray(kinds, dtype=np.int64)
    if K.shape != (n,) or np.any((K < 0) | (K > 2)):
        raise ValidationError(f"kinds: expected ({n},) values in 0, 1, 2, got {K.tolist()}")
    objects = []
    for i in range(n):
        a1, a2, a3, e1, e2, k, b, alpha, a4 = (float(v) for v in P[i])
        try:
            sq = Superquadric(size=(a1, a2, a3), shape=(e1, e2), pose=T[i], kind=KINDS[K[i]],
                              taper=k, bend=b, bend_direction=alpha, a4=a4)  # fmt: skip
        except ValueError as exc:
            raise ValidationError(f"params[{i}]: {exc}") from None
        objects.append(superquadric_to_proto(sq))
    msg = dynamics_pb.PredictRequest(
        objects=objects,
        num_actions=A.shape[0],
        actions=np.ascontiguousarray(A, dtype=F32).tobytes(),
        model=model,
    )
    if scene_poses is not None:
        S = _array(scene_poses, "scene_poses", (A.shape[0], n, 4, 4))
        msg.scene_poses = np.ascontiguousarray(S, dtype=F32).tobytes()
    return msg


@dataclasses.dataclass(frozen=True)
class PredictArgs:
    """A decoded PredictRequest: the arguments of ``SQPDNet.predict`` and the model name."""

    poses: np.ndarray
    """(N, 4, 4) float64."""
    params: np.ndarray
    """(N, 9) float64."""
    kinds: np.ndarray
    """(N,) int64."""
    actions: np.ndarray
    """(K, 6) float32 (the wire precision)."""
    model: str
    scene_poses: np.ndarray | None = None
    """(K, N, 4, 4) float64: one scene per push (``predict_batch``), or None."""


def predict_request_from_proto(msg: dynamics_pb.PredictRequest) -> PredictArgs:
    """PredictRequest -> :class:`PredictArgs`; byte sizes, finiteness and shapes are checked."""
    k = int(msg.num_actions)
    actions = _plane(msg.actions, F32, (k, 6), "actions").astype(np.float32)
    if not np.isfinite(actions).all():
        raise ValidationError("actions: expected finite numbers")
    sqs = [_finite_superquadric(o, f"objects[{i}]") for i, o in enumerate(msg.objects)]
    n = len(sqs)
    poses = np.stack([s.pose for s in sqs]) if n else np.zeros((0, 4, 4))
    params = np.stack([s.params() for s in sqs]) if n else np.zeros((0, 9))
    kinds = np.asarray([s.kind_index for s in sqs], dtype=np.int64)
    scenes = None
    if msg.scene_poses:
        scenes = _plane(msg.scene_poses, F32, (k, n, 4, 4), "scene_poses").astype(np.float64)
        if not np.isfinite(scenes).all():
            raise ValidationError("scene_poses: expected finite numbers")
    return PredictArgs(poses, params, kinds, actions, msg.model or "sqpdnet", scenes)


def predict_response_to_proto(
    next_poses: Any,
    *,
    model: str,
    failed: np.ndarray | None = None,
    latency_ms: float = 0.0,
) -> dynamics_pb.PredictResponse:
    """``next_poses (K, N, 4, 4)`` -> PredictResponse (float32 on the wire)."""
    X = np.asarray(next_poses.detach().cpu() if torch.is_tensor(next_poses) else next_poses)
    if X.ndim != 4 or X.shape[-2:] != (4, 4):
        raise ValidationError(f"poses: expected shape (K, N, 4, 4), got {X.shape}")
    msg = dynamics_pb.PredictResponse(
        num_actions=X.shape[0],
        num_objects=X.shape[1],
        poses=np.ascontiguousarray(X, dtype=F32).tobytes(),
        model=model,
        latency_ms=float(latency_ms),
    )
    if failed is not None:
        f = np.asarray(failed, dtype=bool).reshape(-1)
        if f.shape != (X.shape[0],):
            raise ValidationError(f"failed: expected shape ({X.shape[0]},), got {f.shape}")
        msg.failed = f.astype(np.uint8).tobytes()
    return msg


def predict_response_from_proto(
    msg: dynamics_pb.PredictResponse,
) -> tuple[np.ndarray, np.ndarray | None]:
    """PredictResponse -> ``(next poses (K, N, 4, 4) float32, failed (K,) bool | None)``."""
    k, n = int(msg.num_actions), int(msg.num_objects)
    poses = _plane(msg.poses, F32, (k, n, 4, 4), "poses").astype(np.float32)
    failed = None
    if msg.failed:
        failed = _plane(msg.failed, np.dtype(np.uint8), (k,), "failed").astype(bool)
    return poses, failed


# --- MPC planner (planner.proto) ----------------------------------------------------------------
#
# Objects travel as RecognizedObject (parts + id); the domain side is ``PushMPC.plan(objects
# [(parts, id)], task, rng)`` with a :mod:`sqmanip.planning.tasks` task and a
# :class:`~sqmanip.planning.mpc.PlanResult`. Episode events map
# :class:`sqmanip.planning.episode.StepEvent` / ``EpisodeResult`` (decoded to JSON-ready dicts,
# which is what the gateway keeps).

from sqmanip.planning.mpc import PlanResult as MPCPlanResult  # noqa: E402
from sqmanip.planning.tasks import (  # noqa: E402
    GraspingTask,
    InteractiveMovingTask,
    MovingTask,
    SingulationTask,
)
from sqmanip.v1 import planner_pb2 as planner_pb  # noqa: E402
from sqmanip.v1 import search_pb2 as search_pb  # noqa: E402

MAX_MPC_SEQUENCES = 100_000
EPISODE_OBJECTS = ("recognition", "ground_truth")


def task_to_proto(task: Any) -> planner_pb.PlanTask:
    """A :mod:`sqmanip.planning.tasks` task -> PlanTask."""
    if isinstance(task, MovingTask):
        goals = [planner_pb.MovingGoal(object_id=int(k), goal=pose_to_proto(T))
                 for k, T in task.goals.items()]  # fmt: skip
        return planner_pb.PlanTask(moving=planner_pb.MovingTask(goals=goals, beta=task.beta))
    if isinstance(task, SingulationTask):
        return planner_pb.PlanTask(singulation=planner_pb.SingulationTask(tau=task.tau))
    if isinstance(task, GraspingTask):
        return planner_pb.PlanTask(grasping=planner_pb.GraspingTask(target_id=task.target_id))
    if isinstance(task, InteractiveMovingTask):
        msg = planner_pb.InteractiveMovingTask(
            target_id=task.target_id, goal=vec3_to_proto(task.goal)
        )
        return planner_pb.PlanTask(interactive_moving=msg)
    raise ValidationError(f"task: expected a planning task, got {type(task).__name__}")


def task_from_proto(msg: planner_pb.PlanTask) -> Any:
    """PlanTask -> task; a missing task or bad numbers raise ValidationError naming ``task...``."""
    which = msg.WhichOneof("task")
    if which is None:
        raise ValidationError(
            "task: expected one of moving, singulation, grasping, interactive_moving"
        )
    if which == "moving":
        goals: dict[int, np.ndarray] = {}
        for i, g in enumerate(msg.moving.goals):
            if not g.HasField("goal"):
                raise ValidationError(f"task.goals[{i}].goal: required")
            p, q = g.goal.position, g.goal.orientation
            if not np.isfinite([p.x, p.y, p.z, q.x, q.y, q.z, q.w]).all():
                raise ValidationError(f"task.goals[{g.object_id}]: expected finite numbers")
            if int(g.object_id) in goals:
                raise ValidationError(f"task.goals: object id {g.object_id} given twice")
            goals[int(g.object_id)] = pose_from_proto(g.goal)
        return MovingTask(goals, float(msg.moving.beta))
    if which == "singulation":
        s = msg.singulation
        return SingulationTask(float(s.tau)) if s.HasField("tau") else SingulationTask()
    if which == "grasping":
        return GraspingTask(int(msg.grasping.target_id))
    im = msg.interactive_moving
    if not im.HasField("goal"):
        raise ValidationError("task.goal: required for interactive moving")
    return InteractiveMovingTask(int(im.target_id), np.asarray(vec3_from_proto(im.goal)))


@dataclasses.dataclass(frozen=True)
class MPCArgs:
    """Decoded MPCOptions: None = the planner's default."""

    num_sequences: int | None = None
    horizon: int | None = None
    seed: int | None = None
    dynamics_model: str = "sqpdnet"


def mpc_options_to_proto(
    num_sequences: int | None = None,
    horizon: int | None = None,
    seed: int | None = None,
    dynamics_model: str = "",
) -> planner_pb.MPCOptions:
    msg = planner_pb.MPCOptions(dynamics_model=dynamics_model or "")
    if num_sequences is not None:
        msg.num_sequences = int(num_sequences)
    if horizon is not None:
        msg.horizon = int(horizon)
    if seed is not None:
        msg.seed = int(seed)
    return msg


def mpc_options_from_proto(msg: planner_pb.MPCOptions) -> MPCArgs:
    """MPCOptions -> :class:`MPCArgs`; K = 0, K too large, horizon outside [1, 10] are
    ValidationErrors naming ``options.<field>``."""
    k = int(msg.num_sequences) if msg.HasField("num_sequences") else None
    if k is not None and not 1 <= k <= MAX_MPC_SEQUENCES:
        raise ValidationError(
            f"options.num_sequences: must be in [1, {MAX_MPC_SEQUENCES}], got {k}"
        )
    h = int(msg.horizon) if msg.HasField("horizon") else None
    if h is not None and not 1 <= h <= 10:
        raise ValidationError(f"options.horizon: must be in [1, 10], got {h}")
    seed = int(msg.seed) if msg.HasField("seed") else None
    return MPCArgs(k, h, seed, msg.dynamics_model or "sqpdnet")


@dataclasses.dataclass(frozen=True)
class PlanArgs:
    """A decoded PlanRequest: the arguments of ``PushMPC.plan`` and the options."""

    objects: list[tuple[list[Superquadric], int]]
    task: Any
    options: MPCArgs


def plan_request_to_proto(
    objects: Sequence[tuple[Sequence[Superquadric], int]],
    task: Any,
    **options: Any,
) -> planner_pb.PlanRequest:
    """``objects [(parts, id)]``, a task and :func:`mpc_options_to_proto` keywords -> PlanRequest."""
    return planner_pb.PlanRequest(
        objects=[_parts_object(i, parts) for parts, i in objects],
        task=task_to_proto(task),
        options=mpc_options_to_proto(**options),
    )


def plan_request_from_proto(msg: planner_pb.PlanRequest) -> PlanArgs:
    """PlanRequest -> :class:`PlanArgs`; empty or duplicate objects, non-finite parts, a missing
    task or bad options raise ValidationError naming the field."""
    if len(msg.objects) == 0:
        raise ValidationError("objects: expected at least one object")
    objects: list[tuple[list[Superquadric], int]] = []
    seen: set[int] = set()
    for i, o in enumerate(msg.objects):
        if len(o.parts) == 0:
            raise ValidationError(f"objects[{i}].parts: expected at least one part")
        if int(o.id) in seen:
            raise ValidationError(f"objects[{i}].id: duplicate object id {o.id}")
        seen.add(int(o.id))
        parts = [_finite_superquadric(p, f"objects[{i}].parts[{j}]") for j, p in enumerate(o.parts)]
        objects.append((parts, int(o.id)))
    if not msg.HasField("task"):
        raise ValidationError("task: required")
    return PlanArgs(objects, task_from_proto(msg.task), mpc_options_from_proto(msg.options))


def plan_response_to_proto(
    result: MPCPlanResult, dynamics_model: str = ""
) -> planner_pb.PlanResponse:
    """A :class:`~sqmanip.planning.mpc.PlanResult` -> PlanResponse."""
    msg = planner_pb.PlanResponse(
        has_action=result.action is not None,
        action=[] if result.action is None else [float(v) for v in result.action],
        predicted_next=[
            planner_pb.ObjectPose(object_id=int(i), pose=pose_to_proto(T))
            for i, T in zip(result.object_ids, np.asarray(result.predicted_next), strict=True)
        ],
        cost=float(result.cost),
        current_cost=float(result.current_cost),
        num_candidates=int(result.n_candidates),
        num_sampled=int(result.n_sampled),
        num_rejected_start=int(result.n_rejected_start),
        num_rejected_workspace=int(result.n_rejected_workspace),
        sequence=[float(v) for v in np.asarray(result.sequence, dtype=np.float64).reshape(-1)],
        timings_ms={k: float(v) for k, v in result.timings_ms.items()},
        dynamics_model=dynamics_model,
        solved=bool(result.solved),
    )
    if result.pushed_id is not None:
        msg.pushed_id = int(result.pushed_id)
    return msg


def plan_response_from_proto(msg: planner_pb.PlanResponse) -> MPCPlanResult:
    """PlanResponse -> :class:`~sqmanip.planning.mpc.PlanResult` (float64 poses)."""
    action = np.asarray(msg.action, dtype=np.float64) if msg.has_action else None
    if action is not None and action.shape != (6,):
        raise ValidationError(f"action: expected 6 values, got {action.shape[0]}")
    seq = np.asarray(msg.sequence, dtype=np.float64)
    if seq.size % 6:
        raise ValidationError(f"sequence: expected H x 6 values, got {seq.size}")
    ids = tuple(int(p.object_id) for p in msg.predicted_next)
    nxt = (
        np.stack([pose_from_proto(p.pose) for p in msg.predicted_next])
        if ids
        else np.zeros((0, 4, 4))
    )
    return MPCPlanResult(
        action=action,
        predicted_next=nxt,
        cost=float(msg.cost),
        current_cost=float(msg.current_cost),
        n_candidates=int(msg.num_candidates),
        timings_ms=dict(msg.timings_ms),
        sequence=seq.reshape(-1, 6),
        pushed_id=int(msg.pushed_id) if msg.HasField("pushed_id") else None,
        object_ids=ids,
        n_sampled=int(msg.num_sampled),
        n_rejected_start=int(msg.num_rejected_start),
        n_rejected_workspace=int(msg.num_rejected_workspace),
    )


@dataclasses.dataclass(frozen=True)
class EpisodeArgs:
    """A decoded EpisodeRequest."""

    kind: str
    index: int
    seed: int
    objects: str
    options: MPCArgs
    max_steps: int


def episode_request_to_proto(
    kind: str,
    index: int = 0,
    seed: int = 0,
    *,
    objects: str = "recognition",
    max_steps: int | None = None,
    options: Mapping[str, Any] | None = None,
) -> planner_pb.EpisodeRequest:
    """``options``: :func:`mpc_options_to_proto` keywords (its ``seed`` seeds the planner;
    ``seed`` here picks the scenario)."""
    msg = planner_pb.EpisodeRequest(
        kind=kind, index=int(index), seed=int(seed), objects=objects,
        options=mpc_options_to_proto(**dict(options or {})),
    )  # fmt: skip
    if max_steps is not None:
        msg.max_steps = int(max_steps)
    return msg


def episode_request_from_proto(msg: planner_pb.EpisodeRequest) -> EpisodeArgs:
    from sqmanip.planning.scenarios import SCENARIO_KINDS

    if msg.kind not in SCENARIO_KINDS:
        raise ValidationError(f"kind: must be one of {list(SCENARIO_KINDS)}, got {msg.kind!r}")
    objects = msg.objects or "recognition"
    if objects not in EPISODE_OBJECTS:
        raise ValidationError(f"objects: must be one of {list(EPISODE_OBJECTS)}, got {objects!r}")
    steps = int(msg.max_steps) if msg.HasField("max_steps") else 10
    if not 0 <= steps <= 100:
        raise ValidationError(f"max_steps: must be in [0, 100], got {steps}")
    return EpisodeArgs(msg.kind, int(msg.index), int(msg.seed), objects,
                       mpc_options_from_proto(msg.options), steps)  # fmt: skip


def _xyzyaw_list(poses: Mapping[int, Sequence[float]]) -> list[planner_pb.ObjectXYZYaw]:
    return [
        planner_pb.ObjectXYZYaw(object_id=int(k), x=v[0], y=v[1], z=v[2], yaw=v[3])
        for k, v in poses.items()
    ]


def episode_event_to_proto(event: Any) -> planner_pb.EpisodeEvent:
    """A :class:`sqmanip.planning.episode.StepEvent` -> EpisodeEvent."""
    msg = planner_pb.EpisodeEvent(
        step=int(event.step),
        status=event.status,
        message=event.message,
        num_points=int(event.n_points),
        recognized_ids=[int(i) for i in event.recognized_ids],
        missing_ids=[int(i) for i in event.missing_ids],
        action=[] if event.action is None else [float(v) for v in event.action],
        predicted=_xyzyaw_list(event.predicted),
        recognized=_xyzyaw_list(event.recognized),
        observed=_xyzyaw_list(event.observed),
        cost=float(event.cost),
        current_cost=float(event.current_cost),
        metric_after=float(event.metric_after),
        num_candidates=int(event.n_candidates),
        timings_ms={k: float(v) for k, v in event.timings_ms.items()},
    )
    if event.pushed_id is not None:
        msg.pushed_id = int(event.pushed_id)
    return msg


def episode_result_to_proto(result: Any) -> planner_pb.EpisodeEvent:
    """An ``EpisodeResult`` -> the last EpisodeEvent (status ``result``)."""
    r = planner_pb.EpisodeResult(
        kind=result.kind, index=int(result.index), success=bool(result.success),
        steps=int(result.steps), reason=result.reason, metric=float(result.metric),
        wall_s=float(result.wall_s),
    )  # fmt: skip
    if result.grasp_found is not None:
        r.grasp_found = bool(result.grasp_found)
    return planner_pb.EpisodeEvent(
        step=int(result.steps), status="result", message=result.reason, result=r
    )


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def episode_event_from_proto(msg: planner_pb.EpisodeEvent) -> dict[str, Any]:
    """EpisodeEvent -> a JSON-ready dict (non-finite costs -> None); the last event has
    ``result``."""
    if msg.HasField("result"):
        r = msg.result
        return {
            "status": "result",
            "result": {
                "kind": r.kind,
                "index": int(r.index),
                "success": bool(r.success),
                "steps": int(r.steps),
                "reason": r.reason,
                "grasp_found": bool(r.grasp_found) if r.HasField("grasp_found") else None,
                "metric": _finite_or_none(r.metric),
                "wall_s": float(r.wall_s),
            },  # fmt: skip
        }

    def poses(items) -> dict[str, list[float]]:
        return {str(p.object_id): [p.x, p.y, p.z, p.yaw] for p in items}

    return {
        "step": int(msg.step),
        "status": msg.status,
        "message": msg.message,
        "n_points": int(msg.num_points),
        "recognized_ids": list(msg.recognized_ids),
        "missing_ids": list(msg.missing_ids),
        "action": list(msg.action) or None,
        "pushed_id": int(msg.pushed_id) if msg.HasField("pushed_id") else None,
        "predicted": poses(msg.predicted),
        "recognized": poses(msg.recognized),
        "observed": poses(msg.observed),
        "cost": _finite_or_none(msg.cost),
        "current_cost": _finite_or_none(msg.current_cost),
        "metric_after": _finite_or_none(msg.metric_after),
        "n_candidates": int(msg.num_candidates),
        "timings_ms": dict(msg.timings_ms),
    }


# --- shelf search (search.proto) ----------------------------------------------------------------
#
# Maps over the pose grid are float32 planes with the grid shape; the domain side is
# :mod:`sqmanip.search` (ShelfSpec, TargetSpec, PinholeCamera, Maps) and its episode
# ``StepEvent`` / ``EpisodeResult``.

SEARCH_METHODS = ("search_for_grasp", "search_and_grasp")
SEARCH_SHAPES = ("oracle", "recognized")
SEARCH_ACTIONS = ("both", "push", "pick_and_place")
SHELF_FIELDS = ("front_x", "depth", "inner_width", "inner_height", "bottom_z", "thickness")


def search_target_to_proto(target: Any) -> search_pb.SearchTarget:
    return search_pb.SearchTarget(kind=target.kind, size=vec3_to_proto(target.size))


def search_target_from_proto(msg: search_pb.SearchTarget | None) -> Any:
    """SearchTarget -> ``TargetSpec`` (unset = the scenarios' red cylinder)."""
    from sqmanip.search.scenarios import TARGET_HEIGHT, TARGET_RADIUS
    from sqmanip.search.shelf import TargetSpec

    if msg is None:
        return TargetSpec.cylinder(TARGET_RADIUS, TARGET_HEIGHT)
    size = vec3_from_proto(msg.size)
    try:
        return TargetSpec(msg.kind or "cylinder", size)
    except ValidationError as exc:
        raise ValidationError(field_message("target", exc.message)) from None


def shelf_to_proto(shelf: Any) -> search_pb.ShelfGeometry:
    return search_pb.ShelfGeometry(**{f: float(getattr(shelf, f)) for f in SHELF_FIELDS})


def shelf_from_proto(msg: search_pb.ShelfGeometry | None) -> Any:
    from sqmanip.search.shelf import ShelfSpec

    if msg is None:
        return ShelfSpec()
    kw = {f: float(getattr(msg, f)) for f in SHELF_FIELDS if msg.HasField(f)}
    for k, v in kw.items():
        if not np.isfinite(v):
            raise ValidationError(f"shelf.{k}: expected a finite number")
    try:
        return ShelfSpec(**kw)
    except (ValidationError, ValueError) as exc:
        raise ValidationError(field_message("shelf", str(exc))) from None


def camera_to_proto(camera: Any) -> search_pb.PinholeCamera:
    return search_pb.PinholeCamera(
        width=int(camera.width), height=int(camera.height), fx=float(camera.fx),
        fy=float(camera.fy), cx=float(camera.cx), cy=float(camera.cy),
        pose=pose_to_proto(np.asarray(camera.pose)),
    )  # fmt: skip


def camera_from_proto(msg: search_pb.PinholeCamera | None, shelf: Any) -> Any:
    """PinholeCamera -> ``geometry.PinholeCamera`` (unset = ``shelf.camera()``)."""
    from sqmanip.geometry import PinholeCamera

    if msg is None:
        return shelf.camera()
    if not 1 <= msg.width <= 4096 or not 1 <= msg.height <= 4096:
        raise ValidationError(
            f"camera: width and height must be in [1, 4096], got {msg.width} x {msg.height}"
        )
    vals = [msg.fx, msg.fy, msg.cx, msg.cy]
    if not np.isfinite(vals).all() or msg.fx <= 0 or msg.fy <= 0:
        raise ValidationError("camera: fx, fy must be finite and > 0, cx, cy finite")
    if not msg.HasField("pose"):
        raise ValidationError("camera.pose: required (camera to world, optical frame)")
    pose = pose_from_proto(msg.pose)
    return PinholeCamera(fx=msg.fx, fy=msg.fy, cx=msg.cx, cy=msg.cy, width=int(msg.width),
                         height=int(msg.height), pose=pose)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class EvaluateArgs:
    """A decoded EvaluateRequest."""

    objects: list[Superquadric]
    target: Any
    shelf: Any
    camera: Any
    target_visible: bool
    target_pose: np.ndarray | None
    resolution: float
    n_theta: int


def evaluate_request_to_proto(
    objects: Sequence[Superquadric],
    target: Any = None,
    shelf: Any = None,
    camera: Any = None,
    *,
    target_visible: bool = False,
    target_pose: np.ndarray | None = None,
    resolution: float | None = None,
    n_theta: int | None = None,
) -> search_pb.EvaluateRequest:
    msg = search_pb.EvaluateRequest(
        objects=[superquadric_to_proto(o) for o in objects], target_visible=bool(target_visible)
    )
    if target is not None:
        msg.target.CopyFrom(search_target_to_proto(target))
    if shelf is not None:
        msg.shelf.CopyFrom(shelf_to_proto(shelf))
    if camera is not None:
        msg.camera.CopyFrom(camera_to_proto(camera))
    if target_pose is not None:
        msg.target_pose.CopyFrom(pose_to_proto(np.asarray(target_pose)))
    if resolution is not None:
        msg.resolution = float(resolution)
    if n_theta is not None:
        msg.n_theta = int(n_theta)
    return msg


def evaluate_request_from_proto(msg: search_pb.EvaluateRequest) -> EvaluateArgs:
    """EvaluateRequest -> :class:`EvaluateArgs`; errors name the field."""
    objects = [_finite_superquadric(o, f"objects[{i}]") for i, o in enumerate(msg.objects)]
    target = search_target_from_proto(msg.target if msg.HasField("target") else None)
    shelf = shelf_from_proto(msg.shelf if msg.HasField("shelf") else None)
    camera = camera_from_proto(msg.camera if msg.HasField("camera") else None, shelf)
    pose = None
    if msg.target_visible:
        pose = _required_pose(msg, "target_pose")
    res = float(msg.resolution) if msg.HasField("resolution") else 0.02
    if not (np.isfinite(res) and 0.005 <= res <= 0.2):
        raise ValidationError(f"resolution: must be in [0.005, 0.2] m, got {res}")
    n_theta = int(msg.n_theta) if msg.HasField("n_theta") else 8
    if not 1 <= n_theta <= 72:
        raise ValidationError(f"n_theta: must be in [1, 72], got {n_theta}")
    return EvaluateArgs(objects, target, shelf, camera, bool(msg.target_visible), pose, res,
                        n_theta)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class EvaluateResult:
    """f, g and g_m over the pose grid, each of the grid's ``shape``."""

    shape: tuple[int, ...]
    f: np.ndarray
    g: np.ndarray
    g_m: np.ndarray
    grid_xy: np.ndarray
    """(P, 2) grid positions."""
    resolution: float
    objective: float
    timings_ms: dict[str, float]


def evaluate_response_to_proto(result: EvaluateResult) -> search_pb.EvaluateResponse:
    P = int(np.prod(result.shape))
    planes = {}
    for name in ("f", "g", "g_m"):
        a = np.asarray(getattr(result, name), dtype=F32).reshape(-1)
        if a.size != P:
            raise ValidationError(
                f"{name}: expected {P} values (shape {result.shape}), got {a.size}"
            )
        planes[name] = a.tobytes()
    xy = np.asarray(result.grid_xy, dtype=F32)
    if xy.shape != (P, 2):
        raise ValidationError(f"grid_xy: expected shape ({P}, 2), got {xy.shape}")
    return search_pb.EvaluateResponse(
        shape=[int(s) for s in result.shape], grid_xy=xy.tobytes(),
        resolution=float(result.resolution), objective=float(result.objective),
        timings_ms={k: float(v) for k, v in result.timings_ms.items()}, **planes,
    )  # fmt: skip


def evaluate_response_from_proto(msg: search_pb.EvaluateResponse) -> EvaluateResult:
    shape = tuple(int(s) for s in msg.shape)
    P = int(np.prod(shape)) if shape else 0
    maps = {n: _plane(getattr(msg, n), F32, shape, n).astype(np.float32) for n in ("f", "g", "g_m")}
    xy = _plane(msg.grid_xy, F32, (P, 2), "grid_xy").astype(np.float32)
    return EvaluateResult(shape, maps["f"], maps["g"], maps["g_m"], xy, float(msg.resolution),
                          float(msg.objective), dict(msg.timings_ms))  # fmt: skip


@dataclasses.dataclass(frozen=True)
class SearchEpisodeArgs:
    """A decoded SearchEpisodeRequest."""

    scenario: dict[str, Any] | None
    """``ShelfScenario.to_dict()`` or None (generate from ``n_objects``, ``seed``)."""
    n_objects: int
    seed: int
    method: str
    shapes: str
    actions: str
    dynamics_model: str
    max_steps: int | None
    num_sequences: int | None
    plan_seed: int


def search_episode_request_to_proto(
    scenario: Any = None,
    *,
    n_objects: int = 2,
    seed: int = 0,
    method: str = "search_for_grasp",
    shapes: str = "oracle",
    actions: str = "both",
    dynamics_model: str = "kinematic",
    max_steps: int | None = None,
    num_sequences: int | None = None,
    plan_seed: int = 0,
) -> search_pb.SearchEpisodeRequest:
    """``scenario`` is a ``ShelfScenario``, its dict, or None (generated from n_objects, seed)."""
    if scenario is not None and not isinstance(scenario, Mapping):
        scenario = scenario.to_dict()
    msg = search_pb.SearchEpisodeRequest(
        scenario_json=json.dumps(scenario) if scenario is not None else "",
        n_objects=int(n_objects), seed=int(seed), method=method, shapes=shapes, actions=actions,
        dynamics_model=dynamics_model, plan_seed=int(plan_seed),
    )  # fmt: skip
    if max_steps is not None:
        msg.max_steps = int(max_steps)
    if num_sequences is not None:
        msg.num_sequences = int(num_sequences)
    return msg


def _choice(value: str, default: str, allowed: tuple[str, ...], field: str) -> str:
    value = value or default
    if value not in allowed:
        raise ValidationError(f"{field}: must be one of {list(allowed)}, got {value!r}")
    return value


def search_episode_request_from_proto(msg: search_pb.SearchEpisodeRequest) -> SearchEpisodeArgs:
    scenario = None
    if msg.scenario_json:
        try:
            scenario = json.loads(msg.scenario_json)
        except json.JSONDecodeError as exc:
            raise ValidationError(f"scenario_json: not valid JSON ({exc})") from None
        if not isinstance(scenario, dict) or not {"n_objects", "seed", "scene", "target"} <= set(
            scenario
        ):
            raise ValidationError(
                "scenario_json: expected a ShelfScenario dict (n_objects, seed, scene, target)"
            )
    elif not 0 <= msg.n_objects <= 12:
        raise ValidationError(f"n_objects: must be in [0, 12], got {msg.n_objects}")
    model = msg.dynamics_model or "kinematic"
    if model != "kinematic" and not re.match(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$", model):
        raise ValidationError(f"dynamics_model: not a model name: {model!r}")
    steps = int(msg.max_steps) if msg.HasField("max_steps") else None
    if steps is not None and steps > 50:
        raise ValidationError(f"max_steps: must be in [0, 50], got {steps}")
    k = int(msg.num_sequences) if msg.HasField("num_sequences") else None
    if k is not None and not 1 <= k <= 1000:
        raise ValidationError(f"num_sequences: must be in [1, 1000], got {k}")
    return SearchEpisodeArgs(
        scenario, int(msg.n_objects), int(msg.seed),
        _choice(msg.method, "search_for_grasp", SEARCH_METHODS, "method"),
        _choice(msg.shapes, "oracle", SEARCH_SHAPES, "shapes"),
        _choice(msg.actions, "both", SEARCH_ACTIONS, "actions"),
        model, steps, k, int(msg.plan_seed),
    )  # fmt: skip


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value


def search_event_to_proto(event: Any) -> search_pb.SearchEvent:
    """A :class:`sqmanip.search.episode.StepEvent` -> SearchEvent (maps and images dropped)."""
    return search_pb.SearchEvent(
        step=int(event.step), action=event.action,
        params_json=json.dumps(_jsonable(event.params)), f_sum=float(event.f_sum),
        fg_sum=float(event.fg_sum), visible=bool(event.visible),
        graspable=bool(event.graspable), target_pixels=int(event.target_pixels),
        executed=bool(event.executed), message=event.message,
        timings_ms={k: float(v) for k, v in event.timings_ms.items()},
    )  # fmt: skip


def search_result_to_proto(
    result: Any, *, wall_s: float = 0.0, scenario_json: str = ""
) -> search_pb.SearchEvent:
    """A search ``EpisodeResult`` -> the last SearchEvent (action ``result``)."""
    r = search_pb.SearchResult(
        found=bool(result.found), grasped=bool(result.grasped), steps=int(result.steps),
        reason=result.reason, wall_s=float(wall_s), scenario_json=scenario_json,
    )  # fmt: skip
    if result.find_steps is not None:
        r.find_steps = int(result.find_steps)
    if result.grasp_steps is not None:
        r.grasp_steps = int(result.grasp_steps)
    return search_pb.SearchEvent(
        step=int(result.steps), action="result", message=result.reason, result=r
    )


def search_event_from_proto(msg: search_pb.SearchEvent) -> dict[str, Any]:
    """SearchEvent -> a JSON-ready dict; the last event has ``result``."""
    if msg.HasField("result"):
        r = msg.result
        return {
            "action": "result",
            "result": {
                "found": r.found,
                "grasped": r.grasped,
                "find_steps": int(r.find_steps) if r.HasField("find_steps") else None,
                "grasp_steps": int(r.grasp_steps) if r.HasField("grasp_steps") else None,
                "steps": int(r.steps),
                "reason": r.reason,
                "wall_s": float(r.wall_s),
                "scenario": json.loads(r.scenario_json) if r.scenario_json else None,
            },  # fmt: skip
        }
    try:
        params = json.loads(msg.params_json) if msg.params_json else {}
    except json.JSONDecodeError:
        params = {}
    return {
        "step": int(msg.step), "action": msg.action, "params": params,
        "f_sum": float(msg.f_sum), "fg_sum": float(msg.fg_sum), "visible": msg.visible,
        "graspable": msg.graspable, "target_pixels": int(msg.target_pixels),
        "executed": msg.executed, "message": msg.message, "timings_ms": dict(msg.timings_ms),
    }  # fmt: skip
