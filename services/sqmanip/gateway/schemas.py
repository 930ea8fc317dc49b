"""HTTP request/response models of the gateway (the JSON contracts of ``POST /recognize`` and
the ``/sim`` routes).

Names follow ARCHITECTURE.md and the SDK: metres, radians, quaternions (x, y, z, w), poses map
object to world, colors are floats in [0, 1]. Request and response models are separate.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from sqmanip.geometry import Superquadric
from sqmanip.geometry.transforms import matrix_to_quat
from sqmanip.perception.types import RecognizedObject, RecognizeOptions, Scene
from sqmanip.rpc.convert import split_by_counts
from sqmanip.sim.actions import ActionResult, ObjectState, Observation, SimState

Vec3 = tuple[float, float, float]

# Integers bounded by their protobuf wire types: a larger value would make the gateway's proto
# assignment raise (a 500) instead of a 422 naming the field (found by tests/integration/test_fuzz).
Int64 = Annotated[int, Field(ge=-(2**63), le=2**63 - 1)]
Int32 = Annotated[int, Field(ge=-(2**31), le=2**31 - 1)]
UInt32 = Annotated[int, Field(ge=0, le=2**32 - 1)]


class WorkspaceIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    min: Vec3 = Field(description="Lower corner of the crop box, world frame (m).")
    max: Vec3 = Field(description="Upper corner of the crop box, world frame (m).")


class RecognizeOptionsIn(BaseModel):
    """Recognition options; omitted ones take the service defaults."""

    model_config = ConfigDict(extra="forbid")
    method: Literal["optimization", "network", "hybrid", "mvbb"] = "optimization"
    segmentation: Literal["clustering", "color", "labels", "network"] | None = Field(
        None,
        description="Default: 'labels' when labels are sent, else 'clustering'. 'color': "
        "clustering that also separates touching objects of different colours (uniformly "
        "coloured objects; needs colors).",
    )
    points_per_segment: UInt32 = Field(
        300, ge=1, description="Resampled points per segment (3.5.3)."
    )
    remove_support: bool = True
    amodal: bool = True
    deformable: bool = True
    seed: Int64 = 0

    def to_domain(self, *, has_labels: bool) -> RecognizeOptions:
        seg = self.segmentation or ("labels" if has_labels else "clustering")
        return RecognizeOptions(
            method=self.method,
            segmentation=seg,
            points_per_segment=self.points_per_segment,
            remove_support=self.remove_support,
            amodal=self.amodal,
            deformable=self.deformable,
            seed=self.seed,
        )


class RecognizeBody(BaseModel):
    """JSON body of ``POST /recognize``."""

    model_config = ConfigDict(extra="forbid")
    points: list[list[float]] = Field(description="N x 3 world-frame points (m).")
    colors: list[list[float]] | None = Field(None, description="N x 3 colors in [0, 1].")
    labels: list[int] | None = Field(None, description="N instance labels, -1 = background.")
    viewpoint: Vec3 | None = Field(None, description="Sensor origin, world frame (m).")
    workspace: WorkspaceIn | None = None
    options: RecognizeOptionsIn = Field(default_factory=RecognizeOptionsIn)


class PoseOut(BaseModel):
    position: Vec3 = Field(description="Object origin in the world frame (m).")
    orientation: tuple[float, float, float, float] = Field(
        description="Object-to-world rotation as a unit quaternion (x, y, z, w)."
    )


class PartOut(BaseModel):
    kind: Literal["superellipsoid", "superparaboloid", "supertoroid"]
    size: list[float] = Field(description="[a1, a2, a3] half extents (m); a4 appended for toroids.")
    shape: tuple[float, float] = Field(description="[e1, e2] shape exponents.")
    taper: float = Field(description="Tapering k (2.3.12).")
    bend: float = Field(description="Bending curvature b (1/m) (2.3.15).")
    bend_direction: float = Field(description="Bending direction alpha (rad).")
    pose: PoseOut


class ObjectOut(BaseModel):
    id: int
    parts: list[PartOut]
    point_indices: list[int] = Field(description="Indices of the object's points in the request.")
    mean_color: Vec3 | None = None
    residual: float = Field(description="Mean squared radial distance of the points (m^2).")
    confidence: float = 1.0


class SupportPlaneOut(BaseModel):
    normal: Vec3 = Field(description="Unit normal pointing into free space.")
    offset: float = Field(description="d in normal . x + d = 0 (m).")


class RecognizeResponse(BaseModel):
    objects: list[ObjectOut]
    support_plane: SupportPlaneOut | None = None
    timings_ms: dict[str, float] = Field(default_factory=dict)


class ServiceHealth(BaseModel):
    address: str
    status: str = Field(description="gRPC health: SERVING, NOT_SERVING or UNREACHABLE: ...")


class HealthOut(BaseModel):
    status: Literal["ok", "degraded"]
    services: dict[str, ServiceHealth]


def _parts(parts: list[Superquadric]) -> list[PartOut]:
    """Superquadrics -> response parts, the quaternions in one batched call (per-part calls on
    tiny tensors cost ~0.3 ms each)."""
    import torch

    if not parts:
        return []
    rotations = np.array([np.asarray(sq.pose)[:3, :3] for sq in parts], dtype=np.float64)
    quats = matrix_to_quat(torch.as_tensor(rotations)).tolist()
    out = []
    for sq, q in zip(parts, quats, strict=True):
        size = [float(v) for v in sq.size]
        if sq.kind == "supertoroid":
            size.append(float(sq.a4))
        out.append(
            PartOut(
                kind=sq.kind,
                size=size,
                shape=(float(sq.shape[0]), float(sq.shape[1])),
                taper=float(sq.taper),
                bend=float(sq.bend),
                bend_direction=float(sq.bend_direction),
                pose=PoseOut(
                    position=tuple(float(v) for v in sq.pose[:3, 3]), orientation=tuple(q)
                ),
            )
        )
    return out


def _object(obj: RecognizedObject, parts: list[PartOut]) -> ObjectOut:
    return ObjectOut(
        id=int(obj.id),
        parts=parts,
        point_indices=np.asarray(obj.point_indices, dtype=np.int64).reshape(-1).tolist(),
        mean_color=None if obj.mean_color is None else tuple(float(c) for c in obj.mean_color),
        residual=float(obj.residual),
        confidence=float(obj.confidence),
    )


def scene_to_response(scene: Scene) -> RecognizeResponse:
    counts = [len(o.parts) for o in scene.objects]
    parts = split_by_counts(_parts([p for o in scene.objects for p in o.parts]), counts)
    plane = scene.support_plane
    return RecognizeResponse(
        objects=[_object(o, p) for o, p in zip(scene.objects, parts, strict=True)],
        support_plane=None
        if plane is None
        else SupportPlaneOut(
            normal=tuple(float(v) for v in plane.normal), offset=float(plane.offset)
        ),
        timings_ms={str(k): float(v) for k, v in scene.timings_ms.items()},
    )


# --- simulator (/sim) ------------------------------------------------------------------------------

Quat = tuple[float, float, float, float]


class PoseIn(BaseModel):
    """A pose (object, tool or camera optical frame to world)."""

    model_config = ConfigDict(extra="forbid")
    position: Vec3 = Field(description="Origin in the world frame (m).")
    orientation: Quat = Field(
        (0.0, 0.0, 0.0, 1.0), description="Rotation as a quaternion (x, y, z, w); normalized."
    )

    @field_validator("orientation")
    @classmethod
    def _nonzero(cls, q: Quat) -> Quat:
        n = float(np.linalg.norm(q))
        if not np.isfinite(n) or n < 1e-9:
            raise ValueError("expected a finite, non-zero quaternion (x, y, z, w)")
        return q

    def matrix(self) -> np.ndarray:
        """4 x 4 homogeneous matrix."""
        import torch

        from sqmanip.geometry.transforms import quat_to_matrix

        T = np.eye(4)
        T[:3, :3] = quat_to_matrix(torch.tensor(self.orientation, dtype=torch.float64)).numpy()
        T[:3, 3] = self.position
        return T


class SimResetBody(BaseModel):
    """``POST /sim/reset``: give ``scene`` (a SceneSpec dict, e.g. the ``scene`` of an earlier
    reset) to replay it, or ``seed`` for a random scene."""

    model_config = ConfigDict(extra="forbid")
    scene: dict[str, Any] | None = Field(
        None,
        description="SceneSpec: {kind, seed, objects: [{kind: box|cylinder|superquadric|mesh, "
        "position, orientation (xyzw), size | radius, height | params, sq_kind | path, scale, "
        "mass, friction, color, upright, name}]}",
    )
    seed: Int64 | None = Field(None, description="Seed of a random scene (instead of scene).")
    n_objects: int | None = Field(None, ge=0, le=20, description="Random scene: objects (4).")
    kind: Literal["tabletop", "shelf"] = "tabletop"
    object_kinds: list[Literal["box", "cylinder", "superquadric"]] | None = Field(
        None, description="Random scene object kinds (default box, cylinder)."
    )


class IntrinsicsIn(BaseModel):
    """Pinhole intrinsics (OpenCV, pixels); omitted focal lengths keep the default camera's
    (504 px), an omitted principal point is the image centre."""

    model_config = ConfigDict(extra="forbid")
    width: int = Field(640, ge=1, le=4096)
    height: int = Field(576, ge=1, le=4096)
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    near: float = 0.05
    far: float = 3.0


class SimObserveBody(BaseModel):
    """``POST /sim/observe`` (every field optional; an empty body is the default camera)."""

    model_config = ConfigDict(extra="forbid")
    camera: Literal["default", "wrist", "shelf", "overview"] = "default"
    intrinsics: IntrinsicsIn | None = None
    camera_pose: PoseIn | None = Field(
        None, description="Optical frame (x right, y down, z forward) to world; overrides camera."
    )
    noise: bool = Field(True, description="Appendix A.1 point-cloud noise.")


class SimPushBody(BaseModel):
    model_config = ConfigDict(extra="forbid")
    p: Vec3 = Field(description="Push start point, world frame (m).")
    v: Vec3 = Field(description="Push displacement, world frame (m).")
    upright: bool = Field(
        default=False,
        description="Shelf only: the hand turned on its side (its 20 cm vertical), to fit beside "
        "an object near a side board; p at least 10.2 cm above the floor.",
    )


class SimGraspBody(BaseModel):
    model_config = ConfigDict(extra="forbid")
    pose: PoseIn = Field(description="Tool pose; approach along the tool z axis.")
    width: float = Field(description="Gripper opening (m), at most 0.08.")


class SimPickAndPlaceBody(BaseModel):
    model_config = ConfigDict(extra="forbid")
    grasp_pose: PoseIn
    width: float = Field(description="Gripper opening (m), at most 0.08.")
    place_pose: PoseIn = Field(description="Tool pose at release; the object moves with the tool.")


class SimObjectOut(BaseModel):
    id: int = Field(description="Index in the scene spec; the segmentation label of the object.")
    name: str
    kind: str = Field(description="box | cylinder | superquadric | mesh")
    pose: PoseOut
    superquadric: PartOut | None = Field(
        None, description="Ground-truth shape at the current pose; null for meshes."
    )


class SimStateOut(BaseModel):
    time: float = Field(description="Simulated time since reset (s).")
    scene_kind: str
    objects: list[SimObjectOut]
    joint_positions: list[float] = Field(description="Panda arm joints (7, rad).")
    gripper_width: float = Field(description="Gripper opening (m).")
    tcp_pose: PoseOut = Field(description="Tool centre point to world.")
    held_object: int | None = None


class SimResetOut(BaseModel):
    state: SimStateOut
    scene: dict[str, Any] = Field(
        description="The scene as built: POST it to /sim/reset to replay."
    )


class SimActionOut(BaseModel):
    success: bool
    message: str
    before: SimStateOut
    after: SimStateOut
    held_object: int | None = None
    sim_time: float = Field(description="Simulated duration of the action (s).")


class IntrinsicsOut(BaseModel):
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    near: float
    far: float


class ArrayInfo(BaseModel):
    shape: list[int]
    dtype: str


class SimObservationOut(BaseModel):
    """Summary of one frame; ``?include=points`` adds the cloud, ``?format=npz`` gives arrays."""

    camera: str
    time: float
    intrinsics: IntrinsicsOut
    camera_pose: PoseOut = Field(description="Optical frame (x right, y down, z forward) to world.")
    arrays: dict[str, ArrayInfo] = Field(
        description="Shapes and dtypes of depth, rgb, segmentation, points, point_labels, "
        "point_pixels (all in the npz download)."
    )
    num_points: int
    point_counts: dict[str, int] = Field(
        description="Cloud points per label: object ids >= 0, -2 static, -3 robot."
    )
    objects: list[SimObjectOut] = Field(description="Ground truth at the time of the frame.")
    points: list[list[float]] | None = Field(None, description="N x 3 world points (include).")
    point_labels: list[int] | None = Field(None, description="N labels (include=points).")


def pose_out(T: np.ndarray) -> PoseOut:
    import torch

    T = np.asarray(T, dtype=np.float64)
    q = matrix_to_quat(torch.as_tensor(T[:3, :3])).tolist()
    return PoseOut(position=tuple(float(v) for v in T[:3, 3]), orientation=tuple(q))


def sim_object_out(obj: ObjectState) -> SimObjectOut:
    return SimObjectOut(
        id=int(obj.id),
        name=obj.name,
        kind=obj.kind,
        pose=pose_out(obj.pose),
        superquadric=None if obj.superquadric is None else _parts([obj.superquadric])[0],
    )


def sim_state_out(state: SimState) -> SimStateOut:
    return SimStateOut(
        time=float(state.time),
        scene_kind=state.scene_kind,
        objects=[sim_object_out(o) for o in state.objects],
        joint_positions=[float(q) for q in state.joint_positions],
        gripper_width=float(state.gripper_width),
        tcp_pose=pose_out(state.tcp_pose),
        held_object=state.held_object,
    )


def sim_action_out(result: ActionResult) -> SimActionOut:
    return SimActionOut(
        success=bool(result.success),
        message=result.message,
        before=sim_state_out(result.before),
        after=sim_state_out(result.after),
        held_object=result.held_object,
        sim_time=float(result.sim_time),
    )


def observation_arrays(obs: Observation) -> dict[str, np.ndarray]:
    """The arrays of the npz download (wire dtypes: points float32)."""
    return {
        "depth": obs.depth.astype(np.float32),
        "rgb": obs.rgb.astype(np.uint8),
        "segmentation": obs.segmentation.astype(np.int32),
        "points": obs.points.astype(np.float32),
        "point_labels": obs.point_labels.astype(np.int32),
        "point_pixels": obs.point_pixels.astype(np.int32),
        "camera_pose": np.asarray(obs.camera_pose, dtype=np.float64),
        "camera_matrix": obs.intrinsics.matrix(),
    }


def sim_observation_out(obs: Observation, *, include_points: bool = False) -> SimObservationOut:
    k = obs.intrinsics
    labels, counts = np.unique(obs.point_labels, return_counts=True)
    arrays = observation_arrays(obs)
    return SimObservationOut(
        camera=obs.camera,
        time=float(obs.time),
        intrinsics=IntrinsicsOut(
            width=k.width,
            height=k.height,
            fx=k.fx,
            fy=k.fy,
            cx=k.cx,
            cy=k.cy,
            near=k.near,
            far=k.far,
        ),  # fmt: skip
        camera_pose=pose_out(obs.camera_pose),
        arrays={
            name: ArrayInfo(shape=list(a.shape), dtype=a.dtype.name)
            for name, a in arrays.items()
            if name not in ("camera_pose", "camera_matrix")
        },
        num_points=int(obs.points.shape[0]),
        point_counts={str(int(l)): int(c) for l, c in zip(labels, counts, strict=True)},
        objects=[sim_object_out(o) for o in obs.objects],
        points=obs.points.astype(np.float32).tolist() if include_points else None,
        point_labels=obs.point_labels.tolist() if include_points else None,
    )


# --- grasp planner (/grasps) ----------------------------------------------------------------------


class PartIn(BaseModel):
    """One superquadric part: the JSON shape of a ``/recognize`` object's ``parts[i]``."""

    model_config = ConfigDict(extra="forbid")
    kind: Literal["superellipsoid", "superparaboloid", "supertoroid"] = "superellipsoid"
    size: list[float] = Field(description="[a1, a2, a3] half extents (m); a4 appended for toroids.")
    shape: tuple[float, float] = Field(description="[e1, e2] shape exponents in [0.2, 1.7].")
    taper: float = 0.0
    bend: float = 0.0
    bend_direction: float = 0.0
    pose: PoseIn

    def to_domain(self, field: str) -> Superquadric:
        """The domain part; a wrong size length or value raises ValidationError naming ``field``."""
        from sqmanip.errors import ValidationError

        n = 4 if self.kind == "supertoroid" else 3
        if len(self.size) != n:
            raise ValidationError(
                f"{field}.size: expected {n} values for a {self.kind}, got {len(self.size)}"
            )
        values = [*self.size, *self.shape, self.taper, self.bend, self.bend_direction]
        if not np.all(np.isfinite(values)) or not np.all(np.isfinite(self.pose.position)):
            raise ValidationError(f"{field}: expected finite numbers")
        try:
            return Superquadric(
                size=tuple(self.size[:3]),
                shape=self.shape,
                pose=self.pose.matrix(),
                kind=self.kind,
                taper=self.taper,
                bend=self.bend,
                bend_direction=self.bend_direction,
                a4=self.size[3] if n == 4 else 0.0,
            )
        except ValueError as exc:
            raise ValidationError(f"{field}: {exc}") from None


