"""Closed-loop pushing episodes in the simulator (Ch. 4.6.3, 4.7.3, 4.7.4).

:meth:`EpisodeRunner.run` is a generator: observe -> recognize (or read the ground truth) ->
associate ids -> plan one MPC step (:class:`~sqmanip.planning.mpc.PushMPC`) -> execute the push
in the simulator -> repeat, at most ``max_steps`` pushes. It yields one :class:`StepEvent` per
step (so a gRPC ``RunEpisode`` can stream them) and *returns* the :class:`EpisodeResult`
(``StopIteration.value``; :func:`run_episode` drains the generator and returns it).

Success rules (4.6.3, judged on the simulator's ground truth, before every step and after the
last push):

- moving: the mean planar distance of the objects with a goal to their goals is < 5 cm (planar:
  goals keep the start height, a tipped object would otherwise never count);
- singulation: every pairwise planar distance of object centres is > ``tau`` (20 cm);
- interactive moving (4.7.3): the target's planar distance to its goal is < 5 cm;
- grasping: B.5.13 finds a feasible grasp of the target in the *recognized* scene (the thesis'
  criterion, reported as ``grasp_found``) AND executing it in the simulator lifts the target
  (stricter than the thesis). Up to ``grasp_attempts`` feasible candidates are tried in order;
  candidates the simulator refuses (IK, collisions) are skipped, the first executed grasp decides.

An object that falls below the table top fails the episode. ``steps`` counts executed pushes
(refused pushes count too: the step was spent). Table 4.6 averages ``steps`` over successes.

:func:`render_strip` draws an episode as a PNG strip (top view; objects before each push as
outlines, after it filled; the push as an arrow; goals as crosses) with numpy only: this venv has
neither matplotlib nor PIL, so a minimal PNG writer (zlib) is used.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import time
import zlib
from collections.abc import Generator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sqmanip.errors import PreconditionError, ValidationError

from .mpc import PlanResult, PushMPC
from .recognition import GroundTruthObjects, ObjectTracker, PerceptionObjects, object_centre
from .scenarios import Scenario
from .tasks import GraspingTask, InteractiveMovingTask, MovingTask, SingulationTask, Task

__all__ = [
    "EpisodeResult",
    "EpisodeRunner",
    "StepEvent",
    "render_strip",
    "run_episode",
    "sim_planner",
    "task_metric",
    "write_png",
]

SUCCESS_DISTANCE = 0.05
"""Moving / interactive moving: mean distance to the goals below this (m), 4.6.3."""
FELL_Z = -0.03
"""An object centre below this height (m) has fallen off the table."""


def _xyzyaw(T: np.ndarray) -> tuple[float, float, float, float]:
    T = np.asarray(T)
    return (
        float(T[0, 3]),
        float(T[1, 3]),
        float(T[2, 3]),
        float(math.atan2(T[1, 0], T[0, 0])),
    )


@dataclasses.dataclass(frozen=True)
class StepEvent:
    """One step of an episode (what ``RunEpisode`` streams)."""

    step: int
    """0-based index of the push this step executed (or tried)."""
    status: str
    """``pushed``, ``push_refused``, ``no_action``, ``grasp_lifted``, ``grasp_failed``,
    ``grasp_refused``, ``lost_object``."""
    message: str
    n_points: int
    """Points in the observation (0 for ground truth)."""
    recognized_ids: tuple[int, ...]
    """Task ids of the objects the planner saw (after association)."""
    missing_ids: tuple[int, ...]
    """Tracked ids not recognized this step."""
    action: tuple[float, ...] | None
    """(6,) ``(p, v)`` executed push, or None."""
    pushed_id: int | None
    predicted: dict[int, tuple[float, float, float, float]]
    """Task id -> predicted ``(x, y, z, yaw)`` after the push (planner's state)."""
    recognized: dict[int, tuple[float, float, float, float]]
    """Task id -> recognized ``(x, y, z, yaw)`` before the push (what the planner started from)."""
    truth_before: np.ndarray
    """(N, 4, 4) true poses of the simulator objects before the step (row = sim id)."""
    truth_after: np.ndarray
    """(N, 4, 4) true poses after it."""
    cost: float
    """Predicted terminal cost of the chosen sequence (``inf`` without one)."""
    current_cost: float
    """Task cost of the recognized state before the push."""
    metric_after: float
    """:func:`task_metric` of the true state after the step."""
    n_candidates: int
    timings_ms: dict[str, float]
    """``observe``, ``recognize``, ``sampling``, ``rollout``, ``cost``, ``grasp``, ``plan``,
    ``execute``, ``grasp_check`` (B.5.13 on the observed scene, grasping)."""

    @property
    def observed(self) -> dict[int, tuple[float, float, float, float]]:
        """Sim id -> true ``(x, y, z, yaw)`` after the step."""
        return {i: _xyzyaw(T) for i, T in enumerate(self.truth_after)}

    def to_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        d["truth_before"] = np.round(self.truth_before, 5).tolist()
        d["truth_after"] = np.round(self.truth_after, 5).tolist()
        d["predicted"] = {str(k): list(v) for k, v in self.predicted.items()}
        d["recognized"] = {str(k): list(v) for k, v in self.recognized.items()}
        d["observed"] = {str(k): list(v) for k, v in self.observed.items()}
        for k in ("cost", "current_cost", "metric_after"):
            d[k] = None if not math.isfinite(d[k]) else d[k]
        return d


@dataclasses.dataclass(frozen=True)
class EpisodeResult:
    kind: str
    index: int
    success: bool
    steps: int
    """Pushes executed (or tried)."""
    reason: str
    grasp_found: bool | None
    """Grasping only: B.5.13 found a feasible grasp (the thesis' success criterion)."""
    metric: float
    """Final :func:`task_metric`."""
    wall_s: float
    events: tuple[StepEvent, ...]

    def to_dict(self, events: bool = False) -> dict[str, Any]:
        d = {
            "kind": self.kind,
            "index": self.index,
            "success": self.success,
            "steps": self.steps,
            "reason": self.reason,
            "grasp_found": self.grasp_found,
            "metric": self.metric if math.isfinite(self.metric) else None,
            "wall_s": self.wall_s,
            "step_timings_ms": [e.timings_ms for e in self.events],
        }
        if events:
            d["events"] = [e.to_dict() for e in self.events]
        return d


def task_metric(task: Task, poses: np.ndarray) -> float:
    """What the success rule thresholds, on true poses ``(N, 4, 4)`` (rows = task ids).

    Moving: mean planar distance to the goals; interactive moving: the target's; singulation:
    the smallest pairwise planar distance; grasping: nan (decided by grasping).
    """
    xy = np.asarray(poses)[:, :2, 3]
    if isinstance(task, MovingTask):
        return float(np.mean([np.linalg.norm(xy[k] - T[:2, 3]) for k, T in task.goals.items()]))
    if isinstance(task, InteractiveMovingTask):
        return float(np.linalg.norm(xy[task.target_id] - task.goal[:2]))
    if isinstance(task, SingulationTask):
        if len(xy) < 2:
            return math.inf
        d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
        return float(d[np.triu_indices(len(xy), 1)].min())
    return math.nan


def _succeeded(task: Task, metric: float) -> bool:
    if isinstance(task, MovingTask | InteractiveMovingTask):
        return metric < SUCCESS_DISTANCE
    if isinstance(task, SingulationTask):
        return metric > task.tau
    return False


def _restrict(task: Task, ids: set[int]) -> Task | None:
    """The task on the objects the planner sees; None when a needed object is missing."""
    if isinstance(task, MovingTask):
        goals = {k: v for k, v in task.goals.items() if k in ids}
        return dataclasses.replace(task, goals=goals) if goals else None
    if isinstance(task, GraspingTask | InteractiveMovingTask):
        return task if task.target_id in ids else None
    return task


class EpisodeRunner:
    """Run scenarios in ``sim`` with ``objects`` (recognition or ground truth) and ``planner``.

    ``sim`` is a ``sqmanip.sim.Simulator`` (the "real" world); ``objects`` a
    :class:`~sqmanip.planning.recognition.PerceptionObjects` or
    :class:`~sqmanip.planning.recognition.GroundTruthObjects`; ``planner`` a :class:`PushMPC`
    whose sampler should be restricted to the simulator's push workspace and whose table should
    be the simulator's (:func:`~sqmanip.planning.scenarios.sim_table`).
    """

    def __init__(
        self,
        sim,
        objects: PerceptionObjects | GroundTruthObjects,
        planner: PushMPC,
        max_steps: int = 10,
        *,
        grasp_attempts: int = 3,
        grasp_width_margin: float = 0.02,
        gate: float = 0.10,
    ) -> None:
        if not isinstance(max_steps, int) or max_steps < 0:
            raise ValidationError(f"max_steps must be an integer >= 0, got {max_steps!r}")
        self.sim = sim
        self.objects = objects
        self.planner = planner
        self.max_steps = max_steps
        self.grasp_attempts = int(grasp_attempts)
        self.grasp_width_margin = float(grasp_width_margin)
        self.gate = float(gate)

    # -- the loop --------------------------------------------------------------------------------

    def run(
        self, scenario: Scenario, seed: int | None = None
    ) -> Generator[StepEvent, None, EpisodeResult]:
        """Yield a :class:`StepEvent` per step; return the :class:`EpisodeResult`."""
        t_start = time.perf_counter()
        rng = np.random.default_rng(scenario.scene.seed if seed is None else seed)
        sim = self.sim
        task = scenario.task
        self._task = task
        sim.reset(scenario.scene)
        tracker = ObjectTracker(
            {i: p for i, p in enumerate(scenario.initial_positions())}, gate=self.gate
        )
        events: list[StepEvent] = []
        grasping = isinstance(task, GraspingTask)
        grasp_found: bool | None = False if grasping else None
        steps = 0

        def finish(success: bool, reason: str) -> EpisodeResult:
            return EpisodeResult(
                scenario.kind,
                scenario.index,
                success,
                steps,
                reason,
                grasp_found,
                task_metric(task, self._truth()),
                time.perf_counter() - t_start,
                tuple(events),
            )

        for step in range(self.max_steps + 1):
            truth = self._truth()
            if np.any(truth[:, 2, 3] < FELL_Z):
                fell = np.flatnonzero(truth[:, 2, 3] < FELL_Z).tolist()
                return finish(False, f"object(s) {fell} fell off the table")
            metric = task_metric(task, truth)
            if not grasping and _succeeded(task, metric):
                return finish(True, f"success after {steps} push(es) (metric {metric:.3f} m)")
            if step == self.max_steps and not grasping:
                break

            seen = self.objects(sim)
            if self.objects.uses_tracker:
                objs, missing = tracker.associate(seen.objects)
            else:
                objs, missing = list(seen.objects), []
            ids = {oid for _, oid in objs}
            timings = dict(seen.timings_ms)
            recognized = {oid: _xyzyaw(parts[0].pose) for parts, oid in objs}
            sub = _restrict(task, ids)
            base = dict(
                n_points=seen.n_points,
                recognized_ids=tuple(sorted(ids)),
                missing_ids=tuple(missing),
                recognized=recognized,
                truth_before=truth,
            )
            if sub is None or not objs:
                ev = self._event(
                    step, "lost_object", "a task object was not recognized", base, timings, truth
                )
                events.append(ev)
                yield ev
                return finish(False, "a task object was not recognized")

            if grasping:
                ev, outcome = self._try_grasp(step, objs, sub, base, timings)
                if ev is not None:
                    grasp_found = True
                    events.append(ev)
                    yield ev
                    if outcome is not None:
                        return finish(outcome, ev.message)
                if step == self.max_steps:
                    break

            try:
                plan = self.planner.plan(objs, sub, rng)
            except (ValidationError, ValueError) as exc:
                # e.g. over-segmentation giving more objects than SQPD-Net's max_objects (4)
                ev = self._event(step, "no_action", f"planner: {exc}", base, timings, truth)
                events.append(ev)
                yield ev
                return finish(False, f"planner refused the task: {exc}")
            timings.update({k: float(v) for k, v in plan.timings_ms.items() if k != "total"})
            timings["plan"] = float(plan.timings_ms.get("total", 0.0))
            if plan.action is None:
                ev = self._event(
                    step, "no_action", "no admissible push", base, timings, truth, plan
                )
                events.append(ev)
                yield ev
                return finish(False, "no admissible push sequence")

            t0 = time.perf_counter()
            status, msg = "pushed", "pushed"
            try:
                sim.push(plan.action[:3], plan.action[3:])
            except (PreconditionError, ValidationError) as exc:
                status, msg = "push_refused", f"simulator refused the push: {exc}"
            timings["execute"] = 1e3 * (time.perf_counter() - t0)
            steps += 1
            predicted = {oid: plan.predicted_next[i] for i, oid in enumerate(plan.object_ids)}
            if self.objects.uses_tracker:
                expect = {}
                for parts, oid in objs:
                    # carry the recognized centre with the predicted motion of the first part
                    M = predicted[oid] @ np.linalg.inv(parts[0].pose)
                    expect[oid] = M[:3, :3] @ object_centre(parts) + M[:3, 3]
                tracker.expect(expect)
            ev = self._event(step, status, msg, base, timings, self._truth(), plan)
            events.append(ev)
            yield ev

        if grasping:
            return finish(False, f"no feasible grasp within {self.max_steps} pushes")
        return finish(False, f"not solved within {self.max_steps} pushes")

    # -- helpers ---------------------------------------------------------------------------------

    def _truth(self) -> np.ndarray:
        return np.stack([o.pose for o in self.sim.get_state().objects]).astype(np.float64)

    def _event(
        self,
        step: int,
        status: str,
        message: str,
        base: dict,
        timings: dict,
        after: np.ndarray,
        plan: PlanResult | None = None,
        action: np.ndarray | None = None,
    ) -> StepEvent:
        if plan is not None and plan.action is not None:
            action = plan.action
            predicted = {
                oid: _xyzyaw(plan.predicted_next[i]) for i, oid in enumerate(plan.object_ids)
            }
        else:
            predicted = {}
        return StepEvent(
            step=step,
            status=status,
            message=message,
            action=None if action is None else tuple(float(x) for x in action),
            pushed_id=None if plan is None else plan.pushed_id,
            predicted=predicted,
            cost=math.inf if plan is None else float(plan.cost),
            current_cost=math.nan if plan is None else float(plan.current_cost),
            metric_after=task_metric(self._task, after),
            n_candidates=0 if plan is None else int(plan.n_candidates),
            timings_ms=timings,
            truth_after=after,
            **base,
        )

    def _try_grasp(
        self, step: int, objs, task: GraspingTask, base: dict, timings: dict
    ) -> tuple[StepEvent | None, bool | None]:
        """B.5.13 on the recognized scene; if a grasp is feasible, execute it.

        Returns ``(None, None)`` when no grasp is feasible (keep pushing); otherwise the event and
        the outcome (True lifted the target, False failed; None: every feasible grasp was refused
        by the simulator, keep pushing).
        """
        from sqmanip.grasping.reachability import sim_tool_pose

        from .costs import PackedScene

        t0 = time.perf_counter()
        checker = self.planner.grasp_checker
        scene = PackedScene.from_objects(objs)
        target = scene.ids.index(task.target_id)
        feas = checker.feasible(scene, scene.poses[None], target)[0].numpy()
        timings["grasp_check"] = 1e3 * (time.perf_counter() - t0)
        if not feas.any():
            return None, None
        cands = checker.candidates(scene.parts[target])
        # the Panda IK check accepts a grasp when it or its half-turned twin is reachable: send
        # the reachable one (another reachability has no twins)
        to_sim = getattr(checker.reachability, "executable_pose", None) or sim_tool_pose
        refused: list[str] = []
        for k in centred_first(cands, np.flatnonzero(feas), object_centre(scene.parts[target]))[
            : self.grasp_attempts
        ]:
            pose = to_sim(cands.poses[k].numpy())
            if pose is None:
                refused.append(f"candidate {k} is out of the arm's reach")
                continue
            width = min(0.08, float(cands.widths[k]) + self.grasp_width_margin)
            t1 = time.perf_counter()
            try:
                res = self.sim.grasp(pose, width)
            except (PreconditionError, ValidationError) as exc:
                refused.append(str(exc))
                continue
            timings["execute"] = 1e3 * (time.perf_counter() - t1)
            held = res.after.held_object
            ok = bool(res.success) and held == task.target_id
            msg = (
                f"grasp lifted the target (candidate {k})"
                if ok
                else f"grasp executed but did not lift the target: {res.message} (held {held})"
            )
            ev = self._event(
                step,
                "grasp_lifted" if ok else "grasp_failed",
                msg,
                base,
                timings,
                self._truth(),
                action=None,
            )
            return ev, ok
        ev = self._event(
            step,
            "grasp_refused",
            f"{int(feas.sum())} feasible grasp(s), the simulator refused the tried ones: "
            + "; ".join(refused[:2]),
            base,
            timings,
            self._truth(),
        )
        return ev, None


def centred_first(cands, indices: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """``indices`` of ``cands`` ordered by how close the fingers' midpoint is to ``centre``.

    A grasp near a recognized end is the one a size error spoils: a box pushed over the table
    edge is fitted about 1 cm too long (4 cm before the floor past the edge was seen,
    ``tests/integration/planning/test_overhang_recognition.py``), and the outermost edge grasp
    then closes on its tip or on air. A centred grasp also holds with the least torque.
    """
    mid = cands.contacts[torch.as_tensor(indices, dtype=torch.long)].mean(1).numpy()
    return indices[np.argsort(np.linalg.norm(mid - centre, axis=-1), kind="stable")]


SIM_GRASP_WIDTH = 0.075
"""Widest rule-based grasp (m) the simulator's planner keeps, instead of B.5's 7 cm. PyBullet
renders the 6.7 cm tomato-soup can (the grasping-clutter target) 7.0 cm wide: its side points lie
3.45-3.55 cm from the axis, without sensor noise, and recognition adds a few mm (fitted radii
3.5-3.9 cm at the first step of the 10 clutter scenes). At 7 cm the target then often had no
candidate at all (clutter #4 never found a grasp in 10 pushes). 7.5 cm is the thesis' own limit
for the shelf (C.3) and leaves 2.5 mm per finger of the 8 cm opening; the large flat box (13 cm
across, 5 cm high) stays graspable only across its height, at the table edge (ours)."""


def sim_planner(dynamics, n_sequences: int = 100, *, reachability=None, **config) -> PushMPC:
    """A :class:`PushMPC` set up for the simulator: its table (:func:`sim_table`), pushes sampled
    inside the simulator's push workspace (``Simulator.push`` refuses others), the Panda IK with
    the table as the arm's obstacle (:func:`.scenarios.sim_reachability`) as the grasp
    reachability, and
    grasps up to :data:`SIM_GRASP_WIDTH` wide (unless ``config`` gives ``grasp``)."""
    from sqmanip.grasping.types import RuleOptions
    from sqmanip.sim.simulator import workspace_bounds

    from .config import GraspCostSpec, MPCConfig
    from .mpc import CandidateSampler
    from .scenarios import sim_reachability, sim_table

    config.setdefault("grasp", GraspCostSpec(rule=RuleOptions(max_width=SIM_GRASP_WIDTH)))
    cfg = MPCConfig(n_sequences=n_sequences, table=sim_table(), **config)
    return PushMPC(
        dynamics,
        config=cfg,
        sampler=CandidateSampler(workspace_bounds(), cfg.sampler),
        reachability=reachability or sim_reachability(),
    )


def run_episode(
    runner: EpisodeRunner, scenario: Scenario, seed: int | None = None, on_event=None
) -> EpisodeResult:
    """Drain :meth:`EpisodeRunner.run`, calling ``on_event(event)`` for each step."""
    gen = runner.run(scenario, seed)
    while True:
        try:
            ev = next(gen)
        except StopIteration as stop:
            return stop.value
        if on_event is not None:
            on_event(ev)


# --- drawing ------------------------------------------------------------------------------------

_VIEW_X = (0.10, 0.85)
_VIEW_Y = (-0.55, 0.55)
_PX_PER_M = 240.0


def write_png(path: str | Path, image: np.ndarray) -> None:
    """Write an ``(H, W, 3)`` uint8 image as an 8-bit RGB PNG (zlib, no filter)."""
    img = np.ascontiguousarray(image, dtype=np.uint8)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must have shape (H, W, 3), got {img.shape}")
    h, w, _ = img.shape
    raw = b"".join(b"\x00" + img[r].tobytes() for r in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data))
            + tag
            + data
            + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
        )

    png = (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(raw, 6))
        + chunk(b"IEND", b"")
    )
    Path(path).write_bytes(png)


