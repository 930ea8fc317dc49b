"""Seeded pushing scenarios of Ch. 4.6.3 / 4.7.3 / 4.7.4: a simulator scene plus its task.

Object sets (Fig. 4.15 uses box- and cylinder-like objects "inspired by YCB"; the figure gives
no sizes, so the sizes below are the YCB objects' published dimensions, rounded to mm):

- boxes: ``potted_meat`` (YCB 010, 9.7 x 5.0 x 8.2 cm, upright), ``pudding`` (YCB 008,
  11.0 x 8.9 x 3.5 cm, lying flat), ``gelatin`` (YCB 009, 8.5 x 7.3 x 2.8 cm, lying flat),
  ``sugar`` (YCB 004, 17.5 x 8.9 x 3.8 cm, lying on its back);
- cylinders: ``tomato_soup`` (YCB 005, r 3.35 cm, h 10.1 cm), ``tuna`` (YCB 007, r 4.28 cm,
  h 3.3 cm), ``master_chef`` (YCB 002, r 5.1 cm, h 13.9 cm), ``small_can`` (r 3.7 cm, h 7.5 cm,
  a generic food can);
- ``large_flat_box`` for "grasping large": 34 x 13 x 5 cm lying flat (a cereal-box-like object).
  Both footprint sides exceed the 8 cm opening (and the 7 cm rule of B.5), so it is graspable
  only across its 5 cm height where it overhangs the table edge. YCB has no box this long; the
  length lets pushes, whose start and end must lie in the simulator's push workspace
  (``|y| <= 0.256``), carry it over the table's y edge (``|y| = 0.40``): it starts at
  ``|y| in [0.10, 0.20]`` (its end 13-23 cm from the edge) and needs a centre at ``|y| ~ 0.30``
  (7 cm overhang) for an edge grasp.

Every object rests on the table top (``z = 0``) at a random planar pose drawn from
``np.random.default_rng(seed)``; footprints (boxes as rectangles, cylinders as 16-gons) must not
overlap (separating-axis test with a margin). Task object ids are the scene's object indices, i.e.
``Simulator`` object ids. Tasks:

- ``moving`` (4.6.3): 3 objects of one set; goal of every object ``(0.30, y_0, z_0)`` as in the
  thesis' real-world moving task (objects start at ``x in [0.42, 0.60]``);
- ``singulation`` (4.6.3): 3-4 objects of one set packed within +-9 cm of a cluster centre (scenes
  already singulated are redrawn);
- ``grasping_clutter``: the tomato-soup can (graspable alone) surrounded by 3 objects (4 in all:
  SQPD-Net handles at most 4, 4.5) with 0-1.5 cm gaps; scenes whose target is already graspable
  (B.5.13 check on the ground truth, Panda IK) are redrawn;
- ``grasping_large``: the large flat box, long side within 15 deg of world y, on one y side;
- ``interactive_moving`` (4.7.3): a tuna can as target, goal ``(0.30, 0.0, z_0)``, a pushing
  object touching it on its far (+x) side and 1-2 distractors.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from sqmanip.errors import ValidationError
from sqmanip.sim.config import TABLE_SIZE, WORKSPACE_CENTER
from sqmanip.sim.scene import ObjectSpec, SceneSpec

from .config import TableSpec
from .tasks import GraspingTask, InteractiveMovingTask, MovingTask, SingulationTask, Task

__all__ = [
    "BOX_SET",
    "CYLINDER_SET",
    "LARGE_FLAT_BOX",
    "SCENARIO_KINDS",
    "Scenario",
    "make_scenario",
    "scenario_suite",
    "sim_table",
]

SCENARIO_KINDS = (
    "moving",
    "singulation",
    "grasping_clutter",
    "grasping_large",
    "interactive_moving",
)

_COLORS = {
    "potted_meat": (0.20, 0.35, 0.80, 1.0),
    "pudding": (0.55, 0.30, 0.15, 1.0),
    "gelatin": (0.85, 0.20, 0.25, 1.0),
    "sugar": (0.95, 0.85, 0.30, 1.0),
    "tomato_soup": (0.80, 0.10, 0.10, 1.0),
    "tuna": (0.30, 0.55, 0.85, 1.0),
    "master_chef": (0.15, 0.30, 0.70, 1.0),
    "small_can": (0.35, 0.70, 0.35, 1.0),
    "large_flat_box": (0.90, 0.60, 0.20, 1.0),
}

BOX_SET: dict[str, tuple[float, float, float]] = {
    "potted_meat": (0.097, 0.050, 0.082),
    "pudding": (0.110, 0.089, 0.035),
    "gelatin": (0.085, 0.073, 0.028),
    "sugar": (0.175, 0.089, 0.038),
}
"""Box-like objects: full extents (x, y, z) in m, YCB-sized (module docstring)."""
CYLINDER_SET: dict[str, tuple[float, float]] = {
    "tomato_soup": (0.0335, 0.101),
    "tuna": (0.0428, 0.033),
    "master_chef": (0.051, 0.139),
    "small_can": (0.037, 0.075),
}
"""Cylinder-like objects: (radius, height) in m."""
LARGE_FLAT_BOX = (0.13, 0.34, 0.05)
"""(x, y, z) extents of the "grasping large" box (module docstring explains the 30 cm)."""


def sim_table() -> TableSpec:
    """The simulator's table as the planner's :class:`TableSpec` (built from ``sqmanip.sim``'s
    constants, so the two cannot drift; ``TableSpec()``'s defaults repeat them without PyBullet).
    """
    return TableSpec(
        center=(WORKSPACE_CENTER[0] + 0.1, WORKSPACE_CENTER[1]),
        size=(TABLE_SIZE[0], TABLE_SIZE[1]),
        height=0.0,
        thickness=TABLE_SIZE[2],
    )


def sim_reachability():
    """The simulator's Panda IK reachability with its table as the arm links' obstacle (the
    grasp check of every simulated episode, the planner service's included)."""
    from sqmanip.grasping.reachability import PandaIKReachability

    t = sim_table()
    return PandaIKReachability(obstacles=[((*t.lo, t.height - t.thickness), (*t.hi, t.height))])


@dataclasses.dataclass(frozen=True)
class Scenario:
    """One episode's start: the scene to reset the simulator with and the task on its ids."""

    kind: str
    index: int
    seed: int
    scene: SceneSpec
    task: Task
    object_set: str
    """``boxes``, ``cylinders``, ``clutter``, ``large`` or ``interactive``."""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(o.name for o in self.scene.objects)

    def initial_positions(self) -> np.ndarray:
        """``(N, 3)`` object positions of the scene spec (ids are row indices)."""
        return np.array([o.position for o in self.scene.objects], dtype=np.float64)


# --- footprints ------------------------------------------------------------------------------


def _quat_z(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def _footprint(spec: ObjectSpec, xy: np.ndarray, yaw: float) -> np.ndarray:
    """``(V, 2)`` convex polygon of the object's footprint at ``(xy, yaw)``."""
    if spec.kind == "box":
        hx, hy = spec.size[0] / 2, spec.size[1] / 2
        local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    else:
        a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        local = spec.radius * np.stack([np.cos(a), np.sin(a)], -1)
    c, s = math.cos(yaw), math.sin(yaw)
    return local @ np.array([[c, s], [-s, c]]) + xy


def _overlap(P: np.ndarray, Q: np.ndarray, margin: float) -> bool:
    """Separating-axis test of two convex polygons, each grown by ``margin / 2``."""
    for poly in (P, Q):
        edges = np.roll(poly, -1, 0) - poly
        normals = np.stack([edges[:, 1], -edges[:, 0]], -1)
        normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
        a, b = P @ normals.T, Q @ normals.T
        if np.any((a.max(0) + margin < b.min(0)) | (b.max(0) + margin < a.min(0))):
            return False
    return True


def _spec(name: str) -> ObjectSpec:
    if name in BOX_SET:
        return ObjectSpec("box", size=BOX_SET[name], color=_COLORS[name], name=name)
    if name in CYLINDER_SET:
        r, h = CYLINDER_SET[name]
        return ObjectSpec("cylinder", radius=r, height=h, color=_COLORS[name], name=name)
    if name == "large_flat_box":
        return ObjectSpec("box", size=LARGE_FLAT_BOX, color=_COLORS[name], name=name)
    raise ValidationError(f"unknown object name {name!r}")


def _height(spec: ObjectSpec) -> float:
    return spec.size[2] if spec.kind == "box" else spec.height


def _place(spec: ObjectSpec, xy, yaw: float) -> ObjectSpec:
    return spec.with_pose((float(xy[0]), float(xy[1]), _height(spec) / 2), _quat_z(float(yaw)))


class _Placer:
    """Rejection sampling of non-overlapping planar poses."""

    def __init__(self, rng: np.random.Generator, margin: float = 0.01) -> None:
        self.rng = rng
        self.margin = margin
        self.placed: list[tuple[ObjectSpec, np.ndarray]] = []

    def fits(self, poly: np.ndarray, margin: float | None = None) -> bool:
        m = self.margin if margin is None else margin
        return not any(_overlap(poly, q, m) for _, q in self.placed)

    def add(self, spec: ObjectSpec, xy, yaw: float) -> ObjectSpec:
        placed = _place(spec, xy, yaw)
        self.placed.append((placed, _footprint(spec, np.asarray(xy, float), yaw)))
        return placed

    def sample(
        self,
        spec: ObjectSpec,
        lo: Sequence[float],
        hi: Sequence[float],
        margin: float | None = None,
        tries: int = 200,
    ) -> ObjectSpec:
        for _ in range(tries):
            xy = self.rng.uniform(lo, hi)
            yaw = float(self.rng.uniform(-np.pi, np.pi))
            if self.fits(_footprint(spec, xy, yaw), margin):
                return self.add(spec, xy, yaw)
        raise ValidationError(f"could not place {spec.name} in {lo}..{hi} after {tries} tries")

    @property
    def specs(self) -> tuple[ObjectSpec, ...]:
        return tuple(s for s, _ in self.placed)


# --- the generators ------------------------------------------------------------------------------


def _object_set(index: int) -> tuple[str, dict]:
    """Alternate the two object sets over episodes (4.6.3: "5 experiments for 2 object sets")."""
    return ("boxes", BOX_SET) if index % 2 == 0 else ("cylinders", CYLINDER_SET)


def _moving(rng: np.random.Generator, index: int) -> tuple[tuple[ObjectSpec, ...], Task, str]:
    set_name, objs = _object_set(index)
    names = rng.choice(sorted(objs), size=3, replace=False)
    pl = _Placer(rng, margin=0.03)
    for n in names:
        pl.sample(_spec(str(n)), (0.42, -0.18), (0.60, 0.18))
    goals = {i: (0.30, s.position[1], s.position[2]) for i, s in enumerate(pl.specs)}
    return pl.specs, MovingTask.to_positions(goals), set_name


def _singulation(rng: np.random.Generator, index: int) -> tuple[tuple[ObjectSpec, ...], Task, str]:
    set_name, objs = _object_set(index)
    n = int(rng.integers(3, 5))
    names = rng.choice(sorted(objs), size=n, replace=False)
    center = rng.uniform((0.40, -0.08), (0.52, 0.08))
    pl = _Placer(rng, margin=0.005)
    for name in names:
        pl.sample(_spec(str(name)), center - 0.09, center + 0.09)
    return pl.specs, SingulationTask(0.20), set_name


def _clutter(rng: np.random.Generator) -> tuple[tuple[ObjectSpec, ...], Task, str]:
    center = rng.uniform((0.40, -0.10), (0.52, 0.10))
    pl = _Placer(rng, margin=0.0)
    target = _spec("tomato_soup")
    pl.add(target, center, float(rng.uniform(-np.pi, np.pi)))
    others = ["potted_meat", "master_chef", "pudding"]
    base = float(rng.uniform(0, 2 * np.pi))
    for k, name in enumerate(others):
        spec = _spec(name)
        for _ in range(200):
            ang = base + k * 2 * np.pi / 3 + rng.uniform(-0.3, 0.3)
            yaw = float(rng.uniform(-np.pi, np.pi))
            d = np.array([math.cos(ang), math.sin(ang)])
            # slide in from far away until the footprint touches the placed ones, then back off
            # by a random 0-1.5 cm gap
            for r in np.arange(0.25, 0.03, -0.0025):
                if not pl.fits(_footprint(spec, center + r * d, yaw), 0.0):
                    break
            r_touch = r + 0.0025
            r_final = r_touch + float(rng.uniform(0.0, 0.015))
            if pl.fits(_footprint(spec, center + r_final * d, yaw), 0.001):
                pl.add(spec, center + r_final * d, yaw)
                break
    return pl.specs, GraspingTask(0), "clutter"


def _large(rng: np.random.Generator) -> tuple[tuple[ObjectSpec, ...], Task, str]:
    side = 1.0 if rng.random() < 0.5 else -1.0
    xy = (float(rng.uniform(0.40, 0.52)), side * float(rng.uniform(0.10, 0.20)))
    yaw = float(rng.uniform(-np.pi / 12, np.pi / 12))
    pl = _Placer(rng)
    pl.add(_spec("large_flat_box"), xy, yaw)
    return pl.specs, GraspingTask(0), "large"


def _interactive(rng: np.random.Generator) -> tuple[tuple[ObjectSpec, ...], Task, str]:
    pl = _Placer(rng, margin=0.02)
    target = _spec("tuna")
    txy = np.array([float(rng.uniform(0.42, 0.48)), float(rng.uniform(-0.08, 0.08))])
    pl.add(target, txy, 0.0)
    # the pushing object touches the target on its far (+x) side
    pusher = _spec(str(rng.choice(["potted_meat", "small_can"])))
    yaw = float(rng.uniform(-0.3, 0.3)) + (np.pi / 2 if pusher.kind == "box" else 0.0)
    d = np.array([1.0, 0.0])
    r = 0.30
    for r in np.arange(0.30, 0.03, -0.0025):
        if not pl.fits(_footprint(pusher, txy + r * d, yaw), 0.0):
            break
    pl.add(pusher, txy + (r + 0.005) * d, yaw)
    for name in rng.choice(["gelatin", "tomato_soup", "pudding"], size=2, replace=False):
        pl.sample(_spec(str(name)), (0.30, -0.22), (0.62, 0.22), margin=0.04)
    goal = (0.30, 0.0, _height(target) / 2)
    return pl.specs, InteractiveMovingTask(0, np.array(goal)), "interactive"


def _graspable_now(specs: Sequence[ObjectSpec], target: int) -> bool:
    """B.5.13 on the ground truth: does the target already have a feasible grasp?"""

    from sqmanip.grasping.config import PANDA_HAND

    from .config import GraspCostSpec
    from .costs import GraspFeasibility, PackedScene

    scene = PackedScene.from_objects([([s.superquadric()], i) for i, s in enumerate(specs)])
    feas = GraspFeasibility(
        sim_reachability(), spec=GraspCostSpec(), gripper=PANDA_HAND, table=sim_table()
    )
    return bool(feas.feasible(scene, scene.poses[None], target).any())


def _min_pair_distance(xy: np.ndarray) -> float:
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    return float(d[np.triu_indices(len(xy), 1)].min()) if len(xy) > 1 else math.inf


def make_scenario(kind: str, index: int, seed: int = 0) -> Scenario:
    """The ``index``-th scenario of ``kind`` for base ``seed`` (deterministic).

    The generator's seed is ``hash((kind, seed, index))`` via ``np.random.SeedSequence``, so
    episodes are independent of one another and of the order they are generated in.
    """
    if kind not in SCENARIO_KINDS:
        raise ValidationError(f"kind must be one of {SCENARIO_KINDS}, got {kind!r}")
    if not isinstance(index, int) or index < 0:
        raise ValidationError(f"index must be an integer >= 0, got {index!r}")
    k = SCENARIO_KINDS.index(kind)
    ss = np.random.SeedSequence([int(seed), k, index])
    scene_seed = int(ss.generate_state(1)[0])
    for attempt in range(50):
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), k, index, attempt]))
        try:
            if kind == "moving":
                specs, task, set_name = _moving(rng, index)
            elif kind == "singulation":
                specs, task, set_name = _singulation(rng, index)
            elif kind == "grasping_clutter":
                specs, task, set_name = _clutter(rng)
            elif kind == "grasping_large":
                specs, task, set_name = _large(rng)
            else:
                specs, task, set_name = _interactive(rng)
        except ValidationError:
            continue  # an object found no free spot: draw the next attempt
        if kind == "singulation":
            xy = np.array([o.position[:2] for o in specs])
            if _min_pair_distance(xy) > 0.20:
                continue  # already singulated
        elif kind == "grasping_clutter" and (len(specs) < 4 or _graspable_now(specs, 0)):
            continue
        return Scenario(kind, index, seed, SceneSpec("tabletop", specs, scene_seed), task, set_name)
    raise ValidationError(f"could not generate a {kind} scenario for index {index}, seed {seed}")


def scenario_suite(counts: dict[str, int], seed: int = 0) -> list[Scenario]:
    """``counts[kind]`` scenarios of each kind (Table 4.6: moving 20, singulation 20, grasping
    clutter 10, grasping large 10)."""
    return [make_scenario(k, i, seed) for k, n in counts.items() for i in range(n)]
