"""Simulated shelf scenarios for the search experiments (Ch. 5.5.1).

A scenario is ``n`` surrounding cylinders and boxes of several sizes standing on the shelf floor
and a red cylinder target placed where the fixed shelf camera (1280 x 720) cannot see it:

1. the surrounding objects are drawn (boxes or cylinders, uniform sizes below; duplicates
   allowed, as the thesis' random selection among its object set) and placed upright at random
   floor positions without overlap (discs with a 1 cm gap), then spawned in the simulator;
2. the target is placed (5.5.1): candidate positions are the grid poses where the existence
   function with the ground-truth shapes is 1 (hidden from the camera and collision-free,
   C.2) and where at least one C.3 grasp is free of the shelf boards ("the target object is not
   graspable because of the collision of the gripper with the shelf": discarded). Candidates
   are tried in random order; the first one with fewer than ``found_pixels = 100`` target
   pixels in the simulator's segmentation image, and (with an in-process simulator) at least
   one candidate grasp the robot can execute there with the shelf alone
   (:class:`.execution.SimGraspCheck` with ``objects=False``: the IK and the whole arm against
   the shelf, not only the gripper's afterimage), is kept;
3. when no candidate is left the scenario is discarded (``make_scenario`` returns ``None`` and
   :func:`scenarios` draws the next seed).

Everything is seeded: ``ShelfScenario.scene`` is a :class:`sqmanip.sim.SceneSpec` (target last)
and resetting a simulator with it replays the scenario exactly.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import torch

from sqmanip.errors import ValidationError
from sqmanip.geometry import PinholeCamera
from sqmanip.sim import Intrinsics, ObjectSpec, SceneSpec, Simulator

from .actions import GraspSource
from .config import SearchConfig
from .execution import SimGraspCheck
from .existence import ExistenceModel
from .graspability import GraspabilityModel
from .shelf import SceneState, ShelfSpec, TargetSpec, make_pose_grid

SHELF_CAMERA = Intrinsics(1280, 720, 640.0, 640.0, 639.5, 359.5, 0.05, 3.0)
"""Azure Kinect colour mode: 1280 x 720, 90 deg horizontal field of view (5.5)."""
TARGET_COLOR = (0.9, 0.05, 0.05, 1.0)
FOUND_PIXELS = 100
"""5.5.1: the target is found when more than 100 of its pixels are in the segmentation image."""

BOX_SIDES = (0.04, 0.09)
"""Box footprint sides (m) (ours: the thesis' objects are shown in Fig. 5.5 only)."""
CYLINDER_RADII = (0.025, 0.045)
HEIGHTS = (0.11, 0.18)
TARGET_RADIUS = 0.025
TARGET_HEIGHT = 0.10


@dataclasses.dataclass(frozen=True)
class ShelfScenario:
    """One replayable scenario: the scene spec (surrounding objects, then the target)."""

    n_objects: int
    seed: int
    scene: SceneSpec
    target: TargetSpec

    @property
    def target_index(self) -> int:
        return len(self.scene.objects) - 1

    def to_dict(self) -> dict[str, Any]:
        return {
            "n_objects": self.n_objects,
            "seed": self.seed,
            "scene": self.scene.to_dict(),
            "target": {"size": list(self.target.size)},
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ShelfScenario:
        return cls(
            int(d["n_objects"]),
            int(d["seed"]),
            SceneSpec.from_dict(d["scene"]),
            TargetSpec("cylinder", tuple(d["target"]["size"])),
        )


def shelf_spec(sim: Simulator) -> ShelfSpec:
    return ShelfSpec.from_geometry(sim.config.shelf)


def shelf_camera(sim: Simulator, intrinsics: Intrinsics = SHELF_CAMERA) -> PinholeCamera:
    """The simulator's fixed shelf camera as a :class:`PinholeCamera` (same pose, intrinsics)."""
    k = intrinsics
    return PinholeCamera(
        fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy, width=k.width, height=k.height,
        pose=sim.camera_pose("shelf"),
    )  # fmt: skip


def target_pixels(sim: Simulator, target_index: int, intrinsics: Intrinsics = SHELF_CAMERA) -> int:
    """Number of target pixels in the shelf camera's segmentation image."""
    obs = sim.observe("shelf", intrinsics=intrinsics, noise=False)
    return int((obs.segmentation == target_index).sum())


def _random_objects(rng: np.random.Generator, n: int, shelf: ShelfSpec) -> list[ObjectSpec]:
    """``n`` upright boxes / cylinders at random non-overlapping floor positions."""
    placed: list[tuple[float, float, float]] = []
    out: list[ObjectSpec] = []
    lo_x, hi_x = shelf.front_x, shelf.front_x + shelf.depth
    half_w = shelf.inner_width / 2
    for i in range(n):
        for _ in range(200):
            h = float(rng.uniform(*HEIGHTS))
            color = tuple(float(c) for c in rng.uniform(0.2, 0.8, 3) * [0.6, 1.0, 1.0]) + (1.0,)
            if rng.random() < 0.5:
                sx, sy = (float(v) for v in rng.uniform(*BOX_SIDES, size=2))
                r = 0.5 * math.hypot(sx, sy)
                spec = ObjectSpec("box", size=(sx, sy, h), color=color, name=f"box_{i}")
            else:
                rad = float(rng.uniform(*CYLINDER_RADII))
                r = rad
                spec = ObjectSpec(
                    "cylinder", radius=rad, height=h, color=color, name=f"cylinder_{i}"
                )
            x = float(rng.uniform(lo_x + r + 0.01, hi_x - r - 0.01))
            y = float(rng.uniform(-half_w + r + 0.01, half_w - r - 0.01))
            if any(math.hypot(x - px, y - py) < r + pr + 0.01 for px, py, pr in placed):
                continue
            yaw = float(rng.uniform(-math.pi, math.pi))
            quat = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
            out.append(spec.with_pose((x, y, shelf.bottom_z + h / 2 + 1e-4), quat))
            placed.append((x, y, r))
            break
    return out


def scenario_from_objects(
    objects: list[ObjectSpec],
    target_xy: tuple[float, float],
    target: TargetSpec | None = None,
    seed: int = 0,
    shelf: ShelfSpec | None = None,
) -> ShelfScenario:
    """A hand-built scenario: ``objects`` (posed specs) and the red target at ``target_xy``."""
    target = target or TargetSpec.cylinder(TARGET_RADIUS, TARGET_HEIGHT)
    shelf = shelf or ShelfSpec()
    a1, _, a3 = target.size
    tgt = ObjectSpec(
        "cylinder",
        position=(float(target_xy[0]), float(target_xy[1]), shelf.bottom_z + a3 + 1e-4),
        radius=a1,
        height=2 * a3,
        color=TARGET_COLOR,
        name="target",
    )
    return ShelfScenario(len(objects), int(seed), SceneSpec("shelf", (*objects, tgt), seed), target)


class ScenarioBuilder:
    """Builds scenarios with one simulator and the f / g models of the ground-truth target."""

    def __init__(
        self,
        sim: Simulator | None = None,
        config: SearchConfig | None = None,
        target: TargetSpec | None = None,
        grasp_planner=None,
    ) -> None:
        """``grasp_planner``: source of the target's C.3 candidates (see
        :class:`.actions.GraspSource`; ``None`` in-process)."""
        self.sim = sim or Simulator()
        # placement tests the ground-truth shapes: no recognition tolerance
        self.config = dataclasses.replace(config or SearchConfig(), object_tolerance=0.0)
        self.target = target or TargetSpec.cylinder(TARGET_RADIUS, TARGET_HEIGHT)
        self.shelf = shelf_spec(self.sim)
        self.camera = shelf_camera(self.sim)
        self.grid = make_pose_grid(self.shelf, self.target, self.config.resolution)
        self.existence = ExistenceModel(
            self.shelf, self.target, self.grid, self.camera, self.config
        )
        self.grasp = GraspabilityModel(
            self.shelf, self.target, self.grid, self.config, grasp_source=GraspSource(grasp_planner)
        )
        valid = self.grasp.local_valid[self.grasp._theta_index]
        n = torch.where(valid, self.grasp.n_shelf, torch.full_like(self.grasp.n_shelf, 99))
        self.shelf_graspable = (n.min(-1).values == 0) if n.shape[1] else valid.any(-1)
        self.grasp_check = SimGraspCheck(self.sim) if isinstance(self.sim, Simulator) else None

    def arm_graspable(self, i: int) -> bool:
        """Some C.3 candidate at grid pose ``i`` is free of the boards (afterimage) and executable
        by the robot with the shelf alone (always True without an in-process simulator). The
        simulator must hold a shelf scene (its boards are what the arm is checked against).
        The same must hold 1 cm deeper into the shelf, where reach and the elbow's clearance
        above the floor board run out (ours: a target nudged there became ungraspable)."""
        if self.grasp_check is None:
            return True
        gm = self.grasp
        T, valid = gm.grasp_poses(torch.tensor([int(i)]))
        ok = valid[0] & (gm.n_shelf[int(i)] == 0)
        if not bool(ok.any()):
            return False
        poses = T[0][ok].double().numpy()
        deeper = poses.copy()
        deeper[:, 0, 3] += 0.01  # a margin: a push may nudge the target deeper into the shelf
        return bool(self.grasp_check(poses, False).any() and self.grasp_check(deeper, False).any())

    def hidden(self, scene: SceneState, margin: float = 0.005) -> torch.Tensor:
        """``(P,)`` bool: no pixel of the (render-scale) image sees the target at the pose.

        Stricter than ``f_d`` (whose MSE threshold tolerates a partly visible target): a pixel
        sees the target when its ray meets it (``D_T < t_far``) in front of the objects
        (``D_T < D_0 - margin``). One render pixel is ``1 / render_scale^2`` (49) camera pixels,
        so no such pixel means well under the 100 found-pixels of 5.5.1."""
        em = self.existence
        fp = em._foot
        pixels, inverse = torch.unique(fp.pixel, return_inverse=True)
        d0 = em.object_depth(scene, pixels)[inverse]
        seen = (fp.depth < em.config.t_far - 0.01) & (fp.depth < d0 - margin)
        count = torch.zeros(len(self.grid), dtype=torch.long).index_add_(0, fp.pose, seen.long())
        return count == 0

    def make(self, n_objects: int, seed: int, max_tries: int = 10) -> ShelfScenario | None:
        """The scenario of ``seed``, or ``None`` when the target cannot be placed (5.5.1)."""
        if not 0 <= n_objects <= 12:
            raise ValidationError(f"n_objects must be in 0..12, got {n_objects!r}")
        rng = np.random.default_rng([int(seed), int(n_objects)])
        objects = _random_objects(rng, n_objects, self.shelf)
        if len(objects) < n_objects:
            return None
        gt = [o.superquadric() for o in objects]
        scene = SceneState.from_objects(gt)
        f = self.existence.evaluate(scene).bool() & self.hidden(scene)
        cand = (f & self.shelf_graspable).nonzero().squeeze(-1).numpy()
        if cand.size == 0:
            return None
        rng.shuffle(cand)
        a1, _, a3 = self.target.size
        for i in cand[:max_tries]:
            x, y = (float(v) for v in self.grid.xy[int(i)])
            tgt = ObjectSpec(
                "cylinder",
                position=(x, y, self.shelf.bottom_z + a3 + 1e-4),
                radius=a1,
                height=2 * a3,
                color=TARGET_COLOR,
                name="target",
            )
            spec = SceneSpec("shelf", (*objects, tgt), int(seed))
            self.sim.reset(spec)  # the shelf layout: the arm check below needs its boards
            if target_pixels(self.sim, len(objects)) < FOUND_PIXELS and self.arm_graspable(i):
                return ShelfScenario(n_objects, int(seed), spec, self.target)
        return None

    def scenarios(
        self, n_objects: int, count: int, seed: int = 0, max_seeds: int | None = None
    ) -> Iterator[ShelfScenario]:
        """``count`` valid scenarios from seeds ``seed, seed + 1, ...`` (discarded ones skipped)."""
        limit = max_seeds if max_seeds is not None else 20 * count + 20
        made = 0
        for s in range(seed, seed + limit):
            sc = self.make(n_objects, s)
            if sc is not None:
                made += 1
                yield sc
                if made >= count:
                    return
