"""Physics baseline of Ch. 4.7.4: re-simulate the (recognized) superquadrics in PyBullet.

"Pybullet (w/ Recog.)" / "(w/ GT)" of Table 4.6: instead of a learned model, the objects are
spawned as superquadric meshes (:func:`sqmanip.sim.scene.spawn`: one convex hull per convex
superellipsoid, slabs of hulls otherwise) at their poses, pushed, and their resting poses read
back. :meth:`PhysicsDynamics.predict` has the signature of :meth:`SQPDNet.predict` and returns
``(K, N, 4, 4)``; :meth:`PhysicsDynamics.predict_batch` takes one scene per push (the MPC's later
horizon steps, :func:`sqmanip.planning.mpc.predict_scenes`).

**Batched** (the default): all ``K`` pushes of a call run in ONE PyBullet world owned by the
model. It holds ``K`` copies of the tabletop scene on a 3 m grid, each with the simulator's
table and pedestal (:func:`sqmanip.sim.simulator.static_boxes`: objects pushed off a table fall
as in the real scene and never reach another copy), its objects (the simulator's own shapes,
mass, friction and physics settings) and a kinematic closed Panda hand (:func:`hand_urdf`: the
hand and finger links of the simulator's ``panda.urdf`` at width 0, with their collision meshes,
contact and friction values; no arm). The hand is moved every step along the tool path of
:meth:`sqmanip.sim.Simulator.push` with the robot's timing: the joint-space way down from the
pre-push pose to ``p`` (forward kinematics of the interpolated joints), straight to ``p + v`` at
``SimConfig.push_speed``, and the joint-space lift towards the post-push pose (which drags the
pushed object a little, as the robot does). All copies step together; a copy ends when nothing
on its table moves any more (the simulator's settling thresholds), at the latest when the robot
would be home. Pushes that leave identical scenes give bit-identical results in any copy.

Simulated is only what can matter: the way down from where the hand first comes within reach
of an object (exact distances; mostly nowhere, as the start points are clear), the lift until
the rest of it cannot touch an object, and an object only once the moving hand or a moving
object comes near it (removed again, pose kept, when it rests with nothing moving near). The
superquadric hulls (1538 vertices at the simulator's resolution) dominate: one resting on the
table costs ~40 us per step, one pushed by the two fingers ~100 us, the robot's arm little; so
the cost is that of the objects that take part (1-2 of 4 in a typical push).

Feasibility stays the robot's: :meth:`Simulator.push`'s argument checks, the simulator's IK
(:class:`sqmanip.sim.PandaKinematics`, same seeds and restarts, yaw 0 then pi) of the pre-push,
start, end and post-push tool poses with no joint flip between start and end, and its static
collision checks of the arm (key configurations and joint paths vs. table and pedestal, on a
full Panda in a second client that is never stepped). A refused push is flagged in
:attr:`PhysicsDynamics.last_failed` and leaves the poses unchanged (80 random pushes in and
around the workspace: the same 44 refused as by the reference). Not modelled: the arm's links
touching objects (the hand is all that moves) and the via-point IK (a flip is a start-end
change over 0.6 rad).

Agreement with the reference (80 sampler pushes of 1-4 catalogue boxes/cylinders placed as the
data generator places them; the 76 objects that moved, start pose free): 1.4 mm median, 2.0 cm
p90 position, 0.65 deg median yaw; the 66 that stayed upright 1.2 mm median, 3 mm p90, 5.4 mm
mean (two grazing contacts of the hand's edge), 0.44 deg median yaw. Objects that tip over and
roll differ by cm (chaotic in both). The differences left are the arm's compliance: the
reference's position-controlled Panda gives way a little, the kinematic hand does not. So a
push whose start pose already penetrates an object (14 of the 80; the MPC rejects those before
predicting) is not reproduced: the kinematic hand presses the object into the table.
Untouched objects keep their poses exactly (the reference lets them settle by ~1 mm).

Cost on this 2-core machine (shared with other jobs, load ~3-4), 4 objects: ``K = 100`` pushes
8-20 s (the reference, extrapolated from 5 pushes: 55-115 s), ``K = 10`` 1-3 s (6-12 s); one
lone box pushed 100 times ~9 s. Larger ``K`` run in chunks of ``chunk`` copies (the cost per
step is linear in the objects simulated; 25 or 100 copies per world cost the same per push).

**Reference** (``batched=False``): every action resets the full simulator (:class:`sqmanip.sim.
Simulator`) and executes the push with the whole simulated Panda (IK, collision checks, ~8.6 s
of simulated robot motion at 240 Hz), 0.6-1.2 s of wall time per action with 4 objects.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from sqmanip.geometry.superquadric import N_PARAMS
from sqmanip.geometry.transforms import matrix_to_quat

__all__ = ["PhysicsDynamics", "hand_urdf"]

_SQ_KINDS = ("superellipsoid", "superparaboloid", "supertoroid")
GRID_SPACING = 3.0
"""Distance between neighbouring scene copies (m): 2.2 m of free floor between 0.8 m tables."""
GRID_ORIGIN = 33.0
"""x and y offset of the first copy (m). With the 10 x 10 grid every copy's x and y lie in
[32, 64), where doubles have one spacing (2^-47 m): a scene computes bit for bit the same in
each of the first 100 copies (copies further out differ by rounding only)."""
CHUNK = 100
"""Most copies in the world at once (larger ``K`` run in chunks): the world's cost per step is
linear in the copies, so chunking only bounds memory; 100 is the MPC's ``K``."""
HAND_MARGIN = 0.01
"""An object is spawned once the moving hand's links come this close to its bounding box (m;
checks come before the hand can have moved this far, :meth:`_BatchWorld._wait`)."""
OBJECT_MARGIN = 0.02
"""... or a moving object's bounding box this close to its bounding box (m)."""
SPAWN_EVERY = 4
"""Steps between the checks for objects to spawn."""
REMOVE_EVERY = 16
"""Steps between the checks for resting objects to remove."""
REMOVE_REACH = 64
"""A resting object the moving hand comes near within this many steps is not removed (a
respawn costs ~1 ms, some 10 steps of a spawned object)."""
MAX_SHAPES = 256
"""Object shapes the batched world keeps before it is rebuilt (PyBullet never frees one)."""
FALLEN_Z = -0.10
"""Objects below this height (m) have left their table: they are not waited for when settling."""


