"""Typed results of the SDK: frozen dataclasses mirroring the gateway's JSON contract.

Frames and units: world frame right-handed, z up; metres and radians; quaternions (x, y, z, w);
poses map object coordinates to world coordinates.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import numpy as np

Kind = Literal["superellipsoid", "superparaboloid", "supertoroid"]


@dataclasses.dataclass(frozen=True)
class Pose:
    """Rigid transform, object to world."""

    position: tuple[float, float, float]
    """Origin of the object frame in the world frame (m)."""
    orientation: tuple[float, float, float, float]
    """Rotation object -> world as a unit quaternion (x, y, z, w)."""

    def matrix(self) -> np.ndarray:
        """4 x 4 homogeneous matrix (float64)."""
        x, y, z, w = self.orientation
        n = (x * x + y * y + z * z + w * w) ** 0.5 or 1.0
        x, y, z, w = x / n, y / n, z / n, w / n
        T = np.eye(4)
        T[:3, :3] = [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
        T[:3, 3] = self.position
        return T


@dataclasses.dataclass(frozen=True)
class SuperquadricPart:
    """One (deformable) superquadric part."""

    kind: Kind
    """superellipsoid | superparaboloid | supertoroid."""
    size: tuple[float, ...]
    """(a1, a2, a3) half extents along the object x, y, z axes (m); a4 appended for toroids."""
    shape: tuple[float, float]
    """(e1, e2) shape exponents: ~0.2 box-like, 1 round."""
    taper: float
    """Tapering k in [-1, 1] (thesis 2.3.12); 0 = none."""
    bend: float
    """Bending curvature b (1/m) (thesis 2.3.15); 0 = none."""
    bend_direction: float
    """Bending direction alpha in the object x-y plane (rad)."""
    pose: Pose
    """Object-to-world pose of the part."""


@dataclasses.dataclass(frozen=True)
class RecognizedObject:
    """One recognized object."""

    id: int
    """Object id, unique within the scene."""
    parts: tuple[SuperquadricPart, ...]
    """Its superquadric parts (one for a simple object)."""
    point_indices: np.ndarray
    """(K,) int64 indices of its points in the request cloud."""
    mean_color: tuple[float, float, float] | None
    """Mean RGB in [0, 1] of its points, or None when no colors were sent."""
    residual: float
    """Mean squared radial distance of its points to the fitted surface (m^2)."""
    confidence: float
    """Fit confidence in [0, 1]."""


@dataclasses.dataclass(frozen=True)
class SupportPlane:
    """Support surface ``normal . x + offset = 0`` found and removed by the service."""

    normal: tuple[float, float, float]
    """Unit normal pointing into free space (up)."""
    offset: float
    """Plane offset d (m)."""


@dataclasses.dataclass(frozen=True)
class Scene:
    """Result of :meth:`sqmanip_client.Client.recognize`."""

    objects: tuple[RecognizedObject, ...]
    """Recognized objects."""
    support_plane: SupportPlane | None
    """The support plane, or None if none was found or removal was off."""
    timings_ms: dict[str, float]
    """Server-side stage times (preprocess, segment, fit, total) in milliseconds."""


def _pose(d: dict[str, Any]) -> Pose:
    return Pose(tuple(d["position"]), tuple(d["orientation"]))  # type: ignore[arg-type]


def scene_from_json(d: dict[str, Any]) -> Scene:
    """Parse the gateway's ``/recognize`` JSON response."""
    objects = tuple(
        RecognizedObject(
            id=int(o["id"]),
            parts=tuple(
                SuperquadricPart(
                    kind=p["kind"],
                    size=tuple(float(v) for v in p["size"]),
                    shape=(float(p["shape"][0]), float(p["shape"][1])),
                    taper=float(p["taper"]),
                    bend=float(p["bend"]),
                    bend_direction=float(p["bend_direction"]),
                    pose=_pose(p["pose"]),
                )
                for p in o["parts"]
            ),
            point_indices=np.asarray(o["point_indices"], dtype=np.int64),
            mean_color=None if o.get("mean_color") is None else tuple(o["mean_color"]),
            residual=float(o["residual"]),
            confidence=float(o.get("confidence", 1.0)),
        )
        for o in d["objects"]
    )
    plane = d.get("support_plane")
    return Scene(
        objects=objects,
        support_plane=None
        if plane is None
        else SupportPlane(tuple(plane["normal"]), float(plane["offset"])),  # type: ignore[arg-type]
        timings_ms=dict(d.get("timings_ms", {})),
    )