class ObjectIn(BaseModel):
    """A recognized object as ``/recognize`` returns it (only ``id`` and ``parts`` are used;
    ``point_indices`` select the target's observed points when the gateway recognized the
    cloud itself)."""

    model_config = ConfigDict(extra="forbid")
    id: int
    parts: list[PartIn] = Field(min_length=1)
    point_indices: list[int] | None = None
    mean_color: Vec3 | None = None
    residual: float | None = None
    confidence: float | None = None


class SupportPlaneIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    normal: Vec3 = Field((0.0, 0.0, 1.0), description="Unit normal pointing into free space.")
    offset: float = Field(0.0, description="d in normal . x + d = 0 (m).")


class GripperIn(BaseModel):
    """A parallel-jaw gripper; omitted fields are the Franka hand's."""

    model_config = ConfigDict(extra="forbid")
    max_opening: float | None = Field(None, description="Largest finger-pad distance (m); 0.08.")
    finger_length: float | None = None
    finger_width: float | None = None
    finger_thickness: float | None = None
    tip_offset: float | None = None
    palm_size: Vec3 | None = None
    wrist_radius: float | None = None
    wrist_length: float | None = None

    def to_domain(self):
        import dataclasses

        from sqmanip.errors import ValidationError
        from sqmanip.grasping import PANDA_HAND
        from sqmanip.rpc import convert

        kwargs = {k: v for k, v in self.model_dump().items() if v is not None}
        try:
            return dataclasses.replace(PANDA_HAND, **kwargs)
        except ValidationError as exc:
            raise ValidationError(convert.field_message("gripper", exc.message)) from None


