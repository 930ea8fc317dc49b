"""Kinematic feasibility of grasp poses by the Panda IK the simulator itself runs (3.5.3, B.5.13).

:class:`PandaIKReachability` plugs into :class:`~sqmanip.grasping.planner.GraspPlanner` as its
``reachability``. A grasp counts as reachable only when ``Simulator.grasp`` will find IK
solutions for its three key poses, which are solved in the same order and from the same seeds:

1. pre-grasp: the tool ``approach_distance`` (10 cm) back along its z axis, seeded at the home
   configuration;
2. grasp: seeded at the pre-grasp solution;
3. lift: the grasp pose raised ``approach_distance``, seeded at the grasp solution.

Each solve is :meth:`sqmanip.sim.kinematics.PandaKinematics.ik` (pinocchio damped least squares,
joint limits by clamping) on the same URDF and base pose as the simulator. The simulator's
grasp plan (``Simulator.plan_grasp``) tries the seed and the ``READY`` pose first, then its fixed
extra seeds when that chain collides; here only the first two are tried (``restarts=1``), so a
pose accepted here converges in the simulator from the very same seed to the very same joint
angles (the iteration is deterministic), while a pose only another seed could reach is
rejected: the check is *conservative*, never optimistic. ``obstacles`` (world boxes, the table)
add the simulator's arm collision test: a chain whose pre-grasp, grasp or lift configuration
puts a vertex of an arm link's collision mesh (links 1-7, :meth:`PandaKinematics.link_points`)
within ``clearance`` of a box is unreachable. The planner checks the hand itself; a low side
grasp at the table edge can have the hand clear while link 6 cuts the table's corner, which the
simulator refuses ("pre-grasp configuration collides with table").

Frames (checked against both sides): the planner's grasp pose and the simulator's tool pose both
put the origin at the TCP between the fingers, ``z`` = approach, ``y`` = closing axis. They differ
only in the TCP depth: the simulator's ``panda_grasptarget`` is ``TCP_OFFSET = 0.105`` m in front
of the hand frame (the flange), the planner's TCP is ``GripperSpec.flange_offset = 0.1032`` m in
front of it. :func:`sim_tool_pose` converts (a 1.8 mm shift along ``z``) so that the physical hand
lands where the planner's collision model put it.

The parallel-jaw hand (and the planner's gripper model) is symmetric under a half turn about the
approach axis, but joint 7 (+-2.9 rad) is not: a top-down grasp whose yaw is ~180 deg from the
home pose is often out of the IK's reach while its half-turned twin is trivial. With
``symmetric=True`` (default) a pose counts as reachable when either twin is, and
:meth:`PandaIKReachability.executable_pose` returns the twin to send, already converted by
:func:`sim_tool_pose`: that method is *the* place that turns a planned ``Grasp.pose`` into the
``pose`` argument of ``Simulator.grasp``.

Cost (measured on this 2-core CPU, ~10 us per IK iteration): a reachable pose takes three solves
that converge in ~2-13 iterations from their seeds, about 1.3 ms per pose (the twin nearer the
home orientation is tried first); an unreachable pose that passes the cheap workspace-radius
prefilter runs both seeds of each twin until the IK stalls (about 2.5 ms). The pinocchio model is
built once per process and per base pose (about 10 ms) and shared by all instances; results are
memoised per pose (LRU, ``cache_size``). Poses are solved one by one (pinocchio has no batched
IK); the batch interface still lets the planner check a whole chunk per call.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from sqmanip.errors import ValidationError
from sqmanip.sim.actions import lifted, offset_along_z
from sqmanip.sim.config import HOME_TABLETOP, ROBOT_BASE_POSITION, SimConfig
from sqmanip.sim.kinematics import TCP_OFFSET, PandaKinematics

from .config import PANDA_HAND, WorkspaceReachability
from .types import GripperSpec

PREFILTER_MARGIN = 0.10
"""Slack (m) added to the Panda's 0.855 m flange reach in the radius prefilter, so the prefilter
only drops poses no IK could reach."""


def sim_tool_pose(poses: np.ndarray, gripper: GripperSpec = PANDA_HAND) -> np.ndarray:
    """Planner grasp poses ``(..., 4, 4)`` -> the simulator's tool (``panda_grasptarget``) poses.

    The only frame conversion between the grasp planner and the simulator: same axes, TCP moved
    ``TCP_OFFSET - gripper.flange_offset`` along the approach axis so both put the flange (and
    hence the hand and fingers) at the same place.
    """
    T = np.asarray(poses, dtype=np.float64)
    if T.ndim < 2 or T.shape[-2:] != (4, 4):
        raise ValidationError(f"poses must have shape (..., 4, 4), got {T.shape}")
    out = T.copy()
    out[..., :3, 3] += (TCP_OFFSET - gripper.flange_offset) * T[..., :3, 2]
    return out


HALF_TURN_Z = np.diag([-1.0, -1.0, 1.0, 1.0])
"""Right-multiplied: the same grasp with the fingers swapped (half turn about the approach)."""

_MODEL_LOCK = threading.Lock()


@lru_cache(maxsize=8)
def _kinematics(base_key: tuple[float, ...]) -> PandaKinematics:
    """One pinocchio model per process and base pose (building it parses the URDF)."""
    return PandaKinematics(np.asarray(base_key, dtype=np.float64).reshape(4, 4))


def default_base_pose() -> np.ndarray:
    """The simulator's robot base (``panda_link0``) to world: a translation to the pedestal."""
    base = np.eye(4)
    base[:3, 3] = ROBOT_BASE_POSITION
    return base