class _Canvas:
    """Top view: image row = world x (far side up), column = world -y (robot's view)."""

    def __init__(self) -> None:
        self.h = int((_VIEW_X[1] - _VIEW_X[0]) * _PX_PER_M)
        self.w = int((_VIEW_Y[1] - _VIEW_Y[0]) * _PX_PER_M)
        self.img = np.full((self.h, self.w, 3), 255, np.uint8)
        rr, cc = np.mgrid[0 : self.h, 0 : self.w]
        self.world = np.stack(
            [_VIEW_X[1] - (rr + 0.5) / _PX_PER_M, _VIEW_Y[1] - (cc + 0.5) / _PX_PER_M], -1
        )

    def to_px(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float)
        return np.stack(
            [(_VIEW_X[1] - xy[..., 0]) * _PX_PER_M, (_VIEW_Y[1] - xy[..., 1]) * _PX_PER_M], -1
        )

    def fill_poly(self, poly: np.ndarray, color, outline_only: bool = False, width=0.005) -> None:
        poly = np.asarray(poly, float)
        if len(poly) < 3:
            return
        # orientation-independent inside test for a convex polygon
        e = np.roll(poly, -1, 0) - poly
        rel = self.world[:, :, None, :] - poly[None, None]
        cross = e[None, None, :, 0] * rel[..., 1] - e[None, None, :, 1] * rel[..., 0]
        sign = np.sign(
            np.sum(e[:, 0] * np.roll(e, -1, 0)[:, 1] - e[:, 1] * np.roll(e, -1, 0)[:, 0])
        )
        inside = (sign * cross >= 0).all(-1)
        if outline_only:
            inner = (sign * cross >= width * np.linalg.norm(e, axis=-1)).all(-1)
            inside &= ~inner
        self.img[inside] = color

    def line(self, a, b, color, width: float = 0.004) -> None:
        a, b = np.asarray(a, float), np.asarray(b, float)
        d = b - a
        L = max(float(np.dot(d, d)), 1e-12)
        t = np.clip(((self.world - a) @ d) / L, 0, 1)
        dist = np.linalg.norm(self.world - (a + t[..., None] * d), axis=-1)
        self.img[dist <= width / 2] = color

    def disc(self, c, r, color) -> None:
        dist = np.linalg.norm(self.world - np.asarray(c, float), axis=-1)
        self.img[dist <= r] = color

    def rect(self, lo, hi, color, outline: bool = False) -> None:
        poly = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
        self.fill_poly(poly, color, outline_only=outline)