class RuleOptionsIn(BaseModel):
    """The rule-based generator of B.5 / C.3 (method ``rule_based``); omitted = defaults."""

    model_config = ConfigDict(extra="forbid")
    top_down: bool | None = None
    side: bool | None = None
    per_direction: UInt32 | None = None
    max_candidates: UInt32 | None = None
    max_width: float | None = None
    spread: float | None = None
    grasp_depth: float | None = None
    tilt: float | None = None
    facing: Vec3 | None = None
    facing_angle: float | None = None
    round_threshold: float | None = None
    antipodal_threshold: float | None = None


class GraspOptionsIn(BaseModel):
    """Plan options (``sqmanip.grasping.PlanOptions``); omitted ones take the defaults."""

    model_config = ConfigDict(extra="forbid")
    n_samples: UInt32 | None = Field(None, description="Surface samples x1 (Algorithm 1); 256.")
    n_approach: UInt32 | None = Field(None, description="Approach directions per pair; 12.")
    antipodal_threshold: float | None = None
    beta: float | None = Field(None, description="Uncertainty weight of 3.6.3; 5.")
    max_results: UInt32 | None = Field(None, description="Grasps per target (20; 0 = all).")
    seed: Int64 | None = None
    score: Literal["top_down", "uncertainty"] | None = None
    method: Literal["antipodal", "rule_based"] | None = None
    gripper_points: UInt32 | None = None
    include_wrist: bool | None = None
    approach_distance: float | None = None
    support_clearance: float | None = None
    min_width: float | None = None
    check_target: bool | None = None
    check_reachability: bool = Field(
        True, description="Check the Panda IK (false: the gripper alone, geometry only)."
    )
    rule: RuleOptionsIn | None = None

    def to_domain(self):
        """``PlanOptions`` (domain validation: errors name ``options.<field>``)."""
        from sqmanip.errors import ValidationError
        from sqmanip.grasping import PlanOptions, RuleOptions
        from sqmanip.rpc import convert

        skip = {"check_reachability", "rule", "max_results"}
        kwargs = {k: v for k, v in self.model_dump().items() if v is not None and k not in skip}
        if self.max_results is not None:
            kwargs["max_results"] = None if self.max_results == 0 else self.max_results
        try:
            if self.rule is not None:
                rule = {k: v for k, v in self.rule.model_dump().items() if v is not None}
                try:
                    kwargs["rule"] = RuleOptions(**rule)
                except ValidationError as exc:
                    raise ValidationError(
                        convert.field_message("options.rule", exc.message)
                    ) from None
            return PlanOptions(**kwargs)
        except ValidationError as exc:
            if exc.message.startswith("options.rule."):
                raise
            raise ValidationError(convert.field_message("options", exc.message)) from None