class PandaIKReachability:
    """``(K, 4, 4) planner grasp poses -> bool (K,)``: the simulator's grasp IK succeeds.

    ``base_pose`` (4 x 4, default the simulator's pedestal), ``q_home`` (7,) the configuration the
    simulator seeds the pre-grasp IK with (tabletop home), ``approach_distance`` the pre-grasp /
    lift offset (the simulator's 0.10 m). ``check_lift=False`` skips the lift pose. ``restarts``
    and ``max_iters`` are passed to the IK; keep ``restarts <= 1`` and ``max_iters <= 200`` (the
    simulator's) for the conservative guarantee in the module docstring. ``obstacles`` are
    axis-aligned world boxes ``(lo (3,), hi (3,))`` the arm links must keep ``clearance`` from. ``symmetric`` also
    accepts a pose whose half turn about the approach axis is reachable (send
    :meth:`executable_pose` to the simulator then).
    """

    def __init__(
        self,
        base_pose: np.ndarray | None = None,
        *,
        q_home: np.ndarray = HOME_TABLETOP,
        approach_distance: float = SimConfig().approach_distance,
        check_lift: bool = True,
        gripper: GripperSpec = PANDA_HAND,
        restarts: int = 1,
        max_iters: int = 200,
        cache_size: int = 4096,
        symmetric: bool = True,
        obstacles: Sequence[tuple[Sequence[float], Sequence[float]]] = (),
        clearance: float = 0.005,
    ) -> None:
        base = default_base_pose() if base_pose is None else np.asarray(base_pose, np.float64)
        if base.shape != (4, 4) or not np.isfinite(base).all():
            raise ValidationError(f"base_pose must be a finite (4, 4) matrix, got {base.shape}")
        q = np.asarray(q_home, dtype=np.float64)
        if q.shape != (7,) or not np.isfinite(q).all():
            raise ValidationError(f"q_home must be a finite (7,) vector, got shape {q.shape}")
        if not (np.isfinite(approach_distance) and approach_distance >= 0):
            raise ValidationError(f"approach_distance must be >= 0, got {approach_distance!r}")
        if restarts < 1 or max_iters < 1 or cache_size < 0:
            raise ValidationError(
                f"need restarts >= 1, max_iters >= 1, cache_size >= 0; got {restarts}, "
                f"{max_iters}, {cache_size}"
            )
        boxes = np.asarray(obstacles, dtype=np.float64).reshape(-1, 2, 3)
        if not np.isfinite(boxes).all() or (boxes[:, 0] > boxes[:, 1]).any() or clearance < 0:
            raise ValidationError("obstacles must be finite (lo, hi) boxes and clearance >= 0")
        self.obstacles = boxes
        self.clearance = float(clearance)
        self.base_pose = base
        self.q_home = q
        self.approach_distance = float(approach_distance)
        self.check_lift = check_lift
        self.gripper = gripper
        self.restarts = int(restarts)
        self.max_iters = int(max_iters)
        self.cache_size = int(cache_size)
        self.symmetric = bool(symmetric)
        self._cache: OrderedDict[bytes, int] = OrderedDict()
        self._home_rotation: np.ndarray | None = None
        self._prefilter = WorkspaceReachability(
            base=tuple(float(v) for v in base[:3, 3]),
            max_reach=0.855 + PREFILTER_MARGIN,
            min_reach=0.0,
            flange_offset=gripper.flange_offset,
        )
        self.n_solved = 0
        """IK chains actually run (cache misses that passed the prefilter), for cost reports."""

    @property
    def kinematics(self) -> PandaKinematics:
        with _MODEL_LOCK:
            return _kinematics(tuple(float(v) for v in self.base_pose.reshape(-1)))

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_cache"] = OrderedDict()
        return state

    def solve(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Joint angles ``(q_pre, q_grasp, q_lift)`` (7,) each for one planner grasp ``pose``
        (4 x 4) sent as is (no twin), as the simulator finds them, or None when a solve fails
        or a configuration's arm links hit an obstacle."""
        T = sim_tool_pose(np.asarray(pose, dtype=np.float64), self.gripper)
        kin = self.kinematics
        kw = {"restarts": self.restarts, "max_iters": self.max_iters}
        # A fresh generator per pose keeps answers independent of call order (restarts > 1).
        rng = np.random.default_rng(0)
        d = self.approach_distance
        pre = kin.ik(offset_along_z(T, -d), self.q_home, rng=rng, **kw)
        if not pre.success:
            return None
        grasp = kin.ik(T, pre.q, rng=rng, **kw)
        if not grasp.success:
            return None
        chain = (pre.q, grasp.q, grasp.q)
        if self.check_lift:
            lift = kin.ik(lifted(T, d), grasp.q, rng=rng, **kw)
            if not lift.success:
                return None
            chain = (pre.q, grasp.q, lift.q)
        if any(self._hits_obstacle(q) for q in chain):
            return None
        return chain

    def _hits_obstacle(self, q: np.ndarray) -> bool:
        if not len(self.obstacles):
            return False
        P = self.kinematics.link_points(q)
        centre = self.obstacles.mean(1)[:, None]  # (boxes, 1, 3)
        half = 0.5 * (self.obstacles[:, 1] - self.obstacles[:, 0])[:, None] + self.clearance
        return bool((np.abs(P - centre) <= half).all(-1).any())

    def _variants(self, pose: np.ndarray) -> list[np.ndarray]:
        """The pose and (if ``symmetric``) its half turn about z, nearer the home tool first."""
        if not self.symmetric:
            return [pose]
        twin = pose @ HALF_TURN_Z
        if self._home_rotation is None:
            self._home_rotation = self.kinematics.fk(self.q_home)[:3, :3]
        R0 = self._home_rotation
        if np.trace(R0.T @ twin[:3, :3]) > np.trace(R0.T @ pose[:3, :3]):
            return [twin, pose]
        return [pose, twin]

    def _lookup(self, pose: np.ndarray) -> int:
        """Index into :meth:`_variants` of the first reachable twin, -1 when none (memoised)."""
        key = np.round(pose, 9).tobytes()
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return hit
        hit = -1
        for i, v in enumerate(self._variants(pose)):
            self.n_solved += 1
            if self.solve(v) is not None:
                hit = i
                break
        if self.cache_size:
            self._cache[key] = hit
            if len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)
        return hit

    def executable_pose(self, pose: np.ndarray) -> np.ndarray | None:
        """The ``Simulator.grasp`` tool pose (4 x 4) for the planner grasp ``pose`` (4 x 4): the
        reachable twin converted by :func:`sim_tool_pose`; None when no twin is reachable."""
        T = np.asarray(pose, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise ValidationError(f"pose must be a finite (4, 4) matrix, got shape {T.shape}")
        if not self._prefilter(T[None])[0]:
            return None
        i = self._lookup(T)
        return None if i < 0 else sim_tool_pose(self._variants(T)[i], self.gripper)

    def __call__(self, poses: np.ndarray) -> np.ndarray:
        """``poses (K, 4, 4)`` planner grasp poses (world) -> ``(K,)`` bool."""
        T = np.asarray(poses, dtype=np.float64)
        if T.ndim != 3 or T.shape[-2:] != (4, 4):
            raise ValidationError(f"poses must have shape (K, 4, 4), got {T.shape}")
        out = np.zeros(T.shape[0], dtype=bool)
        candidates = np.isfinite(T).all(axis=(1, 2))
        if candidates.any():
            candidates[candidates] = self._prefilter(T[candidates])
        for k in np.flatnonzero(candidates):
            out[k] = self._lookup(T[k]) >= 0
        return out