def hand_urdf() -> str:
    """Path of a hand-only URDF made from the simulator's ``franka_panda/panda.urdf``.

    ``panda_hand`` is the root link and the two fingers are fixed joints at width 0 (closed, as
    in a push), with the URDF's collision meshes and contact values (the finger friction of
    :data:`sqmanip.sim.robot.FINGER_DYNAMICS` is set on loading). Visuals and the arm are
    dropped, the hand's inertial origin is moved to its link frame (so the base pose is the
    ``panda_hand`` frame). Written once into the simulator's mesh cache directory.
    """
    from sqmanip.sim.kinematics import PANDA_URDF
    from sqmanip.sim.scene import _MESH_CACHE

    root = ET.parse(PANDA_URDF).getroot()
    keep = {"panda_hand", "panda_leftfinger", "panda_rightfinger"}
    mesh_dir = os.path.dirname(PANDA_URDF)
    for link in list(root.findall("link")):
        if link.get("name") not in keep:
            root.remove(link)
            continue
        for vis in link.findall("visual"):
            link.remove(vis)
        for mesh in link.iter("mesh"):
            name = mesh.get("filename", "").replace("package://", "")
            mesh.set("filename", os.path.join(mesh_dir, name))
        inertial = link.find("inertial")
        if link.get("name") == "panda_hand" and inertial is not None:
            for origin in inertial.findall("origin"):
                origin.set("xyz", "0 0 0")
    for joint in list(root.findall("joint")):
        if joint.get("name") not in ("panda_finger_joint1", "panda_finger_joint2"):
            root.remove(joint)
            continue
        joint.set("type", "fixed")  # at width 0 the prismatic joints add no offset
        for tag in ("axis", "limit", "mimic", "safety_controller"):
            for child in joint.findall(tag):
                joint.remove(child)
    text = ET.tostring(root, encoding="unicode")
    name = "panda_hand_" + hashlib.sha1(text.encode()).hexdigest()[:16] + ".urdf"
    os.makedirs(_MESH_CACHE, exist_ok=True)
    path = os.path.join(_MESH_CACHE, name)
    if not os.path.exists(path):
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    return path


@dataclasses.dataclass(frozen=True)
class _HandPath:
    """TCP positions, one per physics step, of the hand in one push (world frame, no copy
    offset) at the fixed tool rotation ``R``."""

    R: np.ndarray
    down: np.ndarray
    """``(S, 3)`` the robot's joint-space way down from the pre-push pose to ``p`` (forward
    kinematics of the interpolated joints); simulated from where it comes near an object."""
    push: np.ndarray
    """``(S, 3)`` straight from ``p`` to ``p + v`` at ``push_speed``."""
    lift: np.ndarray
    """``(S, 3)`` the robot's joint-space lift to the post-push pose (forward kinematics of
    the interpolated joints); simulated until the rest of it cannot touch an object."""
    after: int
    """Steps the robot takes from the end of the push until it is home (lift, return)."""


@dataclasses.dataclass
class _Copy:
    """One scene copy during :meth:`_BatchWorld.simulate`."""

    j: int
    hand: int
    offset: np.ndarray
    path: _HandPath
    quat: list[float]
    poses: np.ndarray
    """``(N, 4, 4)`` the objects' last known poses (copy frame)."""
    spec: Any
    shapes: list[tuple[int, int]]
    bodies: dict[int, int] = dataclasses.field(default_factory=dict)
    """Object index -> PyBullet body of the objects in the world now."""
    groups: dict[int, tuple[int, ...]] = dataclasses.field(default_factory=dict)
    """Removed object -> the objects removed with it (resting against each other)."""
    last: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 4, 4)))
    """``(N, 4, 4)`` the spawned objects' poses at the last check for resting ones."""
    tcp: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    """The hand's tool centre point now (copy frame)."""
    steps: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    """``(S, 3)`` the hand's TCP positions, one per step (copy frame)."""
    hand_path: list = dataclasses.field(default_factory=list)
    """``steps`` as positions of the hand's base in the world (for PyBullet)."""
    hand_step: float = 0.0
    """Longest step of the hand along ``steps`` (m)."""
    next_check: int = SPAWN_EVERY
    """Step of the next :meth:`_BatchWorld._update`."""
    next_remove: int = REMOVE_EVERY
    """Step from which the next update also removes resting objects."""
    last_check: int = 0
    """Step of the last removal check (when ``last`` was taken)."""
    lift_from: int = 0
    """Index of the lift's first step in ``steps``."""
    rest_lo: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    rest_hi: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    """``(L, 3)`` extent of the rest of the lift from each of its steps (tool x, tool y, z)."""
    deadline: int = 0
    """Step by which the robot would be home: the copy ends then at the latest."""
    done: bool = False