class GraspsBody(BaseModel):
    """``POST /grasps``: either ``objects`` (as ``/recognize`` returns them) or a point cloud
    (``points`` [+ ``colors``, ``labels``, ``viewpoint``, ``workspace``, ``recognize``]) that
    the gateway first sends to perception. Grasps are planned for ``target_id`` or, when it is
    omitted, for every object (the others are obstacles)."""

    model_config = ConfigDict(extra="forbid")
    objects: list[ObjectIn] | None = Field(None, description="Recognized objects (/recognize).")
    target_id: Int32 | None = Field(None, description="Object id to grasp; omitted = every object.")
    points: list[list[float]] | None = Field(None, description="N x 3 world points (m).")
    colors: list[list[float]] | None = None
    labels: list[int] | None = None
    viewpoint: Vec3 | None = None
    workspace: WorkspaceIn | None = None
    recognize: RecognizeOptionsIn = Field(
        default_factory=RecognizeOptionsIn, description="Recognition options (cloud input)."
    )
    observed_points: list[list[float]] | None = Field(
        None,
        description="The target's observed points (score 'uncertainty' with objects input; "
        "with cloud input the target's recognized points are used).",
    )
    support_plane: SupportPlaneIn | None = Field(
        None,
        description="Support plane to avoid. Omitted: the recognized plane (cloud input) or a "
        "table at z = 0 (objects input); null: none.",
    )
    boxes: list[PartIn] = Field(default_factory=list, description="Fixed obstacles (shelf boxes).")
    gripper: GripperIn | None = None
    options: GraspOptionsIn = Field(default_factory=GraspOptionsIn)