# --- simulator -------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SimObject:
    """Ground truth of one simulated object."""

    id: int
    """Index in the scene spec; also its label in the segmentation and the point labels."""
    name: str
    kind: str
    """box | cylinder | superquadric | mesh."""
    pose: Pose
    """Object to world."""
    superquadric: SuperquadricPart | None
    """The spawned (box/cylinder-equivalent) superquadric at the current pose; None for meshes."""


@dataclasses.dataclass(frozen=True)
class SimState:
    """Simulator state between actions."""

    time: float
    """Simulated time since reset (s)."""
    scene_kind: str
    """tabletop | shelf."""
    objects: tuple[SimObject, ...]
    joint_positions: tuple[float, ...]
    """Panda arm joints (7, rad)."""
    gripper_width: float
    """Gripper opening (m)."""
    tcp_pose: Pose
    """Tool centre point (between the fingertips) to world."""
    held_object: int | None
    """Id of the object in the hand, or None."""


@dataclasses.dataclass(frozen=True)
class SimResetResult:
    state: SimState
    scene: dict[str, Any]
    """The scene as built (settled poses): pass it to ``sim_reset(scene=...)`` to replay."""


@dataclasses.dataclass(frozen=True)
class SimActionResult:
    """Outcome of an executed action (refused actions raise BadRequestError instead)."""

    success: bool
    message: str
    before: SimState
    after: SimState
    held_object: int | None
    sim_time: float
    """Simulated duration (s)."""


@dataclasses.dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics (OpenCV, pixels) and clipping range (m)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    near: float
    far: float


@dataclasses.dataclass(frozen=True)
class SimObservation:
    """One camera frame. The arrays are None when fetched with ``arrays=False``."""

    camera: str
    time: float
    intrinsics: CameraIntrinsics
    camera_pose: Pose
    """Optical frame (x right, y down, z forward) to world."""
    objects: tuple[SimObject, ...]
    """Ground truth at the time of the frame."""
    num_points: int
    point_counts: dict[int, int]
    """Cloud points per label (object ids >= 0, -2 static, -3 robot)."""
    shapes: dict[str, tuple[int, ...]]
    depth: np.ndarray | None = None
    """(H, W) float32 metres along the optical axis, 0 = no hit."""
    rgb: np.ndarray | None = None
    """(H, W, 3) uint8."""
    segmentation: np.ndarray | None = None
    """(H, W) int32 labels."""
    points: np.ndarray | None = None
    """(N, 3) float32 world-frame points (with sensor noise)."""
    point_labels: np.ndarray | None = None
    """(N,) int32 labels of the points."""
    point_pixels: np.ndarray | None = None
    """(N,) int32 flat pixel index of each point."""


def _part(p: dict[str, Any]) -> SuperquadricPart:
    return SuperquadricPart(
        kind=p["kind"],
        size=tuple(float(v) for v in p["size"]),
        shape=(float(p["shape"][0]), float(p["shape"][1])),
        taper=float(p["taper"]),
        bend=float(p["bend"]),
        bend_direction=float(p["bend_direction"]),
        pose=_pose(p["pose"]),
    )


def sim_object_from_json(d: dict[str, Any]) -> SimObject:
    sq = d.get("superquadric")
    return SimObject(
        id=int(d["id"]),
        name=str(d["name"]),
        kind=str(d["kind"]),
        pose=_pose(d["pose"]),
        superquadric=None if sq is None else _part(sq),
    )


def sim_state_from_json(d: dict[str, Any]) -> SimState:
    return SimState(
        time=float(d["time"]),
        scene_kind=str(d["scene_kind"]),
        objects=tuple(sim_object_from_json(o) for o in d["objects"]),
        joint_positions=tuple(float(q) for q in d["joint_positions"]),
        gripper_width=float(d["gripper_width"]),
        tcp_pose=_pose(d["tcp_pose"]),
        held_object=d.get("held_object"),
    )


def sim_action_from_json(d: dict[str, Any]) -> SimActionResult:
    return SimActionResult(
        success=bool(d["success"]),
        message=str(d["message"]),
        before=sim_state_from_json(d["before"]),
        after=sim_state_from_json(d["after"]),
        held_object=d.get("held_object"),
        sim_time=float(d["sim_time"]),
    )