@dataclasses.dataclass(frozen=True)
class _Shapes:
    """Object-frame extents of a scene's objects, from their meshes."""

    corners: np.ndarray
    """``(N, 8, 3)`` corners of the bounding box."""

    @classmethod
    def of(cls, params: np.ndarray, kinds: np.ndarray) -> _Shapes:
        """From a coarse mesh of each object, grown by 2 mm (the mesh's vertices are on the
        surface; the collision hull is the finer mesh of :mod:`sqmanip.sim.scene`)."""
        from sqmanip.geometry.mesh import superquadric_mesh

        meshes = [superquadric_mesh(params[i], int(kinds[i]), 8)[0] for i in range(len(params))]
        lo = np.stack([v.min(0) for v in meshes]) - 0.002
        hi = np.stack([v.max(0) for v in meshes]) + 0.002
        pick = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)])
        corners = np.where(pick[None] == 0, lo[:, None], hi[:, None])
        return cls(corners)


def _corners(poses: np.ndarray, shape: _Shapes) -> np.ndarray:
    """``(N, 8, 3)`` world corners of the objects' bounding boxes at ``poses (N, 4, 4)``."""
    return np.einsum("nij,nkj->nki", poses[:, :3, :3], shape.corners) + poses[:, None, :3, 3]


@dataclasses.dataclass(frozen=True)
class _PushPlan:
    """The robot's plan of one push: tool rotation and the joint configurations of the tool
    poses pre-push, start, end and post-push (world frame)."""

    R: np.ndarray
    q: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


class PhysicsDynamics:
    """A dynamics model that re-simulates each push in PyBullet (4.7.4).

    ``batched=True`` (default): all pushes of a call in one PyBullet world of scene copies with
    a kinematic hand each (at most ``chunk`` copies at a time). ``batched=False``: the
    sequential full-robot reference, one ``simulator`` reset and push per action (a
    ``sqmanip.sim.Simulator``; one is created, and owned, if None). ``config``: the physics and
    motion settings (default: the simulator's, else ``SimConfig()``). ``mass`` / ``friction``
    are given to every spawned object (the data generator's defaults).
    """

    def __init__(
        self,
        simulator=None,
        *,
        mass: float = 0.2,
        friction: float = 0.6,
        batched: bool = True,
        chunk: int = CHUNK,
        config=None,
    ) -> None:
        from sqmanip.sim.config import SimConfig

        if chunk < 1:
            raise ValueError(f"chunk must be >= 1, got {chunk}")
        self.batched = bool(batched)
        self.chunk = int(chunk)
        self.mass = float(mass)
        self.friction = float(friction)
        self.last_failed = np.zeros(0, dtype=bool)
        """``(K,)``: the actions of the last :meth:`predict` that the robot could not execute."""
        self._owned = False
        if not self.batched and simulator is None:
            from sqmanip.sim import Simulator

            simulator = Simulator(config)
            self._owned = True
        self.sim = simulator
        self.config = config or (simulator.config if simulator is not None else SimConfig())
        self._world: _BatchWorld | None = None

    def close(self) -> None:
        if self._world is not None:
            self._world.close()
            self._world = None
        if self._owned and self.sim is not None:
            self.sim.close()
            self._owned = False

    def __enter__(self) -> PhysicsDynamics:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def scene_spec(self, poses: np.ndarray, params: np.ndarray, kinds: np.ndarray):
        """The tabletop ``SceneSpec`` with one superquadric object per row."""
        from sqmanip.sim import ObjectSpec, SceneSpec

        q = matrix_to_quat(torch.as_tensor(poses[:, :3, :3])).numpy()
        objects = tuple(
            ObjectSpec(
                "superquadric",
                position=tuple(poses[i, :3, 3]),
                orientation=tuple(q[i]),
                params=tuple(params[i]),
                sq_kind=_SQ_KINDS[int(kinds[i])],
                mass=self.mass,
                friction=self.friction,
                upright=False,
                name=f"object_{i}",
            )
            for i in range(poses.shape[0])
        )
        return SceneSpec("tabletop", objects, 0)

    def predict(
        self,
        poses: torch.Tensor | np.ndarray,
        params: torch.Tensor | np.ndarray,
        actions: torch.Tensor | np.ndarray,
        kinds: torch.Tensor | np.ndarray | Sequence[int] | None = None,
    ) -> torch.Tensor:
        """Next poses ``(K, N, 4, 4)`` (float64) of ``N`` objects under each of ``K`` pushes.

        ``poses (N, 4, 4)``, ``params (N, 9)``, ``actions (K, 6)`` rows ``(p, v)`` in the world
        frame, ``kinds (N,)`` (default superellipsoids). All pushes start from the same scene.
        """
        poses_np = _array(poses)
        if poses_np.ndim != 3 or poses_np.shape[1:] != (4, 4):
            raise ValueError(f"poses must have shape (N, 4, 4), got {poses_np.shape}")
        acts = _array(actions)
        k = acts.shape[0] if acts.ndim == 2 else 0
        return self._predict(np.broadcast_to(poses_np, (k, *poses_np.shape)), params, acts, kinds)

    def predict_batch(
        self,
        poses: torch.Tensor | np.ndarray,
        params: torch.Tensor | np.ndarray,
        actions: torch.Tensor | np.ndarray,
        kinds: torch.Tensor | np.ndarray | Sequence[int] | None = None,
    ) -> torch.Tensor:
        """Next poses ``(K, N, 4, 4)`` (float64) of ``K`` *different* scenes, one push each.

        ``poses (K, N, 4, 4)``, ``params (N, 9)``, ``kinds (N,)``, ``actions (K, 6)`` (the
        MPC's later horizon steps, :func:`sqmanip.planning.mpc.predict_scenes`).
        """
        poses_np = _array(poses)
        if poses_np.ndim != 4 or poses_np.shape[2:] != (4, 4):
            raise ValueError(f"poses must have shape (K, N, 4, 4), got {poses_np.shape}")
        acts = _array(actions)
        if acts.ndim == 2 and acts.shape[0] != poses_np.shape[0]:
            raise ValueError(
                f"actions must have one row per scene ({poses_np.shape[0]}), got {acts.shape[0]}"
            )
        return self._predict(poses_np, params, acts, kinds)

    def _predict(self, poses_np: np.ndarray, params, acts: np.ndarray, kinds) -> torch.Tensor:
        n = poses_np.shape[1]
        params_np = _array(params)
        if params_np.shape != (n, N_PARAMS):
            raise ValueError(f"params must have shape ({n}, {N_PARAMS}), got {params_np.shape}")
        if acts.ndim != 2 or acts.shape[1] != 6:
            raise ValueError(f"actions must have shape (K, 6), got {acts.shape}")
        kinds_np = np.zeros(n, dtype=np.int64) if kinds is None else np.asarray(kinds, np.int64)
        if kinds_np.shape != (n,):
            raise ValueError(f"kinds must have shape ({n},), got {kinds_np.shape}")
        if np.any((kinds_np < 0) | (kinds_np > 2)):
            raise ValueError(f"kinds must be 0, 1 or 2, got {kinds_np.tolist()}")
        k = acts.shape[0]
        out = np.array(poses_np, dtype=np.float64, copy=True)
        self.last_failed = np.zeros(k, dtype=bool)
        if n == 0 or k == 0:
            return torch.as_tensor(out)
        if self.batched:
            self._predict_batched(out, params_np, kinds_np, acts)
        else:
            self._predict_reference(out, params_np, kinds_np, acts)
        return torch.as_tensor(out)

    def _predict_reference(self, out, params, kinds, acts) -> None:
        from sqmanip.errors import PreconditionError, ValidationError

        for j in range(acts.shape[0]):
            self.sim.reset(self.scene_spec(out[j], params, kinds))
            try:
                result = self.sim.push(acts[j, :3], acts[j, 3:])
            except (PreconditionError, ValidationError):
                self.last_failed[j] = True
                continue
            out[j] = np.stack([o.pose for o in result.after.objects])

    def _predict_batched(self, out, params, kinds, acts) -> None:
        if self._world is None:
            self._world = _BatchWorld(self.config)
        world = self._world
        plans = [world.plan(acts[j, :3], acts[j, 3:]) for j in range(acts.shape[0])]
        self.last_failed[:] = [pl is None for pl in plans]
        todo = [j for j, pl in enumerate(plans) if pl is not None]
        if not todo:
            return
        specs = [self.scene_spec(out[j], params, kinds) for j in todo]
        shapes = world.shapes(specs[0])
        extents = _Shapes.of(params, kinds)
        for s in range(0, len(todo), self.chunk):
            rows = todo[s : s + self.chunk]
            paths = [world.tool_path(acts[j], plans[j]) for j in rows]
            out[rows] = world.simulate(specs[s : s + self.chunk], shapes, paths, extents)