class GraspOut(BaseModel):
    pose: PoseOut = Field(description="Gripper to world: approach = z axis, closing axis = y.")
    width: float = Field(description="Contact distance (m): open wider than this, then close.")
    score: float = Field(description="-z^T z_t (3.4.2), minus beta u if uncertainty-aware.")
    contacts: list[Vec3] | None = Field(None, description="The two antipodal contacts (world).")
    uncertainty: float | None = None


class GraspStatsOut(BaseModel):
    n_samples: int
    n_pairs: int
    n_candidates: int
    n_checked: int
    n_unreachable: int
    n_colliding: int
    collisions: dict[str, int]
    timings_ms: dict[str, float]


class TargetGraspsOut(BaseModel):
    target_id: int
    grasps: list[GraspOut] = Field(description="Feasible grasps, best first.")
    stats: GraspStatsOut


class GraspsResponse(BaseModel):
    targets: list[TargetGraspsOut]
    objects: list[ObjectOut] | None = Field(
        None, description="The recognized objects (cloud input only)."
    )
    support_plane: SupportPlaneOut | None = Field(None, description="The plane that was avoided.")


def grasp_out(grasp) -> GraspOut:
    contacts = None
    if grasp.contacts is not None:
        contacts = [tuple(float(v) for v in c) for c in np.asarray(grasp.contacts).reshape(-1, 3)]
    return GraspOut(
        pose=pose_out(grasp.pose),
        width=float(grasp.width),
        score=float(grasp.score),
        contacts=contacts,
        uncertainty=None if grasp.uncertainty is None else float(grasp.uncertainty),
    )