def sim_observation_from_json(
    d: dict[str, Any], arrays: dict[str, np.ndarray] | None = None
) -> SimObservation:
    """The ``/sim/observe`` summary (plus the npz arrays, or ``include=points`` lists)."""
    arrays = dict(arrays or {})
    if "points" not in arrays and d.get("points") is not None:
        arrays["points"] = np.asarray(d["points"], dtype=np.float32).reshape(-1, 3)
        arrays["point_labels"] = np.asarray(d["point_labels"], dtype=np.int32)
    return SimObservation(
        camera=str(d["camera"]),
        time=float(d["time"]),
        intrinsics=CameraIntrinsics(**d["intrinsics"]),
        camera_pose=_pose(d["camera_pose"]),
        objects=tuple(sim_object_from_json(o) for o in d["objects"]),
        num_points=int(d["num_points"]),
        point_counts={int(k): int(v) for k, v in d["point_counts"].items()},
        shapes={k: tuple(v["shape"]) for k, v in d["arrays"].items()},
        depth=arrays.get("depth"),
        rgb=arrays.get("rgb"),
        segmentation=arrays.get("segmentation"),
        points=arrays.get("points"),
        point_labels=arrays.get("point_labels"),
        point_pixels=arrays.get("point_pixels"),
    )


# --- grasps and dynamics ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Grasp:
    """One ranked parallel-jaw grasp."""

    pose: Pose
    """Gripper to world: approach = z axis, closing axis = y axis, origin between the pads."""
    width: float
    """Distance between the contacts (m): open wider than this, then close."""
    score: float
    """Higher is better (top-down preference, minus the uncertainty penalty when asked)."""
    contacts: np.ndarray | None
    """(2, 3) world-frame antipodal contact points, or None."""
    uncertainty: float | None = None


@dataclasses.dataclass(frozen=True)
class TargetGrasps:
    """The grasps of one target object, best first, with the planner's counts and timings."""

    target_id: int
    grasps: tuple[Grasp, ...]
    stats: dict[str, Any]


@dataclasses.dataclass(frozen=True)
class GraspPlan:
    """Result of :meth:`sqmanip_client.Client.plan_grasps`."""

    targets: tuple[TargetGrasps, ...]
    objects: tuple[RecognizedObject, ...] | None
    """The recognized objects when a point cloud was sent, else None."""
    support_plane: SupportPlane | None
    """The support plane that was avoided."""

    def for_target(self, target_id: int) -> TargetGrasps:
        for t in self.targets:
            if t.target_id == target_id:
                return t
        raise KeyError(
            f"no grasps for target {target_id}; have {[t.target_id for t in self.targets]}"
        )


@dataclasses.dataclass(frozen=True)
class Prediction:
    """Result of :meth:`sqmanip_client.Client.predict`."""

    poses: np.ndarray
    """(K, N, 4, 4) float64: object i after push k is ``poses[k, i]``."""
    model: str
    failed: np.ndarray | None
    """(K,) bool for the physics model (pushes the robot could not execute), else None."""
    latency_ms: float


def grasp_plan_from_json(d: dict[str, Any]) -> GraspPlan:
    """Parse the gateway's ``/grasps`` JSON response."""
    targets = tuple(
        TargetGrasps(
            target_id=int(t["target_id"]),
            grasps=tuple(
                Grasp(
                    pose=_pose(g["pose"]),
                    width=float(g["width"]),
                    score=float(g["score"]),
                    contacts=None
                    if g.get("contacts") is None
                    else np.asarray(g["contacts"], dtype=np.float64).reshape(-1, 3),
                    uncertainty=g.get("uncertainty"),
                )
                for g in t["grasps"]
            ),
            stats=dict(t.get("stats", {})),
        )
        for t in d["targets"]
    )
    objects = None
    if d.get("objects") is not None:
        objects = scene_from_json({"objects": d["objects"]}).objects
    plane = d.get("support_plane")
    return GraspPlan(
        targets=targets,
        objects=objects,
        support_plane=None
        if plane is None
        else SupportPlane(tuple(plane["normal"]), float(plane["offset"])),  # type: ignore[arg-type]
    )


def prediction_from_json(d: dict[str, Any]) -> Prediction:
    """Parse the gateway's ``/predict`` JSON response."""
    k, n = int(d["num_actions"]), int(d["num_objects"])
    poses = np.zeros((k, n, 4, 4))
    for a, row in enumerate(d["poses"]):
        for i, p in enumerate(row):
            poses[a, i] = _pose(p).matrix()
    failed = d.get("failed")
    return Prediction(
        poses=poses,
        model=str(d["model"]),
        failed=None if failed is None else np.asarray(failed, dtype=bool),
        latency_ms=float(d.get("latency_ms", 0.0)),
    )