def _hand_base(c: _Copy, tcp: np.ndarray) -> np.ndarray:
    """World position(s) of the hand's base (``panda_hand``) with its tool centre point at
    ``tcp (..., 3)`` of copy ``c`` (copy frame)."""
    from sqmanip.sim.kinematics import TCP_OFFSET

    return tcp - TCP_OFFSET * c.path.R[:, 2] + c.offset


def _array(x: Any) -> np.ndarray:
    return np.asarray(torch.as_tensor(x, dtype=torch.float64).cpu())


class _BatchWorld:
    """The batched model's PyBullet DIRECT client: scene copies (table, pedestal, hand) on a
    grid, created on demand and kept between calls; objects are spawned per call."""

    def __init__(self, config) -> None:
        import pybullet as p

        from sqmanip.sim.config import HOME_TABLETOP, ROBOT_BASE_POSITION
        from sqmanip.sim.kinematics import PandaKinematics
        from sqmanip.sim.simulator import configure_physics

        self.p = p
        self.config = config
        self.client = p.connect(p.DIRECT)
        configure_physics(self.client, config)
        base = np.eye(4)
        base[:3, 3] = ROBOT_BASE_POSITION
        self.kin = PandaKinematics(base)
        self.home = HOME_TABLETOP
        self.hands: list[int] = []
        self.offsets: list[np.ndarray] = []
        self._box_shapes: dict[tuple, int] = {}
        self._shapes: dict[tuple, tuple[int, int]] = {}
        self._static: set[int] = set()
        self._probe_world: tuple | None = None
        self._hand_urdf = hand_urdf()
        self.hand_boxes = self._link_boxes()
        """``(L, 2, 3)`` lower/upper corners of the hand's links in the frame (tool x, tool y,
        world z) at the tool centre point of a downward push."""

    def _link_boxes(self) -> np.ndarray:
        from sqmanip.sim.actions import push_tool_rotation
        from sqmanip.sim.kinematics import TCP_OFFSET

        p, cid = self.p, self.client
        R = push_tool_rotation(np.array([1.0, 0.0, 0.0]))
        hand = p.loadURDF(
            self._hand_urdf,
            (-TCP_OFFSET * R[:, 2]).tolist(),
            matrix_to_quat(torch.as_tensor(R)).tolist(),
            useFixedBase=True,
            physicsClientId=cid,
        )
        boxes = []
        for link in range(-1, p.getNumJoints(hand, physicsClientId=cid)):
            lo, hi = (np.asarray(x) for x in p.getAABB(hand, link, physicsClientId=cid))
            # world x, y, z -> tool x (= x), tool y (= -y), z
            boxes.append([[lo[0], -hi[1], lo[2]], [hi[0], -lo[1], hi[2]]])
        p.removeBody(hand, physicsClientId=cid)
        return np.asarray(boxes)

    def close(self) -> None:
        if self.client >= 0:
            self.p.disconnect(self.client)
            self.client = -1
        if self._probe_world is not None:
            self.p.disconnect(self._probe_world[0])
            self._probe_world = None

    # --- the robot's plan ---------------------------------------------------------------------

    def plan(self, p0: np.ndarray, v: np.ndarray) -> _PushPlan | None:
        """The push's tool rotation and key configurations as :meth:`Simulator.push` plans
        them (same argument checks, IK seeds and restarts, yaw 0 then pi), or None when the
        robot would refuse it (arguments, IK, a joint flip between start and end, or a static
        collision of the arm)."""
        from sqmanip.errors import ValidationError
        from sqmanip.sim.simulator import (
            check_in_region,
            check_push_vector,
            push_tool_poses,
            workspace_bounds,
        )

        try:
            check_push_vector(v)
            check_in_region(p0, workspace_bounds(), "push start p", "workspace")
            check_in_region(p0 + v, workspace_bounds(), "push end p + v", "workspace")
        except ValidationError:
            return None
        rng = np.random.default_rng(1)  # the simulator's IK generator after reset(seed=0)
        for yaw in (0.0, np.pi):
            poses = push_tool_poses(p0, v, yaw)
            qs: list[np.ndarray] = []
            seed = self.home
            for T in poses:
                res = self.kin.ik(T, seed, rng=rng)
                if not res.success:
                    break
                qs.append(res.q)
                seed = res.q
            else:
                # the robot refuses a joint flip (0.6 rad between via points) on the way
                if np.max(np.abs(qs[2] - qs[1])) <= 0.6:
                    plan = _PushPlan(poses[1][:3, :3], tuple(qs))  # type: ignore[arg-type]
                    return None if self._collides(plan) else plan
        return None

    def _collides(self, plan: _PushPlan) -> bool:
        """:meth:`Simulator.push`'s static collision checks of a plan: the arm at the pre-push,
        start and end configurations and on the joint paths home -> pre-push and post-push ->
        home closer than ``collision_margin`` to the table or the pedestal (checked on a
        full Panda in a second, never stepped, PyBullet client)."""
        from sqmanip.sim.simulator import joint_path, static_hits

        robot, static = self._probe()
        q_pre, q_start, q_end, q_post = plan.q
        configs = [q_pre, q_start, q_end, *joint_path(self.home, q_pre)]
        configs += joint_path(q_post, self.home)
        for q in configs:
            robot.pose_config(q, 0.0)
            if static_hits(robot, static, self.config.collision_margin):
                return True
        return False

    def _probe(self):
        """The collision-check client: the simulator's tabletop statics and Panda."""
        if self._probe_world is None:
            from sqmanip.sim.config import ROBOT_BASE_POSITION
            from sqmanip.sim.robot import PandaRobot
            from sqmanip.sim.simulator import static_boxes

            p = self.p
            cid = p.connect(p.DIRECT)
            static = {}
            for name, half, center, _ in static_boxes("tabletop"):
                col = p.createCollisionShape(
                    p.GEOM_BOX, halfExtents=list(half), physicsClientId=cid
                )
                static[p.createMultiBody(0.0, col, -1, list(center), physicsClientId=cid)] = name
            robot = PandaRobot(cid, ROBOT_BASE_POSITION, self.config, lambda: None)
            self._probe_world = (cid, robot, static)
        return self._probe_world[1:]

    def tool_path(self, action: np.ndarray, plan: _PushPlan) -> _HandPath:
        """The hand's motion in one push: the part of :meth:`Simulator.push`'s tool path
        between the pre-push and the post-push pose (see :class:`_HandPath`), with the
        robot's timing."""
        from sqmanip.sim.robot import joint_motion_steps

        cfg = self.config
        p0, v = action[:3], action[3:]
        q_pre, q_start, q_end, q_post = plan.q
        down = self._joint_line(q_pre, q_start, joint_motion_steps(q_start - q_pre, 0.2, cfg))
        # push: the via points at push_speed, linear in between (Simulator.push / follow)
        seg = float(np.linalg.norm(v)) / cfg.push_via_points / cfg.push_speed
        m = cfg.push_via_points * max(int(math.ceil(seg / cfg.time_step)), 1)
        push = p0 + np.arange(1, m + 1)[:, None] / m * v
        n = joint_motion_steps(q_post - q_end, 0.2, cfg)
        lift = self._joint_line(q_end, q_post, n)
        after = n + joint_motion_steps(self.home - q_post, cfg.speed_scale, cfg)
        return _HandPath(plan.R, down, push, lift, after)

    def _joint_line(self, q0: np.ndarray, q1: np.ndarray, n: int) -> np.ndarray:
        """``(n, 3)`` TCP positions of a :meth:`PandaRobot.move_joints` motion from ``q0`` to
        ``q1`` in ``n`` steps (smoothstep in joint space; forward kinematics every 8 steps,
        linear in between)."""
        from sqmanip.sim.robot import smoothstep

        knots = np.unique(np.r_[np.arange(0, n + 1, 8), n])
        tcp = np.stack([self.kin.fk(q0 + smoothstep(i / n) * (q1 - q0))[:3, 3] for i in knots])
        return np.stack([np.interp(np.arange(1, n + 1), knots, tcp[:, c]) for c in range(3)], -1)

    # --- the world ----------------------------------------------------------------------------

    def shapes(self, spec) -> list[tuple[int, int]]:
        """Collision shapes (no visuals) of the scene's objects, shared by all copies and
        kept for later calls with the same shapes. PyBullet cannot free a collision shape
        (``removeCollisionShape`` is a no-op), so past ``MAX_SHAPES`` the world is rebuilt."""
        from sqmanip.sim.scene import object_shapes

        keys = [(o.sq_kind, o.params) for o in spec.objects]
        if len(self._shapes) + len(set(keys) - set(self._shapes)) > MAX_SHAPES:
            self.reset()
        for key, o in zip(keys, spec.objects, strict=True):
            if key not in self._shapes:
                self._shapes[key] = object_shapes(o, self.client, visual=False)
        return [self._shapes[key] for key in keys]

    def reset(self) -> None:
        """An empty world (no copies, no shapes) with the configured physics."""
        from sqmanip.sim.simulator import configure_physics

        self.p.resetSimulation(physicsClientId=self.client)
        configure_physics(self.client, self.config)
        self.hands, self.offsets = [], []
        self._box_shapes, self._shapes, self._static = {}, {}, set()

    def _ensure_copies(self, k: int) -> None:
        """At least ``k`` scene copies: table and pedestal (static) and a hand, on the grid."""
        from sqmanip.sim.robot import FINGER_DYNAMICS
        from sqmanip.sim.simulator import STATIC_FRICTION, static_boxes

        p, cid = self.p, self.client
        cols = 10
        while len(self.hands) < k:
            j = len(self.hands)
            off = np.array([j % cols, j // cols % cols, 0.0]) * GRID_SPACING
            off[:2] += GRID_ORIGIN + 2 * GRID_SPACING * cols * (j // cols**2)
            for _, half, center, _ in static_boxes("tabletop"):
                col = self._box_shapes.get(half)
                if col is None:
                    col = p.createCollisionShape(
                        p.GEOM_BOX, halfExtents=list(half), physicsClientId=cid
                    )
                    self._box_shapes[half] = col
                body = p.createMultiBody(
                    0.0, col, -1, list(np.asarray(center) + off), physicsClientId=cid
                )
                p.changeDynamics(body, -1, lateralFriction=STATIC_FRICTION, physicsClientId=cid)
                self._static.add(body)
            hand = p.loadURDF(
                self._hand_urdf,
                list(off + [0.0, 0.0, 1.0]),
                useFixedBase=True,
                flags=p.URDF_USE_INERTIA_FROM_FILE,
                physicsClientId=cid,
            )
            for link in range(p.getNumJoints(hand, physicsClientId=cid)):
                p.changeDynamics(hand, link, **FINGER_DYNAMICS, physicsClientId=cid)
            self.hands.append(hand)
            self.offsets.append(off)

    def simulate(self, specs, shapes, paths: list[_HandPath], extents: _Shapes) -> np.ndarray:
        """Poses ``(k, N, 4, 4)`` after pushing copy ``j`` (the objects of ``specs[j]``, of
        collision ``shapes`` and ``extents``) with its hand along ``paths[j]``.

        Objects are simulated only near motion: an object is spawned (at rest, at its last
        pose) once the moving hand comes within ``HAND_MARGIN`` of its bounding box or a
        moving object within ``OBJECT_MARGIN``, and removed again (pose kept) when it rests,
        touches only its table (or other resting objects, removed with it), and nothing
        moving is near. The hand's way down is simulated from where it first comes within
        reach of an object (:meth:`_descent_start`), its lift until the rest of the lift
        clears every object's bounding box; then it is parked far away. A copy ends when its
        hand is parked and no object is left in the world, at the latest when the robot would
        be home (the reference's simulated time).
        """
        p, cid = self.p, self.client
        k = len(specs)
        self._ensure_copies(k)
        copies = []
        for j in range(k):
            path = paths[j]
            poses = np.stack([o.pose for o in specs[j].objects])
            quat = matrix_to_quat(torch.as_tensor(path.R)).tolist()
            c = _Copy(j, self.hands[j], self.offsets[j], path, quat, poses, specs[j], shapes)
            c.last = np.full_like(poses, np.nan)
            down = path.down[self._descent_start(c, extents) :]
            c.tcp = down[0]
            self._update(c, extents, [], True, None)
            c.steps = np.concatenate([down, path.push, path.lift])
            c.lift_from = len(down) + len(path.push)
            c.deadline = c.lift_from + path.after
            # extent of the rest of the lift from each of its steps (tool x, tool y, z)
            rel = np.concatenate([path.lift[:, :2] @ path.R[:2, :2], path.lift[:, 2:]], -1)
            c.rest_lo = np.minimum.accumulate(rel[::-1])[::-1] - rel
            c.rest_hi = np.maximum.accumulate(rel[::-1])[::-1] - rel
            self._hand_at(c, c.steps[0])
            c.hand_path = self._hand_positions(c)
            c.hand_step = float(np.linalg.norm(np.diff(c.steps, axis=0), axis=1).max(initial=0))
            c.hand_step += 1e-4
            copies.append(c)
        live = copies
        t = 0
        reset = p.resetBasePositionAndOrientation
        try:
            while live:
                for c in live:
                    if t < len(c.steps):
                        reset(c.hand, c.hand_path[t], c.quat, physicsClientId=cid)
                p.stepSimulation(physicsClientId=cid)
                t += 1
                for c in live:
                    if t == len(c.steps):
                        self._park(c)
                    if t >= c.next_check:
                        moving, speed = self._refresh(c)
                        if c.lift_from <= t < len(c.steps):
                            c.tcp = c.steps[t - 1]
                            s = t - 1 - c.lift_from
                            sweep = (c.rest_lo[s], c.rest_hi[s])
                            gaps = self._hand_gaps(c, _corners(c.poses, extents), sweep)
                            if np.all(gaps > HAND_MARGIN):
                                c.steps = c.steps[:t]  # the rest of the lift touches nothing
                                self._park(c)
                        c.tcp = c.steps[min(t, len(c.steps) - 1)]
                        moving_hand = t < len(c.steps)
                        remove = t >= c.next_remove
                        slack = self._update(c, extents, moving, moving_hand, t if remove else None)
                        if remove:
                            c.next_remove = t + REMOVE_EVERY
                        c.next_check = t + self._wait(c, t, slack, speed, moving_hand)
                    if t >= c.deadline or (t >= len(c.steps) and not c.bodies):
                        self._finish(c)
                live = [c for c in live if not c.done]
        finally:
            for c in copies:
                if not c.done:
                    self._finish(c)
        return np.stack([c.poses for c in copies])

    def _park(self, c: _Copy) -> None:
        """The hand 1 m above its table, out of every object's reach."""
        self.p.resetBasePositionAndOrientation(
            c.hand, list(c.offset + [0.0, 0.0, 1.0]), [0, 0, 0, 1], physicsClientId=self.client
        )

    def _refresh(self, c: _Copy) -> tuple[list[int], float]:
        """Read the spawned objects' poses into ``c.poses``; returns those on a table that
        move (faster than the simulator's settling thresholds, 2 mm/s or 0.02 rad/s) and a
        bound on how fast their points move (m/s; 0.15 m lever arm)."""
        from sqmanip.sim.scene import pose_matrix

        p, cid = self.p, self.client
        moving, speed = [], 0.0
        for i, b in c.bodies.items():
            pos, orn = p.getBasePositionAndOrientation(b, physicsClientId=cid)
            c.poses[i] = pose_matrix(np.asarray(pos) - c.offset, orn)
            if pos[2] < FALLEN_Z:
                continue
            lv, av = p.getBaseVelocity(b, physicsClientId=cid)
            v, w = math.hypot(*lv), math.hypot(*av)
            if v > 2e-3 or w > 2e-2:
                moving.append(i)
            speed = max(speed, v + 0.15 * w)
        return moving, speed

    def _wait(self, c: _Copy, t: int, slack: tuple[float, float], speed: float, hand: bool):
        """Steps until the next check of a copy: ``SPAWN_EVERY``, or up to ``REMOVE_EVERY``
        (64 with nothing spawned) while nothing can come near a removed object before it:
        ``slack`` = (hand, objects) distances to spawning one (m), the hand moving at most its
        longest step, the spawned objects at most ``speed`` plus free-fall acceleration."""
        if c.lift_from <= t < len(c.steps):  # the lift's end is checked every SPAWN_EVERY
            return SPAWN_EVERY
        dt = self.config.time_step
        v = max(speed, c.hand_step / dt) if hand else speed
        longest = 64 if not c.bodies else REMOVE_EVERY
        k = SPAWN_EVERY
        for cand in range(longest, SPAWN_EVERY, -SPAWN_EVERY):
            reach = v * cand * dt + 0.5 * 9.81 * (cand * dt) ** 2 + 0.002 if c.bodies else 0.0
            if (not hand or c.hand_step * cand + 0.002 < slack[0]) and reach < slack[1]:
                k = cand
                break
        if c.bodies:
            k = min(k, max(c.next_remove - t, 1))
        return k

    def _hand_at(self, c: _Copy, tcp: np.ndarray) -> None:
        self.p.resetBasePositionAndOrientation(
            c.hand, _hand_base(c, tcp).tolist(), c.quat, physicsClientId=self.client
        )

    def _hand_positions(self, c: _Copy) -> list[list[float]]:
        """World positions of the hand's base (``panda_hand``) along ``c.steps``."""
        return _hand_base(c, c.steps).tolist()

    def _update(
        self, c: _Copy, shape: _Shapes, moving: list[int], moving_hand: bool, now: int | None
    ) -> tuple[float, float]:
        """Spawn the objects that something moving (the hand, the objects ``moving``) comes
        near; with ``now`` (the step), also remove the resting ones that nothing moving is
        near (their poses are kept in ``c.poses``). Returns how far the moving hand and the
        spawned objects are from spawning another object (m; inf: nothing left to spawn).

        Objects resting against each other are removed together, as one group, and are
        spawned again together (none loses its support).
        """
        from sqmanip.sim.scene import matrix_to_pq, spawn

        p, cid = self.p, self.client
        n = len(c.poses)
        corners = _corners(c.poses, shape)
        lo, hi = corners.min(1), corners.max(1)  # world-aligned bounding boxes
        hand_gap = self._hand_gaps(c, corners) if moving_hand else np.full(n, np.inf)

        # gaps between the objects' world-aligned bounding boxes, none to itself
        gap = np.maximum(np.maximum(lo[:, None] - hi[None], lo[None] - hi[:, None]), 0.0)
        pair = np.linalg.norm(gap, axis=-1)
        np.fill_diagonal(pair, np.inf)

        def object_gap(movers: list[int]) -> np.ndarray:
            return pair[:, movers].min(1) if movers else np.full(n, np.inf)

        near = (hand_gap < HAND_MARGIN) | (object_gap(moving) < OBJECT_MARGIN)
        new = [i for i in range(n) if i not in c.bodies and near[i]]
        for i in sorted({m for k in new for m in c.groups.get(k, (k,))}):
            pos, orn = matrix_to_pq(c.poses[i])
            o = c.spec.objects[i].with_pose(np.asarray(pos) + c.offset, orn)
            c.bodies[i] = spawn(o, cid, c.shapes[i])
            c.groups.pop(i, None)
            c.last[i] = np.nan  # not resting before it was watched for a while
        frozen = [i for i in range(n) if i not in c.bodies]
        on_table = [i for i in c.bodies if c.poses[i, 2, 3] >= FALLEN_Z]
        slack = (
            float(hand_gap[frozen].min()) - HAND_MARGIN if frozen else np.inf,
            float(object_gap(on_table)[frozen].min()) - OBJECT_MARGIN if frozen else np.inf,
        )
        if now is None or not c.bodies:
            return slack
        # Resting: moved less than the simulator's settling speeds (2 mm/s, 0.02 rad/s) allow
        # since the last check (velocities alone would keep a hull's contact jitter going).
        window = (now - c.last_check) * self.config.time_step
        c.last_check = now
        still = set()
        for i in c.bodies:
            dp = np.linalg.norm(c.poses[i, :3, 3] - c.last[i, :3, 3])
            cos = (np.trace(c.last[i, :3, :3].T @ c.poses[i, :3, :3]) - 1) / 2
            if dp < 2e-3 * window and np.arccos(np.clip(cos, -1, 1)) < 2e-2 * window:
                still.add(i)
            c.last[i] = c.poses[i]
        if moving_hand:  # where the hand goes next (an object it soon reaches stays)
            ahead = c.steps[now : now + REMOVE_REACH] - c.tcp
            ahead = np.concatenate([ahead[:, :2] @ c.path.R[:2, :2], ahead[:, 2:]], -1)
            sweep = (np.minimum(ahead.min(0), 0.0), np.maximum(ahead.max(0), 0.0))
            hand_gap = self._hand_gaps(c, corners, sweep)
        far = (hand_gap >= 2 * HAND_MARGIN) & (
            object_gap([m for m in moving if m not in still]) >= 2 * OBJECT_MARGIN
        )
        # resting objects nothing moving is near, and what else (not static) each one touches
        index = {b: i for i, b in c.bodies.items()}
        idle, touches = set(), {}
        for i, b in c.bodies.items():
            if i not in still or c.poses[i, 2, 3] < FALLEN_Z or not far[i]:
                continue
            others = {pt[2] for pt in p.getContactPoints(bodyA=b, physicsClientId=cid)}
            idle.add(i)
            touches[i] = {index.get(o, -1) for o in others - self._static}
        while idle:  # remove each group of idle objects that touch only each other
            group, todo, ok = set(), [idle.pop()], True
            while todo:
                i = todo.pop()
                group.add(i)
                for m in touches[i]:
                    if m not in group and m not in todo:
                        if m in idle:
                            idle.discard(m)
                            todo.append(m)
                        else:
                            ok = False  # touches a moving object, a busy one or the hand
            if ok:
                for i in group:
                    p.removeBody(c.bodies.pop(i), physicsClientId=cid)
                    c.groups[i] = tuple(sorted(group))
        return slack

    def _hand_gaps(self, c: _Copy, corners: np.ndarray, sweep=None) -> np.ndarray:
        """``(N,)`` distances between the hand's links at ``c.tcp`` (their boxes in the tool
        frame, :attr:`hand_boxes`, grown by the displacements ``sweep = (lo (3,), hi (3,))``
        when given) and the objects' bounding boxes ``corners (N, 8, 3)`` (boxed again in
        that frame)."""
        return self._hand_gaps_at(c, c.tcp[None], corners, sweep)[0]

    def _hand_gaps_at(self, c: _Copy, tcps: np.ndarray, corners: np.ndarray, sweep=None):
        """:meth:`_hand_gaps` ``(P, N)`` with the hand at each of ``tcps (P, 3)``."""
        rel = corners[None] - tcps[:, None, None]  # (P, N, 8, 3)
        axes = c.path.R[:2, :2]  # tool x, y in the plane
        local = np.concatenate([rel[..., :2] @ axes, rel[..., 2:]], -1)
        lo, hi = local.min(2)[:, :, None], local.max(2)[:, :, None]  # (P, N, 1, 3)
        hb = self.hand_boxes[None, None]  # (1, 1, L, 2, 3)
        if sweep is not None:
            hb = hb + np.stack(sweep)
        gap = np.maximum(np.maximum(lo - hb[..., 1, :], hb[..., 0, :] - hi), 0.0)
        return np.linalg.norm(gap, axis=-1).min(-1)

    def _finish(self, c: _Copy) -> None:
        from sqmanip.sim.scene import pose_matrix

        p, cid = self.p, self.client
        for i, b in c.bodies.items():
            pos, orn = p.getBasePositionAndOrientation(b, physicsClientId=cid)
            c.poses[i] = pose_matrix(np.asarray(pos) - c.offset, orn)
            p.removeBody(b, physicsClientId=cid)
        c.bodies.clear()
        self._park(c)
        c.done = True

    def _descent_start(self, c: _Copy, shape: _Shapes) -> int:
        """Index into the way down from which it is simulated: 8 steps before the first of
        its poses (every 8th) where the hand's links come within reach of an object at rest
        (exact distances to the objects' collision shapes; reach = the way to the next of
        those poses + 1 mm), its last pose (the start, ``p``) when there is none."""
        from sqmanip.sim.scene import matrix_to_pq

        p, cid = self.p, self.client
        down = c.path.down
        picks = np.r_[np.arange(0, len(down) - 1, 8), len(down) - 1]
        # how far the hand travels from each pick to the next (+ 1 mm)
        travel = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(down, axis=0), axis=1))]
        reaches = np.diff(travel[picks], append=travel[-1]) + 0.001
        gaps = self._hand_gaps_at(c, down[picks], _corners(c.poses, shape))  # (P, N)
        quats = [matrix_to_pq(T)[1] for T in c.poses]
        pos = c.poses[:, :3, 3] + c.offset
        for k, gap, reach in zip(picks, gaps, reaches, strict=True):
            close = np.nonzero(gap < reach + 0.005)[0]  # boxes include Bullet's AABB margins
            if close.size == 0:
                continue
            self._hand_at(c, down[k])
            for i in close:
                for link in range(-1, 2):
                    if p.getClosestPoints(
                        bodyA=c.hand, bodyB=-1, distance=float(reach), linkIndexA=link,
                        collisionShapeB=c.shapes[i][0], collisionShapePositionB=pos[i].tolist(),
                        collisionShapeOrientationB=quats[i], physicsClientId=cid,
                    ):  # fmt: skip
                        return max(int(k) - 8, 0)
        return len(down) - 1
