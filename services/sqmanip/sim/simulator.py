"""The ``Simulator``: a headless PyBullet Panda with tabletop/shelf scenes, cameras and actions.

One instance owns one PyBullet DIRECT client; use it from one thread only. Everything is
deterministic for a given scene spec or seed: fixed time step and solver iterations, seeded
NumPy generators for scene sampling, IK restarts and sensor noise.

Actions (Ch. 4.5, 5.4.4): ``push(p, v)`` (tool to ``p`` with the Fig. 4.6 orientation, then to
``p + v`` through 10 via points, slowly), ``grasp(pose, width)`` (pre-grasp 10 cm back along the
tool z axis, approach, close, lift 10 cm, hold; the move to the pre-grasp goes through the start
of the 30 cm approach line when the direct joint line from home collides), ``pick_and_place``. Every action first checks
its arguments (``ValidationError``: non-finite, out of workspace, too wide) and then the
reachability (pinocchio IK) and static collisions (table, pedestal, shelf) of its key
configurations and of the free-space joint paths (``PreconditionError`` with the reason), so a
refused action never moves the robot.
"""

from __future__ import annotations

import contextlib
import itertools
import math
from typing import NamedTuple

import numpy as np
import pybullet as p

from ..errors import PreconditionError, ValidationError
from . import scene as sc
from .actions import (
    ActionResult,
    ObjectState,
    Observation,
    SimState,
    as_point,
    as_pose,
    as_width,
    lifted,
    offset_along_z,
    push_tool_rotation,
    tool_pose,
)
from .camera import (
    Intrinsics,
    add_point_noise,
    backproject,
    linearize_depth,
    look_at,
    projection_matrix,
    view_matrix,
)
from .config import (
    GRIPPER_MAX_WIDTH,
    HOME_SHELF,
    HOME_TABLETOP,
    LABEL_BACKGROUND,
    LABEL_ROBOT,
    LABEL_STATIC,
    ROBOT_BASE_POSITION,
    TABLE_FLOOR_DEPTH,
    TABLE_SIZE,
    WORKSPACE_CENTER,
    WORKSPACE_SIZE,
    ShelfGeometry,
    SimConfig,
)
from .kinematics import PandaKinematics
from .robot import FINGER_INDICES, HAND_LINK, PandaRobot

WRIST_CAMERA_OFFSET = np.array(
    [[0.0, -1.0, 0.0, 0.05], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.02], [0, 0, 0, 1.0]]
)
"""Optical frame of the wrist camera in the ``panda_hand`` frame: 5 cm off the hand axis,
looking along the approach (hand z), image x along -hand y."""


STATIC_FRICTION = 0.5
"""Lateral friction of the static boxes (pedestal, table, floor, shelf boards)."""


def static_boxes(
    layout: str, shelf: ShelfGeometry | None = None
) -> list[tuple[str, tuple[float, float, float], tuple[float, float, float], tuple]]:
    """``(name, half_extents, centre, rgba)`` of the static boxes of a ``tabletop`` or
    ``shelf`` world: the robot's pedestal, then the table and the floor below it (or the floor
    and the shelf boards). Each floor is 3 x 3 m, the physics baseline's grid spacing."""
    bx, by, bz = ROBOT_BASE_POSITION
    out = [("pedestal", (0.12, 0.12, bz / 2), (bx, by, bz / 2), (0.3, 0.3, 0.3, 1))]
    if layout == "tabletop":
        tx, ty, tz = TABLE_SIZE
        center = (WORKSPACE_CENTER[0] + 0.1, WORKSPACE_CENTER[1], -tz / 2)
        out.append(("table", (tx / 2, ty / 2, tz / 2), center, (0.75, 0.7, 0.6, 1)))
        out.append(("floor", (1.5, 1.5, 0.01), (0.5, 0.0, -TABLE_FLOOR_DEPTH - 0.01),
                    (0.6, 0.6, 0.6, 1)))  # fmt: skip
    else:
        out.append(("floor", (1.5, 1.5, 0.01), (0.5, 0.0, -0.01), (0.6, 0.6, 0.6, 1)))
        for name, half, center in (shelf or ShelfGeometry()).boxes():
            out.append((name, half, center, (0.55, 0.4, 0.25, 1)))
    return out


def configure_physics(client: int, config: SimConfig) -> None:
    """Time step, solver iterations, deterministic pair order and gravity of ``config``."""
    p.setPhysicsEngineParameter(
        fixedTimeStep=config.time_step,
        numSolverIterations=config.solver_iterations,
        numSubSteps=0,
        deterministicOverlappingPairs=1,
        physicsClientId=client,
    )
    p.setGravity(0, 0, config.gravity, physicsClientId=client)


def check_push_vector(v: np.ndarray) -> None:
    """``ValidationError`` unless ``|v|`` is in [0.0001, 0.5] m (what :meth:`Simulator.push`
    accepts)."""
    if np.linalg.norm(v) < 1e-4 or np.linalg.norm(v) > 0.5:
        raise ValidationError(f"|v| must be in [0.0001, 0.5] m, got {np.linalg.norm(v):.4f}")


def check_in_region(x: np.ndarray, bounds: np.ndarray, name: str, region: str) -> None:
    """``ValidationError`` when the point ``x`` is outside ``bounds (2, 3)`` (1e-6 m slack)."""
    tol = 1e-6
    if np.any(x < bounds[0] - tol) or np.any(x > bounds[1] + tol):
        raise ValidationError(
            f"{name} {np.round(x, 4).tolist()} is out of workspace: the {region} is "
            f"{np.round(bounds[0], 3).tolist()} .. {np.round(bounds[1], 3).tolist()}"
        )