def _footprint(spec, T: np.ndarray) -> np.ndarray:
    """Convex hull ``(V, 2)`` of the object's true shape projected on the table."""
    from scipy.spatial import ConvexHull

    if spec.kind == "box":
        h = np.asarray(spec.size) / 2
        pts = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h
    else:
        r = spec.radius if spec.kind == "cylinder" else float(max(spec.params[:2]))
        hz = spec.height / 2 if spec.kind == "cylinder" else float(spec.params[2])
        a = np.linspace(0, 2 * np.pi, 24, endpoint=False)
        ring = np.stack([r * np.cos(a), r * np.sin(a)], -1)
        pts = np.concatenate([np.c_[ring, np.full(24, -hz)], np.c_[ring, np.full(24, hz)]])
    w = pts @ T[:3, :3].T + T[:3, 3]
    xy = w[:, :2]
    hull = ConvexHull(xy)
    return xy[hull.vertices]


def _panel(
    scenario: Scenario,
    before: np.ndarray,
    after: np.ndarray | None,
    action: Sequence[float] | None,
    predicted: dict | None,
) -> np.ndarray:
    from sqmanip.sim.simulator import workspace_bounds

    from .scenarios import sim_table

    cv = _Canvas()
    t = sim_table()
    cv.rect(t.lo, t.hi, (235, 225, 205))
    wb = workspace_bounds()
    cv.rect(wb[0, :2], wb[1, :2], (150, 150, 150), outline=True)
    task = scenario.task
    goals = []
    if isinstance(task, MovingTask):
        goals = [T[:2, 3] for T in task.goals.values()]
    elif isinstance(task, InteractiveMovingTask):
        goals = [task.goal[:2]]
    for g in goals:
        cv.line(g + [-0.015, -0.015], g + [0.015, 0.015], (0, 150, 0), 0.004)
        cv.line(g + [-0.015, 0.015], g + [0.015, -0.015], (0, 150, 0), 0.004)
    specs = scenario.scene.objects
    for i, spec in enumerate(specs):
        color = tuple(int(255 * c) for c in spec.color[:3])
        if after is not None:
            cv.fill_poly(_footprint(spec, after[i]), color)
    for i, spec in enumerate(specs):
        cv.fill_poly(
            _footprint(spec, before[i]),
            (60, 60, 60) if after is not None else tuple(int(255 * c) for c in spec.color[:3]),
            outline_only=after is not None,
        )
    if isinstance(task, GraspingTask | InteractiveMovingTask):
        c = (after if after is not None else before)[task.target_id][:2, 3]
        cv.disc(c, 0.008, (255, 255, 255))
        cv.disc(c, 0.005, (200, 0, 0))
    if predicted:
        for v in predicted.values():
            cv.disc(v[:2], 0.006, (0, 0, 255))
    if action is not None:
        p0 = np.asarray(action[:2])
        p1 = p0 + np.asarray(action[3:5])
        cv.line(p0, p1, (0, 0, 0), 0.006)
        d = (p1 - p0) / max(np.linalg.norm(p1 - p0), 1e-9)
        n = np.array([-d[1], d[0]])
        cv.line(p1, p1 - 0.025 * d + 0.015 * n, (0, 0, 0), 0.006)
        cv.line(p1, p1 - 0.025 * d - 0.015 * n, (0, 0, 0), 0.006)
        cv.disc(p0, 0.008, (0, 0, 0))
    return cv.img


def render_strip(
    scenario: Scenario, result: EpisodeResult, path: str | Path, max_panels: int = 11
) -> Path:
    """PNG strip of an episode: the start, then one panel per step.

    Step panels: true footprints before the push as dark outlines, after it filled in the
    object's colour, the push as a black arrow from its start point, the planner's predicted
    object states as blue dots; goals are green crosses and a grasp target is marked red.
    """
    ev = list(result.events)
    first = ev[0].truth_before if ev else np.stack([o.pose for o in scenario.scene.objects])
    panels = [_panel(scenario, first, None, None, None)]
    for e in ev[: max_panels - 1]:
        panels.append(_panel(scenario, e.truth_before, e.truth_after, e.action, e.predicted))
    sep = np.full((panels[0].shape[0], 4, 3), 40, np.uint8)
    strip = np.concatenate([x for p in panels for x in (p, sep)][:-1], axis=1)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(path, strip)
    return path
