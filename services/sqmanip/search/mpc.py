"""Sampling MPC for search-for-grasp / search-and-grasp (5.3, 5.4.3, 5.4.4, Table 5.1, 5.6.2).

One :meth:`SearchPlanner.decide` is one MPC iteration: estimate ``f_0``, ``g_0`` from the current
recognized scene, stop with a grasp when the target is visible and graspable, else sample
``n_sequences`` (30) action sequences of horizon ``M = 3``, roll each out with the scene dynamics
and the ``f``/``g`` dynamics (5.4.5), score it by (5.4.6) and return the first action of the best.
The episode loop (observe, act, at most ``T = 10`` times) belongs to the runner.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any, Literal

import numpy as np
import torch

from sqmanip.errors import ValidationError
from sqmanip.geometry import PinholeCamera, Superquadric
from sqmanip.grasping import PANDA_HAND, GripperSpec

from .actions import Action, ActionSampler, PickAndPlace, Push, PushDynamics, apply_actions
from .config import SearchConfig
from .existence import ExistenceModel
from .graspability import GraspabilityModel
from .objective import FGEvaluator, Maps, sequence_cost
from .shelf import PoseGrid, SceneState, ShelfSpec, TargetSpec, make_pose_grid


@dataclasses.dataclass
class Decision:
    """What to do next: ``kind`` push | pick_and_place | grasp | none (no valid action)."""

    kind: Literal["push", "pick_and_place", "grasp", "none"]
    params: dict[str, Any]
    f_map: np.ndarray
    fg_map: np.ndarray
    objective: float
    timings_ms: dict[str, float]
    action: Action | None = None
    reason: str = ""


class _GraspCache:
    """Rule-based C.3 grasps of an object (ray casting, the costliest part of sampling a
    pick-and-place in a rollout) cached by shape and orientation: the candidates translate with
    the object, so they are computed once per (params, rotation) and shifted; only the
    afterimage collision test runs per predicted scene."""

    def __init__(self, sampler: ActionSampler, size: int = 2048) -> None:
        self.sampler, self.size = sampler, size
        self._cache: dict[bytes, torch.Tensor] = {}

    def grasps(self, scene: SceneState, i: int) -> torch.Tensor:
        s = self.sampler
        T = scene.poses[i].double()
        key = (
            np.round(scene.params[i].double().numpy(), 5).tobytes()
            + np.round(T[:3, :3].numpy(), 4).tobytes()
            + bytes([int(scene.kinds[i])])
        )
        local = self._cache.get(key)
        if local is None:
            obj = scene.objects()[i]
            centred = obj.pose.copy()
            centred[:3, 3] = 0.0
            from sqmanip.grasping.rule_based import rule_based_candidates

            obj0 = dataclasses.replace(obj, pose=centred)
            cand = rule_based_candidates([obj0], options=s.rule, dtype=s.dtype)
            local = cand.poses if len(cand) else torch.zeros(0, 4, 4, dtype=s.dtype)
            if len(self._cache) >= self.size:
                self._cache.clear()
            self._cache[key] = local
        if local.shape[0] == 0:
            return local
        cand = local.clone()
        cand[:, :3, 3] += T[:3, 3].to(cand.dtype)
        free = s._free(s._others(scene, i), s.after, cand)
        return cand[free]


class SearchPlanner:
    """Search-for-grasp / search-and-grasp planner; grids and caches are built per (shelf, target,
    camera) on first use and reused."""

    def __init__(
        self,
        dynamics: PushDynamics,
        grasp_generator: GripperSpec | None = None,
        config: SearchConfig | None = None,
    ) -> None:
        self.dynamics = dynamics
        self.gripper = grasp_generator or PANDA_HAND
        self.config = config or SearchConfig()
        self._models: dict[Any, tuple[PoseGrid, FGEvaluator, ActionSampler]] = {}
        self._grasp_cache: dict[int, _GraspCache] = {}
        self._corners: np.ndarray | None = None

    def models(self, shelf: ShelfSpec, target: TargetSpec, camera: PinholeCamera):
        key = (
            shelf,
            target,
            camera.width,
            camera.height,
            camera.fx,
            camera.fy,
            camera.pose.tobytes(),
        )
        if key not in self._models:
            cfg = self.config
            grid = make_pose_grid(shelf, target, cfg.resolution, cfg.n_theta)
            ex = ExistenceModel(shelf, target, grid, camera, cfg)
            gm = GraspabilityModel(shelf, target, grid, cfg, self.gripper)
            sampler = ActionSampler(shelf, cfg, self.gripper)
            self._grasp_cache[id(sampler)] = _GraspCache(sampler)
            self._models[key] = (grid, FGEvaluator(ex, gm, cfg), sampler)
        return self._models[key]

    def decide(
        self,
        objects: Sequence[Superquadric],
        target_spec: TargetSpec,
        shelf: ShelfSpec,
        camera: PinholeCamera,
        target_visible: bool,
        target_pose: np.ndarray | None = None,
        rng: np.random.Generator | int | None = None,
        prior: np.ndarray | torch.Tensor | None = None,
        reject: Callable[[Action], bool] | None = None,
    ) -> Decision:
        """One MPC step. ``prior (P,)`` is the previous ``f`` (optional; ``f <= prior``);
        ``reject`` (optional) drops first actions (e.g. ones the robot refused before).

        Sampled actions the robot cannot execute are dropped (:meth:`feasible`)."""
        if target_visible and target_pose is None:
            raise ValidationError("target_pose is required when target_visible is true")
        rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        cfg = self.config
        times: dict[str, float] = {}
        t0 = time.perf_counter()
        grid, ev, sampler = self.models(shelf, target_spec, camera)
        times["setup"] = (time.perf_counter() - t0) * 1e3
        scene = SceneState.from_objects(objects)
        prior_t = None if prior is None else torch.as_tensor(np.asarray(prior)).bool()
        t = time.perf_counter()
        root = ev.maps(scene, visible=target_visible, target_pose=target_pose, prior=prior_t)
        times["f_g"] = (time.perf_counter() - t) * 1e3
        shape = grid.shape
        f_map = root.f.reshape(shape).numpy()
        fg_map = (root.f * root.g).reshape(shape).numpy()

        if target_visible:
            i = grid.nearest(target_pose)
            if root.g[i] >= 1 and root.best_grasp[i] >= 0:
                T, _ = ev.gm.grasp_poses(torch.tensor([i]))
                pose = T[0, int(root.best_grasp[i])].double().numpy()
                times["total"] = (time.perf_counter() - t0) * 1e3
                return Decision(
                    "grasp",
                    {"grasp_pose": pose, "grid_index": i},
                    f_map,
                    fg_map,
                    root.J,
                    times,
                    reason="target visible and graspable",
                )

        t = time.perf_counter()
        keep_out = torch.cat(
            [
                grid.xy[root.f.bool()],
                torch.full((int(root.f.sum()), 1), target_spec.horizontal_radius),
            ],
            -1,
        )
        cands = sampler.candidates(scene, keep_out)
        first = sampler.sample(scene, rng, cfg.n_sequences, keep_out, cands)
        first = [a for a in first if self.feasible(a, shelf) and (reject is None or not reject(a))]
        times["sample"] = (time.perf_counter() - t) * 1e3
        if not first:
            times["total"] = (time.perf_counter() - t0) * 1e3
            return Decision("none", {}, f_map, fg_map, root.J, times, reason="no valid action")
        t = time.perf_counter()
        costs = self._rollouts(
            scene, root, first, ev, sampler, shelf, target_visible, target_pose, rng
        )
        times["rollout"] = (time.perf_counter() - t) * 1e3
        best = int(np.argmin(costs))
        a = first[best]
        times["total"] = (time.perf_counter() - t0) * 1e3
        return Decision(
            a.kind,
            _action_params(a),
            f_map,
            fg_map,
            float(costs[best]),
            times,
            action=a,
            reason=f"best of {len(first)} sequences",
        )

    def _rollouts(self, scene, root: Maps, first, ev, sampler, shelf, visible, target_pose, rng):
        cfg = self.config
        grid = ev.em.grid
        costs = np.zeros(len(first))
        self._shelf = shelf
        states = apply_actions(scene, first, self.dynamics, shelf)
        for s, s1 in enumerate(states):
            J = [root.J]
            f_prev = root.f
            state = s1
            for step in range(cfg.horizon):
                m = ev.maps(state, visible=visible, target_pose=target_pose, prior=f_prev)
                J.append(m.J)
                f_prev = m.f
                if step + 1 == cfg.horizon:
                    break
                keep_out = torch.cat(
                    [
                        grid.xy[m.f.bool()],
                        torch.full((int(m.f.sum()), 1), ev.em.target.horizontal_radius),
                    ],
                    -1,
                )
                nxt = self._one_action(state, sampler, rng, keep_out)
                if nxt is None:
                    break
                state = apply_actions(state, [nxt], self.dynamics, shelf)[0]
            costs[s] = sequence_cost(J, cfg.gamma)
        return costs

    def feasible(self, a: Action, shelf: ShelfSpec) -> bool:
        """Execution limits of the robot in the shelf that the sampler does not model: a push
        keeps the hand (palm half width ``palm_size[1] / 2`` across the push) off the side
        walls and its tool inside the shelf, a pick-and-place keeps the open gripper
        ``floor_clearance`` above the floor at the grasp and the place pose."""
        cfg = self.config
        g = self.gripper
        half_w = shelf.inner_width / 2
        if isinstance(a, Push):
            y_lim = half_w - g.palm_size[1] / 2 - 0.005
            x_lo, x_hi = shelf.front_x + 0.005, shelf.front_x + shelf.depth - 0.01
            for p in (a.start, a.start + a.displacement):
                if abs(p[1]) > y_lim or not (x_lo <= p[0] <= x_hi):
                    return False
            return True
        if self._corners is None:
            from .graspability import gripper_corners

            self._corners = gripper_corners(g).numpy()
        for T in (a.grasp_pose, a.place_pose):
            z = self._corners @ T[:3, :3].T + T[:3, 3]
            if z[:, 2].min() < shelf.bottom_z + cfg.floor_clearance:
                return False
            if abs(T[1, 3]) > half_w - 0.01:
                return False
        return True

    def _one_action(self, state, sampler: ActionSampler, rng, keep_out) -> Action | None:
        """A single action for a predicted scene: a random object and type, checked lazily."""
        cfg = self.config
        kinds = {"both": ("push", "pick"), "push": ("push",), "pick_and_place": ("pick",)}[
            cfg.actions
        ]
        for _ in range(4):
            i = int(rng.integers(len(state)))
            kind = kinds[int(rng.integers(len(kinds)))]
            if kind == "push":
                p = sampler.push_poses(state, i)
                if p:
                    direction, T, tcp = p[int(rng.integers(len(p)))]
                    d = float(cfg.push_distances[int(rng.integers(len(cfg.push_distances)))])
                    a = Push("push", i, direction, d, T, tcp, np.array([0.0, direction * d, 0.0]))
                    if self.feasible(a, self._shelf):
                        return a
            else:
                gr = self._grasp_cache[id(sampler)].grasps(state, i)
                if gr.shape[0]:
                    spots = sampler.place_spots(state, i, gr[0], keep_out)
                    if spots.shape[0]:
                        place = gr[0].double().numpy().copy()
                        place[:2, 3] += spots[int(rng.integers(spots.shape[0]))].double().numpy()
                        a = PickAndPlace("pick_and_place", i, gr[0].double().numpy(), place)
                        if self.feasible(a, self._shelf):
                            return a
        return None


def _action_params(a: Action) -> dict[str, Any]:
    if isinstance(a, Push):
        return {
            "object": a.obj,
            "direction": a.direction,
            "distance": a.distance,
            "gripper_pose": a.gripper_pose,
            "start": a.start,
            "displacement": a.displacement,
        }
    return {"object": a.obj, "grasp_pose": a.grasp_pose, "place_pose": a.place_pose}