def target_grasps_out(target_id: int, result) -> TargetGraspsOut:
    s = result.stats
    return TargetGraspsOut(
        target_id=int(target_id),
        grasps=[grasp_out(g) for g in result.grasps],
        stats=GraspStatsOut(
            n_samples=s.n_samples,
            n_pairs=s.n_pairs,
            n_candidates=s.n_candidates,
            n_checked=s.n_checked,
            n_unreachable=s.n_unreachable,
            n_colliding=s.n_colliding,
            collisions={str(k): int(v) for k, v in s.collisions.items()},
            timings_ms={str(k): float(v) for k, v in s.timings_ms.items()},
        ),
    )


def object_out(obj: RecognizedObject) -> ObjectOut:
    return _object(obj, _parts(obj.parts))


# --- dynamics (/predict) --------------------------------------------------------------------------


class PredictBody(BaseModel):
    """``POST /predict``: N objects (one superquadric each, at its current pose) and K pushes."""

    model_config = ConfigDict(extra="forbid")
    objects: list[PartIn] = Field(
        description="The objects: one superquadric each (a /recognize part), pose = current pose."
    )
    actions: list[list[float]] = Field(
        description="K x 6 pushes (p_x, p_y, p_z, v_x, v_y, v_z), world frame (m): the tool tip "
        "moves to p, then to p + v."
    )
    model: str = Field(
        "sqpdnet",
        description="'sqpdnet', 'physics' (PyBullet re-simulation, 100 pushes in 8-20 s) or the "
        "name of another checkpoint on the server.",
    )