def push_tool_poses(
    p0: np.ndarray,
    v: np.ndarray,
    yaw_offset: float,
    shelf: ShelfGeometry | None = None,
    upright: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Tool poses ``(pre, start, end, post)`` (4 x 4, world) of a push from ``p0`` along ``v``
    with the Fig. 4.6 orientation (:func:`.actions.push_tool_rotation`): on the tabletop the
    pre-push and post-push poses are above the start and the end (at 0.25 m, at least 5 cm
    higher); in the shelf (``shelf`` given) 12 cm back along the tool z axis (level, -x), and
    at least out to 2 cm before the opening: from a pose deep inside, the joint-space line home
    swung the arm through a side wall (a third of the refused shelf pushes). ``upright``: the
    hand turned on its side (:func:`.actions.push_tool_rotation`), in the shelf only."""
    R = push_tool_rotation(v, yaw_offset, down=shelf is None, upright=upright)
    T_start = tool_pose(R, p0)
    T_end = tool_pose(R, p0 + v)
    if shelf is not None:
        T_pre = offset_along_z(T_start, -0.12)
        T_pre[0, 3] = min(T_pre[0, 3], shelf.front_x - 0.02)
        T_post = offset_along_z(T_end, -0.12)
        T_post[0, 3] = min(T_post[0, 3], shelf.front_x - 0.02)
    else:
        T_pre = lifted(T_start, max(0.25 - p0[2], 0.05))
        T_post = lifted(T_end, max(0.25 - T_end[2, 3], 0.05))
    return T_pre, T_start, T_end, T_post


def static_hits(robot: PandaRobot, static: dict[int, str], margin: float) -> list[str]:
    """Names of the ``static`` bodies (id -> name) that ``robot``, as it is posed now, comes
    closer to than ``margin`` (m); the links that stand on the pedestal do not count."""
    hits = []
    for body, name in static.items():
        for c in p.getClosestPoints(robot.body, body, margin, physicsClientId=robot.client):
            if c[3] <= 0 and name == "pedestal":  # the base stands on it
                continue
            if c[8] < margin:
                hits.append(name)
                break
    return hits


def joint_path(q0: np.ndarray, q1: np.ndarray, n: int = 8) -> list[np.ndarray]:
    """The ``n`` configurations strictly between ``q0`` and ``q1`` on the joint-space line that
    :meth:`Simulator.push` and the grasps check for collisions."""
    return [q0 + s * (q1 - q0) for s in np.linspace(0, 1, n + 2)[1:-1]]


GRASP_PATH_STEP = 0.05
"""Largest joint change (rad) between the checked configurations of the path to a pre-grasp
pose. The path from home to a low side grasp can turn the wrist by 2 rad; 8 samples along it
missed the hand crossing a box that the move then knocked off the table."""


def grasp_path_samples(q0: np.ndarray, q1: np.ndarray) -> int:
    """How many configurations :func:`joint_path` checks between ``q0`` and ``q1`` (at least 8)."""
    largest = float(np.abs(np.asarray(q1) - np.asarray(q0)).max())
    return max(8, math.ceil(largest / GRASP_PATH_STEP))


class GraspPlan(NamedTuple):
    """Joint configurations of a grasp (:meth:`Simulator.plan_grasp`): the free-space move goes
    to ``via`` first when there is one (the start of the approach line, see
    :attr:`SimConfig.grasp_via_distance`), then to ``pre``; ``grasp`` closes, ``lift`` lifts."""

    pre: np.ndarray
    grasp: np.ndarray
    lift: np.ndarray
    via: np.ndarray | None = None


def workspace_bounds() -> np.ndarray:
    """``(2, 3)`` lower/upper corners of the tabletop workspace (Ch. 4.5) in the world."""
    cx, cy = WORKSPACE_CENTER
    sx, sy, sz = WORKSPACE_SIZE
    return np.array([[cx - sx / 2, cy - sy / 2, 0.0], [cx + sx / 2, cy + sy / 2, sz]])


class Simulator:
    """PyBullet Panda simulator (domain API; a gRPC servicer wraps these methods)."""

    def __init__(self, config: SimConfig | None = None) -> None:
        self.config = config or SimConfig()
        self.client = p.connect(p.DIRECT)
        base = np.eye(4)
        base[:3, 3] = ROBOT_BASE_POSITION
        self.kin = PandaKinematics(base)
        self._spec = sc.SceneSpec()
        self._bodies: list[int] = []
        self._static: dict[int, str] = {}
        self._time = 0.0
        self._held: int | None = None
        self._noise_rng = np.random.default_rng(0)
        self._ik_rng = np.random.default_rng(0)
        n = max(self.config.grasp_ik_seeds, 0)
        self._grasp_restart = [np.random.default_rng(0).uniform(self.kin.lower, self.kin.upper)][:n]
        """The IK's first random restart (``kin.ik`` with rng 0), the first extra grasp seed."""
        draw = np.random.default_rng(12345)
        self._grasp_seed_offsets = [draw.normal(0.0, 0.5, 7) for _ in range(n - 1)]
        """Offsets from the home configuration of the other extra grasp IK seeds (rad):
        solutions near home's branch; uniform draws over the joint range gave configurations
        the arm could not track (a joint at its limit, a 4 rad swing of joint 1)."""
        self.robot: PandaRobot | None = None
        self.reset(self._spec)

    # --- lifecycle ----------------------------------------------------------------------------

    def close(self) -> None:
        if self.client >= 0:
            p.disconnect(self.client)
            self.client = -1

    def __enter__(self) -> Simulator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):  # interpreter shutdown
            self.close()

    @property
    def scene_spec(self) -> sc.SceneSpec:
        """The current scene (settled poses after a random reset): save it to replay."""
        return self._spec

    @property
    def home(self) -> np.ndarray:
        return HOME_SHELF if self._spec.kind == "shelf" else HOME_TABLETOP

    def _step(self) -> None:
        p.stepSimulation(physicsClientId=self.client)
        self._time += self.config.time_step

    def reset(
        self,
        scene: sc.SceneSpec | dict | None = None,
        *,
        seed: int | None = None,
        n_objects: int = 4,
        kind: str = "tabletop",
        object_kinds: tuple[str, ...] = ("box", "cylinder"),
    ) -> SimState:
        """Rebuild the world from ``scene`` (spec or its dict), or sample a random scene.

        With ``seed`` (and no ``scene``) ``n_objects`` random boxes/cylinders are dropped one by
        one into the workspace (or shelf), each allowed to settle; a drop that falls over (for
        upright objects), interpenetrates another object or leaves the workspace is removed and
        redrawn (up to 20 tries). The settled poses become ``scene_spec``.
        """
        if isinstance(scene, dict):
            scene = sc.SceneSpec.from_dict(scene)
        if scene is None and seed is None:
            raise ValidationError("reset needs a scene spec or a seed")
        if scene is not None and seed is not None:
            raise ValidationError("give either a scene spec or a seed, not both")
        if scene is None and not 0 <= n_objects <= 20:
            raise ValidationError(f"n_objects must be in 0..20, got {n_objects}")
        cid = self.client
        cfg = self.config
        p.resetSimulation(physicsClientId=cid)
        configure_physics(cid, cfg)
        self._time = 0.0
        self._held = None
        self._bodies = []
        self._static = {}
        layout = scene.kind if scene is not None else kind
        self._build_static(layout)
        self.robot = PandaRobot(cid, ROBOT_BASE_POSITION, cfg, self._step)
        home = HOME_SHELF if layout == "shelf" else HOME_TABLETOP
        self.robot.reset_q(home, 0.0)
        if scene is not None:
            self._spec = scene
            for spec in scene.objects:
                self._bodies.append(sc.spawn(spec, cid))
            self._noise_rng = np.random.default_rng(scene.seed)
        else:
            self._spec = self._random_scene(layout, int(seed), n_objects, object_kinds)
            self._noise_rng = np.random.default_rng(int(seed))
        self._ik_rng = np.random.default_rng(self._spec.seed + 1)
        return self.get_state()

    def _add_static_box(self, name: str, half, center, color) -> int:
        cid = self.client
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(half), physicsClientId=cid)
        vis = p.createVisualShape(
            p.GEOM_BOX, halfExtents=list(half), rgbaColor=list(color), physicsClientId=cid
        )
        body = p.createMultiBody(0.0, col, vis, list(center), physicsClientId=cid)
        p.changeDynamics(body, -1, lateralFriction=STATIC_FRICTION, physicsClientId=cid)
        self._static[body] = name
        return body

    def _build_static(self, layout: str) -> None:
        for name, half, center, color in static_boxes(layout, self.config.shelf):
            self._add_static_box(name, half, center, color)

    # --- random scenes -------------------------------------------------------------------------

    def _drop_region(self, layout: str) -> tuple[np.ndarray, float]:
        if layout == "shelf":
            b = self.config.shelf.inner_bounds()
            return np.array(
                [[b[0, 0] + 0.06, b[0, 1] + 0.06], [b[1, 0] - 0.06, b[1, 1] - 0.06]]
            ), b[0, 2]
        w = workspace_bounds()
        return np.array([[w[0, 0] + 0.06, w[0, 1] + 0.06], [w[1, 0] - 0.06, w[1, 1] - 0.06]]), 0.0

    def _random_scene(self, layout, seed, n, object_kinds) -> sc.SceneSpec:
        rng = np.random.default_rng(seed)
        region, floor = self._drop_region(layout)
        specs: list[sc.ObjectSpec] = []
        for _ in range(n):
            for _attempt in range(20):
                spec = sc.random_object(rng, object_kinds)
                if (
                    layout == "shelf"
                    and sc.half_height(spec) * 2 > self.config.shelf.inner_height - 0.1
                ):
                    continue
                xy = rng.uniform(region[0], region[1])
                yaw = rng.uniform(-np.pi, np.pi)
                z = floor + sc.half_height(spec) + 0.01
                quat = p.getQuaternionFromEuler([0, 0, yaw])
                spec = spec.with_pose((xy[0], xy[1], z), quat)
                body = sc.spawn(spec, self.client)
                self._settle([*self._bodies, body])
                if self._acceptable(body, spec, layout):
                    self._bodies.append(body)
                    specs.append(spec)
                    break
                p.removeBody(body, physicsClientId=self.client)
        self._settle(self._bodies)
        settled = []
        for spec, body in zip(specs, self._bodies, strict=True):
            pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
            settled.append(spec.with_pose(pos, orn))
        # Replaying must start from rest: zero the velocities left by settling.
        for body in self._bodies:
            p.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=self.client)
        return sc.SceneSpec(layout, tuple(settled), seed)

    def _settle(self, bodies: list[int]) -> None:
        steps = int(self.config.settle_time / self.config.time_step)
        for i in range(steps):
            self._step()
            if i % 10 == 9 and i > 30:
                moving = False
                for b in bodies:
                    lv, av = p.getBaseVelocity(b, physicsClientId=self.client)
                    if np.linalg.norm(lv) > 2e-3 or np.linalg.norm(av) > 2e-2:
                        moving = True
                        break
                if not moving:
                    return

    def _acceptable(self, body: int, spec: sc.ObjectSpec, layout: str) -> bool:
        cid = self.client
        pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        R = np.asarray(p.getMatrixFromQuaternion(orn)).reshape(3, 3)
        if spec.upright and R[2, 2] < np.cos(np.deg2rad(15)):
            return False
        region, floor = self._drop_region(layout)
        if not (
            np.all(np.asarray(pos[:2]) > region[0] - 0.05)
            and np.all(np.asarray(pos[:2]) < region[1] + 0.05)
        ):
            return False
        if pos[2] < floor - 0.01:
            return False
        for other in self._bodies:
            for c in p.getContactPoints(body, other, physicsClientId=cid):
                if c[8] < -0.003:
                    return False
        return True

    # --- state -----------------------------------------------------------------------------------

    def _object_states(self) -> tuple[ObjectState, ...]:
        out = []
        for i, (spec, body) in enumerate(zip(self._spec.objects, self._bodies, strict=True)):
            pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
            T = sc.pose_matrix(pos, orn)
            out.append(
                ObjectState(
                    id=i,
                    name=spec.name or f"{spec.kind}_{i}",
                    kind=spec.kind,
                    pose=T,
                    position=np.array(pos),
                    quaternion=np.array(orn),
                    superquadric=spec.superquadric(T),
                )
            )
        return tuple(out)

    def get_state(self) -> SimState:
        r = self._require_robot()
        return SimState(
            time=self._time,
            scene_kind=self._spec.kind,
            objects=self._object_states(),
            joint_positions=r.q(),
            gripper_width=r.gripper_width(),
            tcp_pose=self.kin.fk(r.q()),
            held_object=self._held,
        )

    def _require_robot(self) -> PandaRobot:
        if self.robot is None or self.client < 0:
            raise PreconditionError("simulator is closed")
        return self.robot

    # --- cameras ----------------------------------------------------------------------------------

    def camera_pose(self, camera: str) -> np.ndarray:
        """Optical-frame pose of a named camera: ``wrist`` (on the hand), ``shelf`` (fixed in
        front of the shelf) or ``overview`` (fixed, above the workspace)."""
        if camera == "wrist":
            return self._require_robot().link_pose(HAND_LINK) @ WRIST_CAMERA_OFFSET
        if camera == "shelf":
            s = self.config.shelf
            target = (s.front_x + 0.5 * s.depth, 0.0, s.bottom_z + 0.08)
            return look_at((s.front_x - 0.50, -0.30, s.bottom_z + 0.30), target)
        if camera == "overview":
            cx, cy = WORKSPACE_CENTER
            return look_at((cx - 0.35, cy, 0.75), (cx, cy, 0.0))
        raise ValidationError(
            f"camera must be 'wrist', 'shelf', 'overview' or 'default', got {camera!r}"
        )

    def observe(
        self,
        camera: str = "default",
        *,
        intrinsics: Intrinsics | None = None,
        camera_pose: np.ndarray | None = None,
        noise: bool = True,
    ) -> Observation:
        """Render one frame: depth, RGB, instance segmentation, noisy world point cloud, truth.

        ``camera='default'`` is the wrist camera on the tabletop and the shelf camera on the
        shelf. ``camera_pose`` (optical frame to world) overrides the named pose.
        """
        r = self._require_robot()
        if camera == "default":
            camera = "shelf" if self._spec.kind == "shelf" else "wrist"
        k = intrinsics or Intrinsics()
        T_wc = (
            as_pose(camera_pose, "camera_pose")
            if camera_pose is not None
            else self.camera_pose(camera)
        )
        _, _, rgba, depth_buf, seg = p.getCameraImage(
            k.width,
            k.height,
            viewMatrix=view_matrix(T_wc),
            projectionMatrix=projection_matrix(k),
            renderer=p.ER_TINY_RENDERER,
            physicsClientId=self.client,
        )
        rgb = np.asarray(rgba, np.uint8).reshape(k.height, k.width, 4)[..., :3].copy()
        depth = linearize_depth(np.asarray(depth_buf).reshape(k.height, k.width), k)
        seg_raw = np.asarray(seg, np.int64).reshape(k.height, k.width)
        labels = np.full(seg_raw.shape, LABEL_BACKGROUND, np.int32)
        for i, b in enumerate(self._bodies):
            labels[seg_raw == b] = i
        for b, name in self._static.items():  # the pedestal is the robot's mount: robot points
            labels[seg_raw == b] = LABEL_ROBOT if name == "pedestal" else LABEL_STATIC
        labels[seg_raw == r.body] = LABEL_ROBOT
        depth[labels == LABEL_BACKGROUND] = np.inf
        pts, idx = backproject(depth, k, T_wc)
        if noise and self.config.point_noise_std > 0:
            pts = add_point_noise(pts, self.config.point_noise_std, self._noise_rng)
        depth_out = np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)
        return Observation(
            camera=camera,
            intrinsics=k,
            camera_pose=T_wc,
            depth=depth_out,
            rgb=rgb,
            segmentation=labels,
            points=pts,
            point_labels=labels.reshape(-1)[idx],
            point_pixels=idx,
            objects=self._object_states(),
            time=self._time,
        )

    # --- checks ------------------------------------------------------------------------------------

    def _solve(
        self, T: np.ndarray, q_seed: np.ndarray, what: str, restarts: int | None = None
    ) -> np.ndarray:
        """IK from ``q_seed`` (then the ready pose and random restarts; ``restarts=0``: only
        those two, deterministic)."""
        if restarts is None:
            res = self.kin.ik(T, q_seed, rng=self._ik_rng)
        else:
            res = self.kin.ik(T, q_seed, restarts=restarts)
        if not res.success:
            raise PreconditionError(
                f"{what} at {np.round(T[:3, 3], 3).tolist()} is unreachable "
                f"(IK error {res.position_error * 1000:.1f} mm, {res.rotation_error:.3f} rad "
                "inside the joint limits)"
            )
        return res.q

    def _collisions(
        self, q: np.ndarray, width: float, *, objects: bool = False, margin: float | None = None
    ) -> list[str]:
        """Names of static bodies (and objects, when asked) the robot at ``(q, width)`` touches."""
        r = self._require_robot()
        margin = self.config.collision_margin if margin is None else margin
        snap = r.snapshot()
        hits: list[str] = []
        try:
            r.pose_config(q, width)
            hits += static_hits(r, self._static, margin)
            if objects:
                for i, body in enumerate(self._bodies):
                    if i == self._held:
                        continue
                    for c in p.getClosestPoints(r.body, body, 0.0, physicsClientId=self.client):
                        if c[8] < -0.001:
                            hits.append(f"object {i}")
                            break
        finally:
            r.restore(snap)
        return hits

    def _check_free(self, q: np.ndarray, width: float, what: str, objects: bool = False) -> None:
        hits = self._collisions(q, width, objects=objects)
        if hits:
            names = ", ".join(sorted(set(hits)))
            kind = "shelf" if any(h.startswith("shelf") for h in hits) else names
            extra = ""
            if any(h.startswith("object") for h in hits) and what.startswith("grasp"):
                extra = f" (object wider than the {width:.3f} m opening, or in the fingers' way)"
            err = PreconditionError(f"{what} collides with {kind} ({names}){extra}")
            err.bodies = tuple(sorted(set(hits)))  # what was hit, for callers that re-plan
            raise err

    def _tool_line(
        self, T0: np.ndarray, T1: np.ndarray, q0: np.ndarray, what: str
    ) -> list[np.ndarray]:
        """Configurations along the straight tool line from ``T0`` (at ``q0``) to ``T1`` (same
        orientation): evenly spaced poses, one per ``push_approach_step``, each IK seeded at
        the previous one; the last is at ``T1``. A joint-space line between
        the ends instead can sweep the hand far off the line: from the pre-push pose at the
        shelf opening to a start 20 cm deep it dipped under the floor board and stalled there,
        and the push then moved nothing."""
        d = T1[:3, 3] - T0[:3, 3]
        n = max(1, math.ceil(float(np.linalg.norm(d)) / self.config.push_approach_step))
        out, q = [], q0
        for k in range(1, n + 1):
            q = self._solve(tool_pose(T1[:3, :3], T0[:3, 3] + d * k / n), q, what)
            out.append(q)
        return out

    def _check_path(
        self,
        q0: np.ndarray,
        q1: np.ndarray,
        width: float,
        what: str,
        n: int = 8,
        objects: bool = False,
    ) -> None:
        for q in joint_path(q0, q1, n):
            self._check_free(q, width, f"joint path to {what}", objects=objects)

    def _check_idle(self) -> None:
        if self._held is not None:
            raise PreconditionError(f"gripper is holding object {self._held}; call release() first")

    def _in_workspace(self, x: np.ndarray, name: str) -> None:
        if self._spec.kind == "shelf":
            check_in_region(x, self.config.shelf.inner_bounds(), name, "shelf interior")
        else:
            check_in_region(x, workspace_bounds(), name, "workspace")

    def _result(self, ok: bool, msg: str, before: SimState, t0: float) -> ActionResult:
        after = self.get_state()
        return ActionResult(ok, msg, before, after, self._held, self._time - t0)

    # --- actions ---------------------------------------------------------------------------------

    def push(self, p_start, v, upright: bool = False) -> ActionResult:
        """Push (Ch. 4.5): from home to the pre-push pose (:func:`push_tool_poses`), the tool
        tip to ``p`` with the Fig. 4.6 orientation, then to ``p + v`` through
        ``push_via_points`` via points at ``push_speed``, back to the post-push pose and home.
        In the shelf the moves to ``p`` and back go along straight tool lines
        (:meth:`_tool_line`); on the tabletop the pre- and post-push poses are right above the
        start and the end, and the joint-space moves between them (which the Table 4.6 runs and
        the SQPD-Net data used) are kept. ``upright`` (shelf only) turns the hand on its side,
        its 20 cm vertical (:func:`.actions.push_tool_rotation`): ``p`` must then be at least
        half that above the floor.

        The pre-push IK is seeded at home, with each of the two hand yaws; in the shelf, where
        that path flips a joint or meets a board, at the extra seeds of :meth:`plan_grasp` too.
        ``benchmarks.shelf_pushes`` (one cylinder at 25 floor positions, pushed 10 cm each way,
        the hand placed as the search planner places it): the upright hand executed 41 of 50
        pushes against 31 with home alone (16 joint flips, mostly 20 cm from the middle, where
        it is needed), the level one 30 against 28; pushed away from a side board the upright
        hand executed 12 of 12 at 9 to 11 cm against 10. R-Search-for-Grasp on fresh scenes
        (seed 2900, 6 and 8 objects, with the seen-target rule of
        :meth:`sqmanip.search.ActionSampler.candidates`), paired against the committed planner
        before: 21/19 of 30 grasped against 20/20 (3 won, 3 lost), 26 refused actions against
        64 (``benchmarks/results/search_r_sfg_6_8obj_seed2900_30x*.json``); at 2 and 4 objects
        27/24 against 27/25 (0 won, 1 lost; ``search_r_sfg_2_4obj_seed2900_30x*.json``).
        """
        r = self._require_robot()
        cfg = self.config
        p0 = as_point(p_start, "p")
        v = as_point(v, "v")
        check_push_vector(v)
        self._in_workspace(p0, "push start p")
        self._in_workspace(p0 + v, "push end p + v")
        self._check_idle()
        shelf = self._spec.kind == "shelf"
        if upright and not shelf:
            raise ValidationError("upright pushes are for the shelf scene only")
        q_home = self.home
        seeds = [None]  # home, with the IK's random restarts
        if shelf:
            seeds += self._extra_ik_seeds(q_home)
        hands = [push_tool_poses(p0, v, yaw, cfg.shelf if shelf else None, upright)
                 for yaw in (0.0, np.pi)]  # fmt: skip
        plan = None
        unreachable: list[str] = []
        collides: list[PreconditionError] = []
        for seed, tool_poses in itertools.product(seeds, hands):
            try:
                chain = self._push_chain(p0, v, tool_poses, seed, shelf)
            except PreconditionError as exc:
                unreachable.append(str(exc))
                continue
            try:
                self._check_push_free(chain, shelf)
            except PreconditionError as exc:
                collides.append(exc)
                continue
            plan = chain
            break
        if plan is None:
            if collides:
                raise collides[0]
            raise PreconditionError(f"push unreachable: {unreachable[0]}")
        q_pre, q_in, qs, q_out = plan

        before = self.get_state()
        t0 = self._time
        teleport = cfg.push_transit == "teleport"
        if teleport:  # the free-space path was checked above; nothing is touched along it
            r.reset_q(q_pre, 0.0)
        else:
            r.actuate_gripper(0.0, max_time=0.3)
            r.move_joints(q_pre)

        def transit(q_line: list[np.ndarray]) -> None:  # to the start, or back from the end
            if shelf:
                r.follow(q_line, [cfg.push_approach_step / cfg.push_transit_speed] * len(q_line))
            else:
                r.move_joints(q_line[-1], speed=0.2)

        transit(q_in)
        seg = float(np.linalg.norm(v)) / cfg.push_via_points / cfg.push_speed
        r.follow(qs, [seg] * len(qs))
        transit(q_out)
        if teleport:
            r.reset_q(q_home, 0.0)
            self._settle(self._bodies)  # what the move home gave: objects at rest
        else:
            r.move_joints(q_home)
        return self._result(True, "pushed", before, t0)

    def _extra_ik_seeds(self, q: np.ndarray) -> list[np.ndarray]:
        """The ``grasp_ik_seeds`` seeds tried after ``q``: the IK's first random restart, then
        the fixed offsets from ``q`` (clamped to the joint limits)."""
        return self._grasp_restart + [self.kin.clamp(q + d) for d in self._grasp_seed_offsets]

    def _push_chain(
        self, p0: np.ndarray, v: np.ndarray, tool_poses, seed: np.ndarray | None, shelf: bool
    ) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
        """Configurations ``(pre-push, approach, via points, retreat)`` of one push, the
        pre-push IK seeded at home (``seed=None``, with the IK's random restarts) or, kept
        0.1 rad inside the joint limits, at ``seed``; raises when a pose is unreachable or
        the path flips a joint."""
        cfg = self.config
        T_pre, T_start, T_end, T_post = tool_poses
        R = T_start[:3, :3]
        if seed is None:
            q_pre = self._solve(T_pre, self.home, "pre-push pose")
        else:
            q_pre = self._solve(T_pre, seed, "pre-push pose", restarts=0)
        if shelf:
            q_in = self._tool_line(T_pre, T_start, q_pre, "push approach")
        else:
            q_in = [self._solve(T_start, q_pre, "push start")]
        qs, q_prev = [], q_in[-1]
        for k in range(1, cfg.push_via_points + 1):
            q_prev = self._solve(
                tool_pose(R, p0 + v * k / cfg.push_via_points), q_prev, "push via point"
            )
            qs.append(q_prev)
        if shelf:
            q_out = self._tool_line(T_end, T_post, qs[-1], "post-push retreat")
        else:
            q_out = [self._solve(T_post, qs[-1], "post-push pose")]
        path = [q_pre, *q_in, *qs, *q_out] if shelf else [*q_in, *qs]
        if np.max(np.abs(np.diff(np.stack(path), axis=0))) > 0.6:
            raise PreconditionError("push path needs a joint flip (unreachable as a straight line)")
        if seed is not None and not all(self.kin.within_limits(q, 0.1) for q in path):
            raise PreconditionError("push needs a joint at its limit")
        return q_pre, q_in, qs, q_out

    def _check_push_free(self, chain, shelf: bool) -> None:
        """Raises when a push's configurations or its joint paths from the robot's current
        configuration and back home meet a static body."""
        q_pre, q_in, qs, q_out = chain
        self._check_free(q_pre, 0.0, "pre-push configuration")
        for q in q_in:
            self._check_free(q, 0.0, "push approach configuration")
        self._check_free(qs[-1], 0.0, "push end configuration")
        for q in q_out if shelf else ():
            self._check_free(q, 0.0, "post-push retreat configuration")
        self._check_path(self._require_robot().q(), q_pre, 0.0, "pre-push pose")
        self._check_path(q_out[-1], self.home, 0.0, "home")

    def plan_grasp(
        self, pose: np.ndarray, width: float, q_start: np.ndarray, *, objects: bool = True
    ) -> GraspPlan:
        """Joint configurations (:class:`GraspPlan`) for a grasp at tool ``pose`` from
        ``q_start``, without moving; :meth:`grasp` and :meth:`pick_and_place` execute them.

        The pre-grasp IK is seeded at ``q_start``, then at ``grasp_ik_seeds`` more: the IK's
        first random restart and fixed offsets from ``q_start`` (these chains must keep 0.1 rad
        from the joint limits); the grasp and the lift are each seeded at the previous
        solution, and the approach may not flip a joint (1 rad). The first chain whose
        pre-grasp and grasp configurations and joint path from ``q_start`` (sampled every
        :data:`GRASP_PATH_STEP`) are free of the static bodies (and of the objects, with
        ``objects``), and whose lift configuration is free of the static bodies, wins.
        When the joint-space line from ``q_start`` to the pre-grasp hits something, the chain
        may instead go through ``via``: the tool on the grasp's approach line,
        ``grasp_via_distance`` back from the grasp, then along that line to the pre-grasp
        (both segments checked the same way). From the shelf robot's home the direct line
        to a deep pose swings the arm through the top board (a third of the shelf grasps
        failed only on it); the approach line is the one the planner's C.3 afterimage checks.
        Deterministic. Raises :class:`PreconditionError` when no seed gives such a chain: the
        first seed's reason, or, when an object stopped a seed, that seed's (its ``bodies``
        name the objects, so a caller knows what to move: the first seed alone often failed
        on its IK and hid that another seed's arm only needed an object out of the way)."""
        a = self.config.approach_distance
        T_pre, T_lift = offset_along_z(pose, -a), lifted(pose, a)
        first: PreconditionError | None = None
        blocked: PreconditionError | None = None  # the first seed an object stopped
        tried: list[np.ndarray] = []
        for k, seed in enumerate((q_start, *self._extra_ik_seeds(q_start))):
            try:
                q_pre = self._solve(T_pre, seed, "pre-grasp pose", restarts=0)
                if any(np.abs(q_pre - q).max() < 1e-2 for q in tried):
                    continue
                tried.append(q_pre)
                q_grasp = self._solve(pose, q_pre, "grasp pose", restarts=0)
                if np.abs(q_grasp - q_pre).max() > 1.0:
                    raise PreconditionError("grasp approach needs a joint flip")
                q_lift = self._solve(T_lift, q_grasp, "lift pose", restarts=0)
                if k and not all(self.kin.within_limits(q, 0.1) for q in (q_pre, q_grasp, q_lift)):
                    raise PreconditionError("grasp needs a joint at its limit")
                self._check_free(q_pre, width, "pre-grasp configuration", objects=objects)
                self._check_free(q_grasp, width, "grasp configuration", objects=objects)
                self._check_free(q_lift, 0.0, "lift configuration")
                return GraspPlan(
                    q_pre, q_grasp, q_lift, self._grasp_via(pose, q_start, q_pre, width, objects)
                )
            except PreconditionError as exc:
                first = first or exc
                if blocked is None and any(
                    b.startswith("object") for b in getattr(exc, "bodies", ())
                ):
                    blocked = exc
        assert first is not None
        raise blocked or first

    def _grasp_via(
        self, pose: np.ndarray, q_start: np.ndarray, q_pre: np.ndarray, width: float, objects: bool
    ) -> np.ndarray | None:
        """``None`` when the joint line ``q_start -> q_pre`` is free, else a free ``via`` on the
        approach line (see :meth:`plan_grasp`); raises the direct line's collision otherwise."""

        def free_path(q0: np.ndarray, q1: np.ndarray) -> None:
            n = grasp_path_samples(q0, q1)
            self._check_path(q0, q1, width, "pre-grasp pose", n, objects=objects)

        try:
            free_path(q_start, q_pre)
            return None
        except PreconditionError as direct:
            d = self.config.grasp_via_distance
            if d <= self.config.approach_distance:
                raise
            try:
                T_via = offset_along_z(pose, -d)
                q_via = self._solve(T_via, q_pre, "approach start", restarts=0)
                if np.abs(q_via - q_pre).max() > 1.0:
                    raise PreconditionError("approach line needs a joint flip") from None
                self._check_free(q_via, width, "approach start configuration", objects=objects)
                free_path(q_start, q_via)
                free_path(q_via, q_pre)
            except PreconditionError:
                raise direct from None
            return q_via

    def _execute_grasp(self, plan: GraspPlan, width: float) -> tuple[bool, str, int | None]:
        r = self._require_robot()
        cfg = self.config
        starts = {i: s.position[2] for i, s in enumerate(self._object_states())}
        r.actuate_gripper(width, max_time=0.4)
        if plan.via is not None:
            r.move_joints(plan.via)
            r.move_joints(plan.pre, speed=0.2)
        else:
            r.move_joints(plan.pre)
        r.move_joints(plan.grasp, speed=0.15)
        r.actuate_gripper(0.0, max_time=0.8)
        r.follow([plan.lift], [cfg.approach_distance / 0.1])
        for _ in range(int(cfg.hold_time / cfg.time_step)):
            self._step()
        held = self._object_in_hand()
        if held is None:
            return False, "nothing between the fingers after lifting and holding", None
        z = p.getBasePositionAndOrientation(self._bodies[held], physicsClientId=self.client)[0][2]
        if z < starts[held] + 0.5 * cfg.approach_distance:
            return False, f"object {held} was not lifted", None
        return True, f"object {held} lifted and held for {cfg.hold_time:.1f} s", held

    def _object_in_hand(self) -> int | None:
        r = self._require_robot()
        if r.gripper_width() < 0.002:
            return None
        for i, body in enumerate(self._bodies):
            touching = [
                len(p.getContactPoints(r.body, body, f, -1, physicsClientId=self.client)) > 0
                for f in FINGER_INDICES
            ]
            if all(touching):
                return i
        return None

    def grasp(self, pose, width: float) -> ActionResult:
        """Grasp (3.5.3): open to ``width``, pre-grasp 10 cm back along the tool z axis, approach,
        close, lift 10 cm, hold ``hold_time``; success = an object is lifted and still between
        the fingers. On success the object stays in the hand (``release()`` drops it)."""
        r = self._require_robot()
        pose = as_pose(pose, "pose")
        width = as_width(width)
        self._check_idle()
        plan = self.plan_grasp(pose, width, self.home)
        before = self.get_state()
        t0 = self._time
        ok, msg, held = self._execute_grasp(plan, width)
        if ok:
            self._held = held
        else:
            r.actuate_gripper(GRIPPER_MAX_WIDTH, max_time=0.3)
            r.move_joints(self.home)
        return self._result(ok, msg, before, t0)

    def release(self) -> ActionResult:
        """Open the gripper where it is (the held object drops) and return home."""
        r = self._require_robot()
        before = self.get_state()
        t0 = self._time
        r.actuate_gripper(GRIPPER_MAX_WIDTH, max_time=0.4)
        self._held = None
        q_up = self._solve(lifted(self.kin.fk(r.q()), 0.05), r.q(), "retreat pose")
        r.move_joints(q_up, speed=0.2)
        r.move_joints(self.home)
        return self._result(True, "released", before, t0)

    def pick_and_place(self, grasp_pose, width: float, place_pose) -> ActionResult:
        """Grasp at ``grasp_pose`` and release with the tool at ``place_pose`` (both tool poses,
        world): the object moves by ``place_pose @ inv(grasp_pose)``. Success = the object was
        grasped and rests within 3 cm of where that puts it after release."""
        r = self._require_robot()
        grasp_pose = as_pose(grasp_pose, "grasp_pose")
        place_pose = as_pose(place_pose, "place_pose")
        width = as_width(width)
        self._check_idle()
        self._in_workspace(
            place_pose[:3, 3] * [1, 1, 0] + [0, 0, self._floor_z() + 0.01], "place position"
        )
        plan = self.plan_grasp(grasp_pose, width, self.home)
        T_pre_place = lifted(place_pose, self.config.approach_distance)
        q_pre_place = self._solve(T_pre_place, plan.lift, "pre-place pose")
        q_place = self._solve(place_pose, q_pre_place, "place pose")
        q_retreat = self._solve(
            offset_along_z(place_pose, -self.config.approach_distance), q_place, "retreat pose"
        )
        self._check_free(q_place, 0.0, "place configuration")
        self._check_free(q_pre_place, 0.0, "pre-place configuration")
        self._check_path(plan.lift, q_pre_place, 0.0, "pre-place pose")
        before = self.get_state()
        t0 = self._time
        ok, msg, held = self._execute_grasp(plan, width)
        if not ok:
            r.actuate_gripper(GRIPPER_MAX_WIDTH, max_time=0.3)
            r.move_joints(self.home)
            return self._result(False, f"grasp failed: {msg}", before, t0)
        body = self._bodies[held]
        T_obj = sc.pose_matrix(*p.getBasePositionAndOrientation(body, physicsClientId=self.client))
        T_tool = self.kin.fk(r.q())
        planned = place_pose @ np.linalg.inv(T_tool) @ T_obj
        r.move_joints(q_pre_place)
        r.move_joints(q_place, speed=0.15)
        r.actuate_gripper(width, max_time=0.5)
        r.move_joints(q_retreat, speed=0.2)
        r.move_joints(self.home)
        self._settle(self._bodies)
        pos = np.asarray(p.getBasePositionAndOrientation(body, physicsClientId=self.client)[0])
        err = float(np.linalg.norm(pos[:2] - planned[:2, 3]))
        ok = err < 0.03
        return self._result(
            ok, f"object {held} placed {err * 100:.1f} cm from its planned spot", before, t0
        )

    def _floor_z(self) -> float:
        return self.config.shelf.bottom_z if self._spec.kind == "shelf" else 0.0
