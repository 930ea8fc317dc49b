"""Sampling MPC for search-for-grasp / search-and-grasp (5.3, 5.4.3, 5.4.4, Table 5.1, 5.6.2).

One :meth:`SearchPlanner.decide` is one MPC iteration: estimate ``f_0``, ``g_0`` from the current
recognized scene, stop with a grasp when the target is visible and graspable, else sample
``n_sequences`` (30) action sequences of horizon ``M = 3``, roll each out with the scene dynamics
and the ``f``/``g`` dynamics (5.4.5), score it by (5.4.6) and return the first action of the best.
The episode loop (observe, act, at most ``T = 10`` times) belongs to the runner.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable, Sequence
from typing import Any, Literal, Protocol

import numpy as np
import torch

from sqmanip.errors import ValidationError
from sqmanip.geometry import PinholeCamera, Superquadric
from sqmanip.grasping import PANDA_HAND, GripperSpec

from .actions import (
    Action,
    ActionSampler,
    GraspSource,
    PickAndPlace,
    Push,
    PushDynamics,
    apply_actions,
)
from .config import SearchConfig
from .existence import ExistenceModel
from .graspability import GraspabilityModel
from .objective import FGEvaluator, Maps, sequence_cost
from .shelf import Obstacles, PoseGrid, SceneState, ShelfSpec, TargetSpec, make_pose_grid


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


class GraspCheck(Protocol):
    """Whether the robot can execute grasps of the target: ``(K, 4, 4)`` world grasp poses ->
    ``(K,)`` bool. ``objects=False`` asks about the arm, the shelf and the robot's own IK only
    (what no rearrangement can change); ``objects=True`` also about the objects now on the
    shelf. :class:`sqmanip.search.execution.SimGraspCheck` answers with the simulator's own IK
    and collision checks. Optional attribute ``last_blockers``: per pose of the last
    ``objects=True`` call, the planner's indices of the objects a refused grasp hit (-1: one
    the planner does not know); :meth:`SearchPlanner.decide` then counts them as obstacles of
    that grasp in a predicted scene until they move. Optional method ``swept(poses) -> list of
    (S, 3)``: the points the whole arm passes through on each grasp's plan (see
    :meth:`sqmanip.search.execution.SimGraspCheck.swept`); a moved object of a predicted scene
    that enters them blocks that grasp, unless it entered them already where it stands and the
    robot's plan did not name it (:func:`_unblocked`)."""

    def __call__(self, poses: np.ndarray, objects: bool) -> np.ndarray: ...