class PredictResponse(BaseModel):
    model: str
    num_actions: int
    num_objects: int
    poses: list[list[PoseOut]] = Field(
        description="K x N next poses: poses[k][i] is object i after push k."
    )
    failed: list[bool] | None = Field(
        None, description="Physics model: pushes the robot could not execute (poses unchanged)."
    )
    latency_ms: float = Field(description="Server-side inference time (ms).")


# --- MPC planner (/plan, /mpc/episodes) and shelf search (/search/...) ----------------------------


class GoalIn(BaseModel):
    """A moving goal: the object ``id`` should end at ``position`` (orientation used only with
    ``beta > 0``)."""

    model_config = ConfigDict(extra="forbid")
    id: int
    position: Vec3
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)


class TaskIn(BaseModel):
    """A pushing task (4.4.2, 4.7.3); the fields its ``kind`` needs (others must be omitted)."""

    model_config = ConfigDict(extra="forbid")
    kind: Literal["moving", "singulation", "grasping", "interactive_moving"]
    goals: list[GoalIn] | None = Field(None, description="moving: goals of some objects.")
    beta: float = Field(0.0, description="moving: weight of the orientation error (4.4.6).")
    tau: float | None = Field(None, description="singulation: pairwise distance (m), 0.20.")
    target_id: Int32 | None = Field(None, description="grasping, interactive_moving: the target.")
    goal: Vec3 | None = Field(None, description="interactive_moving: the target's goal (m).")

    def to_domain(self) -> Any:
        """The :mod:`sqmanip.planning.tasks` task; missing fields name ``task.<field>``."""
        from sqmanip.errors import ValidationError
        from sqmanip.planning import tasks

        if self.kind == "moving":
            if not self.goals:
                raise ValidationError("task.goals: required for moving (at least one goal)")
            goals = {}
            for g in self.goals:
                T = PoseIn(position=g.position, orientation=g.orientation).matrix()
                goals[g.id] = T
            return tasks.MovingTask(goals, self.beta)
        if self.kind == "singulation":
            return tasks.SingulationTask() if self.tau is None else tasks.SingulationTask(self.tau)
        if self.target_id is None:
            raise ValidationError(f"task.target_id: required for {self.kind}")
        if self.kind == "grasping":
            return tasks.GraspingTask(self.target_id)
        if self.goal is None:
            raise ValidationError("task.goal: required for interactive_moving")
        return tasks.InteractiveMovingTask(self.target_id, np.asarray(self.goal))


class MPCOptionsIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    num_sequences: UInt32 | None = Field(
        None,
        description="K sampled sequences (default 100; at most 100 with 'physics'). A moving "
        "step with SQPD-Net (horizon 1) scores every admissible push instead.",
    )
    horizon: UInt32 | None = Field(None, description="Default: 1, or 3 for grasping.")
    seed: Int64 | None = None
    dynamics_model: str = Field(
        "sqpdnet",
        description="'sqpdnet', 'physics' (PyBullet, 100 pushes in 8-20 s) or a checkpoint.",
    )

    def to_kwargs(self) -> dict[str, Any]:
        return self.model_dump()