class SearchPlanner:
    """Search-for-grasp / search-and-grasp planner; grids and caches are built per (shelf, target,
    camera) on first use and reused."""

    def __init__(
        self,
        dynamics: PushDynamics,
        grasp_generator: GripperSpec | None = None,
        config: SearchConfig | None = None,
        grasp_planner=None,
    ) -> None:
        """``grasp_planner``: where the C.3 grasp candidates of the target and the objects come
        from (:class:`.actions.GraspSource`): ``None`` in-process, or a
        :class:`sqmanip.grasping.GraspPlanner`-like object such as the grasp service's client."""
        self.dynamics = dynamics
        self.gripper = grasp_generator or PANDA_HAND
        self.config = config or SearchConfig()
        self.grasp_source = GraspSource(grasp_planner)
        self._models: dict[Any, tuple[PoseGrid, FGEvaluator, ActionSampler]] = {}
        self._corners: np.ndarray | None = None
        self._last_resort: dict[Any, list[ActionSampler]] = {}

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
            gm = GraspabilityModel(shelf, target, grid, cfg, self.gripper, self.grasp_source)
            sampler = self._action_sampler(shelf, target, cfg)
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
        grasp_check: GraspCheck | None = None,
    ) -> Decision:
        """One MPC step. ``prior (P,)`` is the previous ``f`` (optional; ``f <= prior``);
        ``reject`` (optional) drops actions (e.g. ones the robot refused before), first and later.

        Sampled actions the robot cannot execute are dropped (:meth:`feasible`).

        ``grasp_check`` (optional): the robot's own IK and arm checks of a grasp. A pick of a
        surrounding object uses only a grasp it accepts (with the objects). Once the target is
        visible at ``x*``, ``g(x*)`` counts only the C.3 candidates the robot can execute. The
        afterimage of the gripper and links 6-7 (C.3) misses the rest of the arm and the IK:
        the check with ``objects=True`` filters the candidates for the current scene and, when
        it passes one, decides to grasp now even where the afterimage of the recognized shapes
        (inflated, and only an estimate behind what was seen) is blocked; the one with
        ``objects=False`` filters those of the predicted scenes (the arm-shelf part does not
        move), where the objects a refused grasp hit (the check's ``last_blockers``) count as
        obstacles of it until they moved 2 cm, or, when the check has ``swept``, as long as
        their predicted shape still enters the points the arm sweeps on that grasp's plan; an
        object moved into those points blocks it too (:func:`_unblocked`).
        When no candidate passes even without objects, no rearrangement can make the target
        graspable and the decision is ``none``.

        Pushes whose hand or slide may touch where the target may stand are sampled only when
        nothing else is valid (first those whose hand alone passes there, then, when there is
        none, those whose pushed object slides there: a slide through the hidden target shoved
        it against a wall, out of every grasp, seed 2500), or when the target is seen and no
        sequence of the others makes it graspable in a predicted scene: a blocker beside the
        target may be movable only so, or when it is hidden and no sequence of the others
        gains anything (:attr:`SearchConfig.escalate_when_stuck`) (ours). A seen target is
        never in the way of a pushed object: only the hand may pass by it. When even those
        leave no valid action, which ends the episode, the decision tries the last resort of
        :attr:`SearchConfig.last_resort_tolerances` first."""
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
        allowed_now = allowed_later = None
        blockers: dict[int, frozenset[int]] = {}
        arm_sweep: SweptArm | None = None
        if target_visible and grasp_check is not None:
            t = time.perf_counter()
            i = grid.nearest(target_pose)
            poses, valid = self.target_grasps(ev, i, target_pose)
            ok_arm = valid.copy()
            if valid.any():
                ok_arm[valid] = np.asarray(grasp_check(poses[valid], False), dtype=bool)
            ok_now = ok_arm.copy()
            if ok_arm.any():
                ok_now[ok_arm] = np.asarray(grasp_check(poses[ok_arm], True), dtype=bool)
                named = getattr(grasp_check, "last_blockers", None)
                if named is not None and len(named) == int(ok_arm.sum()):
                    blockers = dict(zip(np.flatnonzero(ok_arm).tolist(), named, strict=True))
                if hasattr(grasp_check, "swept") and not ok_now.any():
                    arm = np.flatnonzero(ok_arm)
                    arm_sweep = SweptArm.pack(arm, grasp_check.swept(poses[arm]))
            allowed_now = (i, torch.from_numpy(ok_now))
            allowed_later = (i, torch.from_numpy(ok_arm))
            times["grasp_check"] = (time.perf_counter() - t) * 1e3
        t = time.perf_counter()
        root = ev.maps(
            scene,
            visible=target_visible,
            target_pose=target_pose,
            prior=prior_t,
            allowed=allowed_now,
        )
        times["f_g"] = (time.perf_counter() - t) * 1e3
        shape = grid.shape
        f_map = root.f.reshape(shape).numpy()
        fg_map = (root.f * root.g).reshape(shape).numpy()

        if target_visible:
            i = grid.nearest(target_pose)
            k = int(root.best_grasp[i]) if root.g[i] >= 1 else -1
            if k < 0 and allowed_now is not None and bool(allowed_now[1].any()):
                # the robot's own plan, against the objects as they stand, passes a grasp the
                # afterimage of the recognized (and inflated) shapes rules out: trust the robot
                k = int(allowed_now[1].nonzero()[0])
            if k >= 0:
                T, _ = ev.gm.grasp_poses(torch.tensor([i]))
                pose = T[0, k].double().numpy()
                params: dict[str, Any] = {"grasp_pose": pose, "grid_index": i}
                if allowed_now is not None:
                    params["executable"] = allowed_now[1].nonzero().squeeze(-1).tolist()
                times["total"] = (time.perf_counter() - t0) * 1e3
                return Decision(
                    "grasp",
                    params,
                    f_map,
                    fg_map,
                    root.J,
                    times,
                    reason="target visible and graspable",
                )
            if allowed_later is not None and not bool(allowed_later[1].any()):
                times["total"] = (time.perf_counter() - t0) * 1e3
                return Decision(
                    "none",
                    {},
                    f_map,
                    fg_map,
                    root.J,
                    times,
                    reason="target visible, but the arm can execute none of its grasps in the "
                    "shelf (IK or arm-shelf collision), whatever the objects",
                )

        t = time.perf_counter()
        keep_out = self._keep_out(
            grid.xy, root.f, target_spec, target_pose if target_visible else None
        )
        pick_ok = None
        if grasp_check is not None:
            checked: dict[bytes, bool] = {}

            def pick_ok(T: torch.Tensor) -> bool:
                key = T.double().numpy().tobytes()
                if key not in checked:
                    checked[key] = bool(grasp_check(T.double().numpy()[None], True)[0])
                return checked[key]

        # the hand may graze a seen target, never sweep across its middle third: an escalated
        # push whose hand came in through its axis knocked it over (scenario seed 10500)
        seen_target = None
        if target_visible:
            seen_target = keep_out.clone()
            seen_target[:, 2] = target_spec.horizontal_radius / 3

        def sample(hand: bool, slide: bool, picks_ok=pick_ok, smp=sampler) -> list[Action]:
            # draw until n_sequences pass the robot's limits and the refusals (5.4.4 samples
            # from valid actions): dropping the rest after one draw left as few as 4 sequences
            cands = smp.candidates(scene, keep_out, hand, picks_ok, slide, seen_target)
            out: list[Action] = []
            for _ in range(SAMPLE_ROUNDS):
                drawn = smp.sample(scene, rng, cfg.n_sequences, keep_out, cands)
                out += [a for a in drawn if self.allowed(a, shelf, reject)]
                if not drawn or len(out) >= cfg.n_sequences:
                    break
            return out[: cfg.n_sequences]

        # pushes that may sweep where the target may stand come only when nothing else is
        # left (the hand first, the pushed object's slide last), priced by that risk
        # (risk_weight); picks and places always keep out of it. A seen target is never in the
        # pushed object's way: it would be shoved along, and the push model (which moves the
        # pushed object only) cannot tell where to
        def valid_first(smp: ActionSampler, picks_ok) -> tuple[list[Action], bool]:
            first = sample(True, True, picks_ok, smp)
            if first or not keep_out.numel():
                return first, False
            first = sample(False, True, picks_ok, smp)
            if not first and not target_visible:
                first = sample(False, False, picks_ok, smp)
            return first, True

        first, swept = valid_first(sampler, pick_ok)
        last_resort = not first
        if last_resort:
            # the last resort before "no valid action" ends the episode: picks from the first
            # grasp that clears the floor (not just the first grasp, see ActionSampler.pick),
            # then looser clearances (SearchConfig.last_resort_tolerances)
            def high_pick_ok(T: torch.Tensor) -> bool:
                return self.clears_floor(T, shelf) and (pick_ok is None or pick_ok(T))

            for smp in [sampler, *self.last_resort_samplers(shelf, target_spec)]:
                first, _ = valid_first(smp, high_pick_ok)
                if first:
                    swept = True
                    break
        times["sample"] = (time.perf_counter() - t) * 1e3
        if not first:
            times["total"] = (time.perf_counter() - t0) * 1e3
            return Decision("none", {}, f_map, fg_map, root.J, times, reason="no valid action")
        t = time.perf_counter()
        later = allowed_later
        if allowed_later is not None and (blockers or arm_sweep is not None):
            later = functools.partial(_unblocked, allowed_later, blockers, scene, arm_sweep)
        start = root
        if allowed_later is not None:
            # J_0 judged as the predicted scenes are (the grasps the arm can execute, with the
            # objects its plan hit). From the root's J (only the grasps executable now: none)
            # every sequence, doing nothing included, reported the same gain of ~9 while a
            # bystander was pushed 5 times (scenario seed 8306). The offset is common to all
            # sequences, so the ranking is unchanged; the reported objective is now the gain
            now = later(scene) if callable(later) else later
            J0 = ev.maps(scene, visible=True, target_pose=target_pose, prior=root.f, allowed=now).J
            start = dataclasses.replace(root, J=J0)

        def rollouts(actions):
            return self._rollouts(
                scene,
                start,
                actions,
                ev,
                sampler,
                shelf,
                target_visible,
                target_pose,
                rng,
                later,
                reject,
            )

        costs, grasps = rollouts(first)
        stuck = False
        if not swept and keep_out.numel():
            # the target is seen and no sequence that keeps off it makes it graspable, or it is
            # hidden and none gains anything (SearchConfig.escalate_when_stuck): the pushes
            # that may sweep where it stands compete too, the hand's way first
            if target_visible:
                stuck, slides = not grasps.any(), (True,)
            else:
                stuck, slides = cfg.escalate_when_stuck and costs.min() >= -GAIN_EPS, (True, False)
            for slide in slides if stuck else ():
                more = sample(False, slide)
                if more:
                    c, _ = rollouts(more)
                    first, costs = first + more, np.concatenate([costs, c])
                    if c.min() < -GAIN_EPS:
                        break
        times["rollout"] = (time.perf_counter() - t) * 1e3
        risk = np.array(
            [sampler.push_risk(scene, a, keep_out) if isinstance(a, Push) else 0.0 for a in first]
        )
        costs = costs + cfg.risk_weight * risk * max(root.J, 1.0)
        best = int(np.argmin(costs))
        a = first[best]
        params = _action_params(a)
        if isinstance(a, Push):
            params["target_risk"] = float(risk[best])
        times["total"] = (time.perf_counter() - t0) * 1e3
        return Decision(
            a.kind,
            params,
            f_map,
            fg_map,
            float(costs[best]),
            times,
            action=a,
            reason=f"best of {len(first)} sequences"
            + (f" ({LAST_RESORT})" if last_resort else "")
            + (f" ({STUCK})" if stuck and not target_visible else ""),
        )

    def _action_sampler(
        self, shelf: ShelfSpec, target: TargetSpec, config: SearchConfig
    ) -> ActionSampler:
        return ActionSampler(
            shelf,
            config,
            self.gripper,
            grasp_source=self.grasp_source,
            target_height=2 * target.size[2],
        )

    def last_resort_samplers(self, shelf: ShelfSpec, target: TargetSpec) -> list[ActionSampler]:
        """Action samplers with the looser clearances of
        :attr:`SearchConfig.last_resort_tolerances`."""
        key = (shelf, target)
        if key not in self._last_resort:
            cfg = self.config
            self._last_resort[key] = [
                self._action_sampler(
                    shelf,
                    target,
                    dataclasses.replace(
                        cfg, action_tolerance=tol, push_gap=cfg.last_resort_push_gap
                    ),
                )
                for tol in cfg.last_resort_tolerances
            ]
        return self._last_resort[key]

    def target_grasps(
        self, ev: FGEvaluator, i: int, target_pose: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """World poses ``(K, 4, 4)`` of the C.3 candidates of grid pose ``i`` moved onto the
        observed ``target_pose`` (the grid pose is its nearest, within half a cell), and their
        validity ``(K,)`` (float64 numpy)."""
        T, valid = ev.gm.grasp_poses(torch.tensor([i]))
        poses = T[0].double().numpy().copy()
        shift = np.asarray(target_pose, np.float64)[:2, 3] - ev.em.grid.xy[i].double().numpy()
        poses[:, :2, 3] += shift
        return poses, valid[0].numpy().copy()

    def _rollouts(
        self,
        scene,
        root: Maps,
        first,
        ev,
        sampler,
        shelf,
        visible,
        target_pose,
        rng,
        allowed=None,
        reject=None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Cost (5.4.6) of each sequence starting with ``first[s]``, and whether ``f * g`` is
        non-zero anywhere in one of its predicted scenes (a graspable pose where the target
        may stand). ``reject`` drops later actions too: an object that has not moved in the
        prediction offers the robot's refused action again, and a sequence that counted on
        it (push another object, then the unreachable push) won every step (seed 6300)."""
        cfg = self.config
        grid = ev.em.grid
        costs = np.zeros(len(first))
        grasps = np.zeros(len(first), dtype=bool)
        self._shelf = shelf
        states = apply_actions(scene, first, self.dynamics, shelf)
        for s, s1 in enumerate(states):
            J = [root.J]
            f_prev = root.f
            state = s1
            for step in range(cfg.horizon):
                ok = allowed(state) if callable(allowed) else allowed
                m = ev.maps(
                    state, visible=visible, target_pose=target_pose, prior=f_prev, allowed=ok
                )
                J.append(m.J)
                grasps[s] |= bool((m.f * m.g).any())
                f_prev = m.f
                if step + 1 == cfg.horizon:
                    break
                keep_out = self._keep_out(
                    grid.xy, m.f, ev.em.target, target_pose if visible else None
                )
                nxt = self._one_action(state, sampler, rng, keep_out, reject)
                if nxt is None:
                    break
                state = apply_actions(state, [nxt], self.dynamics, shelf)[0]
            costs[s] = sequence_cost(J, cfg.gamma)
        return costs, grasps

    def _keep_out(
        self, xy: torch.Tensor, f: torch.Tensor, target: TargetSpec, seen_at=None
    ) -> torch.Tensor:
        """``(Q, 3)`` discs ``(x, y, r)`` where the target may stand (``f = 1``), widened by
        ``keep_out_margin``; a seen target's (``seen_at``, its pose) is one disc where it
        stands, not at its nearest grid pose (up to 1.4 cm off)."""
        r = target.horizontal_radius + self.config.keep_out_margin
        if seen_at is not None:
            c = torch.as_tensor(np.asarray(seen_at, np.float64)[:2, 3], dtype=xy.dtype)
            return torch.cat([c, torch.tensor([r], dtype=xy.dtype)])[None]
        on = f.bool()
        return torch.cat([xy[on], torch.full((int(on.sum()), 1), r, dtype=xy.dtype)], -1)

    def feasible(self, a: Action, shelf: ShelfSpec) -> bool:
        """Execution limits of the robot in the shelf that the sampler does not model: a push
        keeps the hand (palm half width ``palm_size[1] / 2`` across the push) off the side
        walls and its tool inside the shelf, a pick-and-place keeps the open gripper
        ``floor_clearance`` above the floor at the grasp and the place pose."""
        g = self.gripper
        half_w = shelf.inner_width / 2
        if isinstance(a, Push):
            y_lim = half_w - g.palm_size[1] / 2 - 0.005
            # an upright hand may start nearer a side board (its thickness across the push and
            # the wrist's clearance, UPRIGHT_WALL_GAP), but ends no nearer than the level one
            # could: it gets objects out of tight spots, it does not push them deeper in
            y_start = half_w - g.palm_size[0] / 2 - UPRIGHT_WALL_GAP if a.upright else y_lim
            x_lo, x_hi = shelf.front_x + 0.005, shelf.front_x + shelf.depth - 0.01
            for p, lim in ((a.start, y_start), (a.start + a.displacement, y_lim)):
                if abs(p[1]) > lim or not (x_lo <= p[0] <= x_hi):
                    return False
            return True
        for T in (a.grasp_pose, a.place_pose):
            if not self.clears_floor(T, shelf) or abs(T[1, 3]) > half_w - 0.01:
                return False
        return True

    def clears_floor(self, T: np.ndarray | torch.Tensor, shelf: ShelfSpec) -> bool:
        """The open gripper at ``T (4, 4)`` stays ``floor_clearance`` above the floor."""
        if self._corners is None:
            from .graspability import gripper_corners

            self._corners = gripper_corners(self.gripper).numpy()
        T = T.double().numpy() if isinstance(T, torch.Tensor) else np.asarray(T, np.float64)
        z = self._corners @ T[:3, :3].T + T[:3, 3]
        return bool(z[:, 2].min() >= shelf.bottom_z + self.config.floor_clearance)

    def allowed(self, a: Action, shelf: ShelfSpec, reject=None) -> bool:
        """``a`` is :meth:`feasible` and ``reject`` (optional) does not drop it."""
        return self.feasible(a, shelf) and (reject is None or not reject(a))

    def _one_action(
        self, state, sampler: ActionSampler, rng, keep_out, reject=None
    ) -> Action | None:
        """A single action for a predicted scene: a random object and type, checked lazily
        (up to 8 draws: with 4, rollouts ended early more often; 75 -> 78 of 108, paired).

        Its picks are not asked of the robot (first actions are: ``pick_ok`` in
        :meth:`decide`), so a sequence may count on a pick the robot refuses: scenario seed
        6709 nudged an object that blocked the arm's path to another 6 times, each nudge
        predicted to free that pick. Asking it (a refused pick passing once the objects the
        robot named left the points its arm sweeps) grasped 34 of 60 fresh scenes against 33
        (``benchmarks/results/search_r_sfg_6_8_seed1100_30x_pickcheck.json``); together with
        taking a sequence's first gaining action at once when the actions before it change
        nothing, 51 against 58 of the first 88 saved seed-300/500/700 episodes. Neither is
        kept."""
        cfg = self.config
        kinds = {"both": ("push", "pick"), "push": ("push",), "pick_and_place": ("pick",)}[
            cfg.actions
        ]
        for _ in range(8):
            i = int(rng.integers(len(state)))
            kind = kinds[int(rng.integers(len(kinds)))]
            if kind == "push":
                p = sampler.push_poses(state, i, keep_out)
                if p:
                    direction, T, tcp = p[int(rng.integers(len(p)))]
                    ds = sampler.push_distances(state, i, direction, keep_out)
                    if not ds:
                        continue
                    a = Push.sideways(i, direction, ds[int(rng.integers(len(ds)))], T, tcp)
                    if self.allowed(a, self._shelf, reject):
                        return a
            else:
                pick = sampler.pick(state, i, keep_out)
                if pick is not None:
                    a = PickAndPlace.to_random_spot(i, *pick, rng)
                    if self.allowed(a, self._shelf, reject):
                        return a
        return None


LAST_RESORT = "last resort"
"""Marks the reason of a decision whose action came from the last resort of
:attr:`SearchConfig.last_resort_tolerances`."""

STUCK = "nothing safe gained"
"""Marks the reason of a decision for a hidden target that also sampled the pushes that may
sweep where it stands (:attr:`SearchConfig.escalate_when_stuck`)."""

UPRIGHT_WALL_GAP = 0.02
"""An upright push starts with the hand's side this far (m) from a side board at least: the
simulator refused most upright pushes whose object stood 8.5 or 9 cm from the board (the wrist
meets it on the way in) and executed them from 9.5 cm (``Simulator.push``, boxes and a
cylinder 0.6 to 0.78 m deep) (ours). Since the simulator tries more IK seeds for a push it
executes them from 9 cm too (``benchmarks.shelf_pushes``); this gap was not tuned again."""

GAIN_EPS = 1e-6
"""A sequence cost (5.4.6) below ``-GAIN_EPS`` is a predicted gain."""

SAMPLE_ROUNDS = 8
"""At most this many draws of ``n_sequences`` first actions per decision (ours)."""

MOVED = 0.02
"""An object counts as moved in a predicted scene when its centre moved at least this far (m);
one that did not keeps blocking the grasps it blocks now (ours)."""

SWEPT_MARGIN = 0.01
"""Objects are grown by this much (m) against the arm's swept points: the points are 1 cm
apart, and the recognized shapes a few mm off."""


@dataclasses.dataclass
class SweptArm:
    """The points ``(S, 3)`` the whole arm sweeps on the robot's plan of each executable target
    grasp, and the grasp (candidate index) ``owner (S,)`` each belongs to."""

    points: torch.Tensor
    owner: torch.Tensor
    _now: torch.Tensor | None = dataclasses.field(default=None, repr=False)

    @classmethod
    def pack(cls, candidates: np.ndarray, points: Sequence[np.ndarray]) -> SweptArm:
        owner = np.concatenate(
            [np.full(len(p), k) for k, p in zip(candidates, points, strict=True)]
        )
        pts = np.concatenate([np.asarray(p, np.float64).reshape(-1, 3) for p in points])
        return cls(torch.as_tensor(pts, dtype=torch.float32), torch.as_tensor(owner).long())

    def hits_now(self, scene: SceneState, which: torch.Tensor, n: int) -> torch.Tensor:
        """:meth:`hits` of the objects ``which`` of the current ``scene`` (the one this sweep was
        packed for: it does not change within a decision), computed once for all its objects
        instead of again for every predicted scene of the rollouts."""
        if self._now is None:
            self._now = self.hits(scene, torch.arange(len(scene)), n)
        return self._now[which]

    def hits(self, state: SceneState, which: torch.Tensor, n: int) -> torch.Tensor:
        """``(len(which), n)``: whether object ``which[m]`` of ``state`` (grown by
        :data:`SWEPT_MARGIN`) enters the swept points of candidate ``k``."""
        from sqmanip.geometry.superquadric import implicit_homogeneous

        out = torch.zeros(len(which), n, dtype=torch.bool)
        if not len(which) or not len(self.points):
            return out
        params = state.params[which].clone()
        params[:, :3] = params[:, :3].abs() + SWEPT_MARGIN
        obs = Obstacles.from_tensors(params, state.poses[which], state.kinds[which])
        pts = self.points.to(params.dtype)
        for m in range(len(obs)):
            local = pts @ obs.inv[m, :3, :3].T + obs.inv[m, :3, 3]
            near = (local.abs() <= obs.half[m]).all(-1).nonzero().squeeze(-1)
            if not len(near):
                continue
            x = local[near].unsqueeze(-2)
            s = implicit_homogeneous(x, obs.params[m].expand(len(near), -1), int(obs.kinds[m]))
            out[m, torch.unique(self.owner[near[s.squeeze(-1) <= 1.0]])] = True
        return out


def _unblocked(
    allowed: tuple[int, torch.Tensor],
    blockers: dict[int, frozenset[int]],
    scene: SceneState,
    swept: SweptArm | None,
    state: SceneState,
) -> tuple[int, torch.Tensor, torch.Tensor]:
    """``allowed`` with, per candidate, the obstacles the robot's plan meets in the predicted
    ``state`` beside those the afterimage of the gripper and links 6-7 hits (for ``g_c,m``):
    the objects its plan was refused on now that have not moved ``MOVED`` (an object the
    planner does not know, -1, never moves), and, with ``swept``, every moved object whose
    predicted shape enters the points the arm sweeps on that plan, unless it entered them
    already where it stands now and the robot's plan did not name it (the grown, recognized
    shape against 1 cm points is on the safe side; what the plan passed is no blocker). Without
    that exception every push that left a bystander inside the swept points counted it as a
    new obstacle: once the target was seen, every sampled sequence raised ``J`` (by 1 to 3)
    and the planner could not tell a freeing push from the others (scenario seed 8701).
    R-Search-for-Grasp on the 124 saved seed-300/500/700 scenes, paired in one session: 76
    grasped either way (1 won, 1 lost), target knocked over 2 against 3
    (``benchmarks/results/search_r_sfg_6_8_*_passed.json`` against ``*_shove_rerun.json``).
    Without ``swept`` a blocker counts as gone once it moved ``MOVED``, and the planner kept
    pushing a box 5 cm at a time along the arm's path, each push predicted to free the grasp
    (scenario seed 2506)."""
    i, ok = allowed
    n = len(ok)
    extra = torch.zeros(n, dtype=torch.long)
    moved = (state.poses[:, :2, 3] - scene.poses[:, :2, 3]).norm(dim=-1) >= MOVED
    for k, objs in blockers.items():
        extra[k] = sum(1 for b in objs if b < 0 or b >= len(moved) or not bool(moved[b]))
    if swept is not None:
        which = moved.nonzero().squeeze(-1)
        named = torch.zeros(len(which), n, dtype=torch.bool)
        for k, objs in blockers.items():
            for m, b in enumerate(which.tolist()):
                named[m, k] = b in objs
        before = swept.hits_now(scene, which, n)
        extra += (swept.hits(state, which, n) & (named | ~before)).sum(0)
    return i, ok, extra


def _action_params(a: Action) -> dict[str, Any]:
    if isinstance(a, Push):
        return {
            "object": a.obj,
            "direction": a.direction,
            "distance": a.distance,
            "gripper_pose": a.gripper_pose,
            "start": a.start,
            "displacement": a.displacement,
            "upright": a.upright,
        }
    return {"object": a.obj, "grasp_pose": a.grasp_pose, "place_pose": a.place_pose}