class PlanBody(BaseModel):
    """``POST /plan``: recognized objects (``/recognize`` output) + task + options."""

    model_config = ConfigDict(extra="forbid")
    objects: list[ObjectIn] = Field(min_length=1)
    task: TaskIn
    options: MPCOptionsIn = Field(default_factory=MPCOptionsIn)


class ObjectPoseOut(BaseModel):
    id: int
    pose: PoseOut


class PlanOut(BaseModel):
    has_action: bool
    action: list[float] | None = Field(description="(p_x, p_y, p_z, v_x, v_y, v_z) to execute.")
    pushed_id: int | None
    predicted_next: list[ObjectPoseOut]
    cost: float | None = Field(description="Predicted terminal cost (null = no admissible push).")
    current_cost: float | None
    num_candidates: int
    num_sampled: int
    num_rejected_start: int
    num_rejected_workspace: int
    sequence: list[list[float]]
    timings_ms: dict[str, float]
    dynamics_model: str
    solved: bool


class MPCEpisodeBody(BaseModel):
    """``POST /mpc/episodes``: a generated scenario (kind, index, seed) run in the simulator."""

    model_config = ConfigDict(extra="forbid")
    kind: Literal[
        "moving", "singulation", "grasping_clutter", "grasping_large", "interactive_moving"
    ]
    index: UInt32 = 0
    seed: Int64 = 0
    objects: Literal["recognition", "ground_truth"] = "recognition"
    options: MPCOptionsIn = Field(default_factory=MPCOptionsIn)
    max_steps: int | None = Field(None, ge=0, le=100)


class SearchEpisodeBody(BaseModel):
    """``POST /search/episodes``: a shelf scenario (given, or generated from n_objects/seed)."""

    model_config = ConfigDict(extra="forbid")
    scenario: dict[str, Any] | None = Field(
        None, description="A ShelfScenario dict (as a result's 'scenario'); default: generate."
    )
    n_objects: int = Field(2, ge=0, le=12)
    seed: Int64 = 0
    method: Literal["search_for_grasp", "search_and_grasp"] = "search_for_grasp"
    shapes: Literal["oracle", "recognized"] = "oracle"
    actions: Literal["both", "push", "pick_and_place"] = "both"
    dynamics_model: str = Field("kinematic", description="'kinematic' or a dynamics model name.")
    max_steps: int | None = Field(None, ge=0, le=50)
    num_sequences: int | None = Field(None, ge=1, le=1000)
    plan_seed: Int64 = 0


class EpisodeStartedOut(BaseModel):
    id: str
    status: str


class EpisodeErrorOut(BaseModel):
    status: int
    code: str
    detail: str


class EpisodeOut(BaseModel):
    id: str
    kind: Literal["mpc", "search"]
    status: Literal["running", "done", "failed"]
    events: list[dict[str, Any]] = Field(description="Step events, oldest first (bounded).")
    n_events: int = Field(description="Events received in total (incl. dropped ones).")
    result: dict[str, Any] | None
    error: EpisodeErrorOut | None
    elapsed_s: float


class SearchTargetIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["cylinder", "box"] = "cylinder"
    size: Vec3 = Field(description="Half extents (a1, a2, a3) (m); a1 = a2 for a cylinder.")


class ShelfIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    front_x: float | None = None
    depth: float | None = None
    inner_width: float | None = None
    inner_height: float | None = None
    bottom_z: float | None = None
    thickness: float | None = None


class CameraIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    width: int = Field(ge=1, le=4096)
    height: int = Field(ge=1, le=4096)
    fx: float
    fy: float
    cx: float
    cy: float
    pose: PoseIn


class SearchEvaluateBody(BaseModel):
    """``POST /search/evaluate``: f and g maps of one shelf scene (C.2, C.3)."""

    model_config = ConfigDict(extra="forbid")
    objects: list[PartIn] = Field(description="The surrounding objects (target excluded).")
    target: SearchTargetIn | None = None
    shelf: ShelfIn | None = None
    camera: CameraIn | None = None
    target_visible: bool = False
    target_pose: PoseIn | None = None
    resolution: float | None = None
    n_theta: int | None = Field(None, ge=1, le=72)


class SearchEvaluateOut(BaseModel):
    shape: list[int]
    f: list[Any] = Field(description="Existence f over the grid, nested lists of `shape`.")
    g: list[Any]
    g_m: list[Any]
    grid_xy: list[list[float]]
    resolution: float
    objective: float
    timings_ms: dict[str, float]
