"""Closed-loop shelf-search episodes in the simulator (Ch. 5.3, 5.5; Table 5.1).

One episode: reset the simulator to a :class:`.scenarios.ShelfScenario`, then repeat at most
``T = max_steps`` (10) times: observe with the shelf camera (1280 x 720); the target is *visible*
when more than 100 of its pixels are in the segmentation image (5.5.1); recognize the
surrounding objects (the target's pixels removed) -- ground-truth shapes for the oracle (O-)
methods, the perception :class:`~sqmanip.perception.pipeline.Recognizer` on the point cloud for
the R- methods (``method='hybrid'``: the recognition network, as in C.1, refined by the fitter;
see :data:`RECOGNITION`); ask :meth:`SearchPlanner.decide` for the next action; execute the push
or the pick-and-place in the simulator. When the planner answers ``grasp`` (visible and
graspable) the target is grasped and lifted (``Simulator.grasp``); success means it is held. The
take-out path is the reversed 30 cm approach, whose afterimage ``g`` already checked
collision-free (C.3).

Grasp executability. ``g`` (C.3) checks the afterimage of the gripper and links 6-7 only;
the simulator also solves the IK of the pre-grasp, grasp and lift poses (from its home
configuration) and checks the whole arm against the shelf and the objects, and refused about
nine in ten grasps ``g`` accepted (the elbow, link 4, hits the shelf's floor board for grasps low
or from the side; links 5-6 hit a neighbour at the pre-grasp pose). With an in-process
simulator the runner therefore hands the planner a :class:`SimGraspCheck` -- the simulator's own
grasp plan (``Simulator.plan_grasp``: IK over its fixed seeds and the collision queries),
without moving the robot -- and ``g(x*)`` counts only the grasps that pass; the
executed grasp is one of them. The check also names the objects a refused grasp hits (each
recognized shape carries the simulator id most of its points have), and the planner's
predicted scenes count those as obstacles of that grasp until they move out of the points the
whole arm sweeps on that grasp's plan (``SimGraspCheck.swept``; an object moved into them
blocks it as well). Before, a blocker counted as gone once it moved 2 cm, and the planner
pushed a box 5 cm at a time along the arm's path (R-Search-for-Grasp, the saved seed-300/500
scenarios: 75 -> 78 of 108, no episode lost). A pick-and-place
of a surrounding object likewise uses a grasp that passes (with the objects). The planner's
grasp poses put the TCP ``GripperSpec.flange_offset`` in front of the flange, the simulator's
1.8 mm further (:func:`sqmanip.grasping.reachability.sim_tool_pose` converts). A remote
simulator (the service) has no such query: there the planner's ``g`` decides and the simulator
may refuse.

Choices (ours): the target's pose, once visible, is the simulator's ground truth (the thesis
estimates it from the segmented points; a red upright cylinder of known size); ``f`` is
recomputed from each observation and is 0 where an earlier camera image showed the target's
place in plain view (:meth:`.existence.ExistenceModel.seen_empty`, on the depth image, so
recognition error cannot rule out the true pose): the non-increasing uncertainty of 5.4.2
across real steps (:class:`TargetMemory`; once seen, the target is looked for only where it
stood when a moved object hides it again). Without it the planner kept placing an object in
front of space it had seen empty, forgot that space the next step and moved the object back
(R-Search-for-Grasp, the saved seed-300/500 scenarios: 73 -> 77 of 108). An executed push
may shove the target, so the poses its object slid over are forgotten when the slide crossed a
pose where the target may have stood (:func:`_shoved_to`). A refused action (unreachable, colliding:
``PreconditionError``) counts as a step that changed nothing, and so does an executed action
after which no object moved more than 5 mm (a push against a wall or the target): both are
banned from the next decisions (:class:`RefusedActions`: an unreachable one for the whole
episode, the others until something moves). An episode never raises for a scene
without a solution: it ends with a reason (``no valid action``, ``step limit``, ``grasp
failed``...).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from typing import Any, Literal

import numpy as np
import torch

from sqmanip.errors import PreconditionError, SQManipError, ValidationError
from sqmanip.geometry import Superquadric
from sqmanip.sim import GRIPPER_MAX_WIDTH, Observation, Simulator

from .actions import Push
from .execution import SimGraspCheck
from .mpc import Decision, SearchPlanner
from .scenarios import FOUND_PIXELS, SHELF_CAMERA, ShelfScenario, shelf_camera, shelf_spec
from .shelf import PoseGrid, SceneState

Shapes = Literal["oracle", "recognized"]

RECOGNITION = "hybrid"
"""Recognition method of the R- methods. On 12 saved 8-object shelf scenes (75 surrounding
objects the gripper's 7.5 cm could hold) the optimisation fit alone made 21 too wide to grasp
(boxes came out 1.3 cm wider on average: rounded corners and an amodal back that reaches too
far), the network refined by the fitter 9 (``python -m benchmarks.search_recognition``).
R-Search-for-Grasp at 6 and 8 objects on the saved seed-300/500/700 scenes, paired in one
session: 66 of 124 grasped against 61 (17 won, 12 lost,
``benchmarks/results/search_r_sfg_*_hybrid.json``), fewer refused actions (0.63 against 0.82
per episode), and 20 of 36 against 18 on new seed-900 scenes (7 won, 5 lost); about 0.3 s
instead of 0.1 s of recognition per step."""

NOTHING_MOVED = "no object moved 5 mm"
"""Appended to the message of an executed action that changed nothing."""


@dataclasses.dataclass
class StepEvent:
    """One step of an episode: what was seen and decided, and the executed action."""

    step: int
    """Actions executed before this observation (0 = initial scene)."""
    action: str
    """push | pick_and_place | grasp | none."""
    params: dict[str, Any]
    f_sum: float
    """``|f| = sum_x f(x)`` over the pose grid."""
    fg_sum: float
    """``|f * g|``."""
    visible: bool
    graspable: bool
    target_pixels: int
    executed: bool
    message: str
    timings_ms: dict[str, float]
    f_map: np.ndarray | None = None
    fg_map: np.ndarray | None = None
    rgb: np.ndarray | None = None


@dataclasses.dataclass
class EpisodeResult:
    found: bool
    grasped: bool
    find_steps: int | None
    """Actions executed before the target was first visible (None: never)."""
    grasp_steps: int | None
    """Actions before the successful grasp (the grasp itself not counted)."""
    steps: int
    reason: str
    events: list[StepEvent]


def _oracle_objects(obs: Observation, target_index: int) -> tuple[list[Superquadric], list[int]]:
    keep = [o for o in obs.objects if o.id != target_index and o.superquadric is not None]
    return [o.superquadric for o in keep], [o.id for o in keep]


class EpisodeRunner:
    """Runs search episodes in one simulator with one planner (see the module doc)."""

    def __init__(
        self,
        sim: Simulator,
        planner: SearchPlanner,
        *,
        shapes: Shapes = "oracle",
        recognizer=None,
        max_steps: int | None = None,
        keep_images: bool = False,
        grasp_width: float = GRIPPER_MAX_WIDTH,
        recognition: str = RECOGNITION,
    ) -> None:
        if shapes not in ("oracle", "recognized"):
            raise ValidationError(f"shapes must be 'oracle' or 'recognized', got {shapes!r}")
        self.sim, self.planner, self.shapes = sim, planner, shapes
        if shapes == "recognized" and recognizer is None:
            from sqmanip.perception.pipeline import Recognizer

            recognizer = Recognizer()
        self.recognizer = recognizer
        self.recognition = recognition
        """``RecognizeOptions.method`` of the R- methods (:data:`RECOGNITION`)."""
        self.max_steps = planner.config.max_steps if max_steps is None else int(max_steps)
        self.keep_images = keep_images
        self.grasp_width = float(grasp_width)
        self.forget_margin = 0.01
        """The pushed object is grown by this much (m) in :func:`_shoved_to`."""
        self.seen_target_radius = 0.03
        """:attr:`TargetMemory.target_radius`."""
        self.max_replans = 3
        """Refused actions re-planned per step before a refusal counts as a step."""
        self.shelf = shelf_spec(sim)
        self.camera = shelf_camera(sim)
        self.grasp_check = SimGraspCheck(sim, grasp_width) if isinstance(sim, Simulator) else None
        """Executability of the target's grasps (in-process simulator only; see the module)."""

    # --- perception ---------------------------------------------------------------------------

    def recognize(
        self, obs: Observation, target_index: int
    ) -> tuple[list[Superquadric], list[int]]:
        """Surrounding objects: ground truth (O-) or recognized from the cloud without the
        target's points (R-; instance labels from the simulator's segmentation), and for each
        the simulator's id of the object it stands for (the most common label of its points):
        the robot's grasp check names what blocks a grasp by that id."""
        if self.shapes == "oracle":
            return _oracle_objects(obs, target_index)
        from sqmanip.perception.types import RecognizeOptions, RecognizeRequest, Workspace

        s = self.shelf
        labels = obs.point_labels.astype(np.int32)
        keep = labels != target_index
        pts, lab = obs.points[keep], labels[keep]
        lab = np.where(lab >= 0, lab, -1).astype(np.int32)
        ws = Workspace(
            (s.front_x + 0.003, -s.inner_width / 2 + 0.003, s.bottom_z - 0.01),
            (s.front_x + s.depth - 0.003, s.inner_width / 2 - 0.003, s.bottom_z + s.inner_height),
        )
        req = RecognizeRequest(
            points=pts.astype(np.float32),
            labels=lab,
            viewpoint=obs.camera_pose[:3, 3].astype(np.float32),
            workspace=ws,
            options=RecognizeOptions(method=self.recognition, deformable=False, seed=0),
        )
        scene = self.recognizer.recognize(req)
        parts, ids = [], []
        for o in scene.objects:
            own = lab[np.asarray(o.point_indices, np.int64)]
            own = own[own >= 0]
            sim_id = int(np.bincount(own).argmax()) if own.size else -1
            for p in o.parts:
                parts.append(_to_floor(p, s.bottom_z))
                ids.append(sim_id)
        return parts, ids

    # --- episode ------------------------------------------------------------------------------

    def run(
        self,
        scenario: ShelfScenario,
        seed: int = 0,
        on_event: Callable[[StepEvent], None] | None = None,
    ) -> EpisodeResult:
        events: list[StepEvent] = []
        gen = self.events(scenario, seed)
        while True:
            try:
                ev = next(gen)
            except StopIteration as stop:
                result: EpisodeResult = stop.value
                result.events = events
                return result
            events.append(ev)
            if on_event is not None:
                on_event(ev)

    def events(self, scenario: ShelfScenario, seed: int = 0) -> Iterator[StepEvent]:
        """Yields a :class:`StepEvent` per step; returns the :class:`EpisodeResult`."""
        sim, planner = self.sim, self.planner
        sim.reset(scenario.scene)
        ti = scenario.target_index
        rng = np.random.default_rng(seed)
        found_step: int | None = None
        steps = 0
        replans = 0
        refused = RefusedActions()
        grid, ev, _ = planner.models(self.shelf, scenario.target, self.camera)
        memory = TargetMemory(grid, self.seen_target_radius)
        while True:
            times: dict[str, float] = {}
            t = time.perf_counter()
            obs = sim.observe("shelf", intrinsics=SHELF_CAMERA)
            n_px = int((obs.segmentation == ti).sum())
            visible = n_px > FOUND_PIXELS
            if visible and found_step is None:
                found_step = steps
            target_state = obs.objects[ti]
            memory.observe(ev.em.seen_empty(obs.depth), target_state.pose if visible else None)
            times["observe"] = (time.perf_counter() - t) * 1e3
            if target_state.pose[2, 2] < 0.9 or target_state.pose[2, 3] < self.shelf.bottom_z:
                return self._end(found_step, None, steps, "target knocked over or off the shelf")
            t = time.perf_counter()
            try:
                objects, ids = self.recognize(obs, ti)
            except SQManipError:  # nothing recognizable: plan with an empty scene
                objects, ids = [], []
            if self.grasp_check is not None:
                self.grasp_check.object_index = {sid: k for k, sid in enumerate(ids) if sid >= 0}
            times["recognize"] = (time.perf_counter() - t) * 1e3
            d = planner.decide(
                objects,
                scenario.target,
                self.shelf,
                self.camera,
                visible,
                target_pose=target_state.pose if visible else None,
                rng=rng,
                prior=None if visible else memory.prior(),
                reject=refused,
                grasp_check=self.grasp_check,
            )
            times.update({f"plan_{k}": v for k, v in d.timings_ms.items()})
            graspable = d.kind == "grasp"
            base = dict(
                step=steps,
                action=d.kind,
                params=_summary(d),
                f_sum=float(d.f_map.sum()),
                fg_sum=float(d.fg_map.sum()),
                visible=visible,
                graspable=graspable,
                target_pixels=n_px,
                f_map=d.f_map,
                fg_map=d.fg_map,
                rgb=obs.rgb if self.keep_images else None,
            )
            if graspable:
                t = time.perf_counter()
                ok, msg = self._grasp_target(d, scenario, target_state.pose)
                times["execute"] = (time.perf_counter() - t) * 1e3
                yield StepEvent(**base, executed=ok, message=msg, timings_ms=times)
                if ok:
                    return self._end(found_step, steps, steps, "target grasped and taken out")
                return self._end(found_step, None, steps, f"grasp failed: {msg}")
            if steps >= self.max_steps:
                yield StepEvent(
                    **base, executed=False, message="step limit reached", timings_ms=times
                )
                return self._end(found_step, None, steps, f"step limit ({self.max_steps}) reached")
            if d.kind == "none":
                yield StepEvent(**base, executed=False, message=d.reason, timings_ms=times)
                return self._end(found_step, None, steps, f"no solution: {d.reason}")
            t = time.perf_counter()
            ok, msg, moved = self._execute(d)
            times["execute"] = (time.perf_counter() - t) * 1e3
            if msg.startswith("refused") and replans < self.max_replans:
                # the robot did not move: ban the action and plan again, no step counted
                refused.add(d.action, msg)
                replans += 1
                yield StepEvent(**base, executed=False, message=msg, timings_ms=times)
                continue
            if not moved:
                msg += f" ({NOTHING_MOVED})"
            yield StepEvent(**base, executed=ok, message=msg, timings_ms=times)
            steps += 1
            replans = 0
            if moved and d.kind == "push":
                memory.forget(_shoved_to(ev.em, objects, d, self.forget_margin))
            if moved:
                refused.something_moved()
            else:  # refused, or nothing moved (a push against a wall or the target)
                refused.add(d.action, msg if msg.startswith("refused") else "")

    def _end(self, found_step, grasp_step, steps, reason) -> EpisodeResult:
        return EpisodeResult(
            found=found_step is not None,
            grasped=grasp_step is not None,
            find_steps=found_step,
            grasp_steps=grasp_step,
            steps=steps,
            reason=reason,
            events=[],
        )

    def _execute(self, d: Decision) -> tuple[bool, str, bool]:
        """``(success, message, moved)``: ``moved`` is False when no object moved 5 mm."""
        from sqmanip.grasping.reachability import sim_tool_pose

        p = d.params
        try:
            if d.kind == "push":
                r = self.sim.push(
                    np.asarray(p["start"]), np.asarray(p["displacement"]), p.get("upright", False)
                )
            else:
                r = self.sim.pick_and_place(
                    sim_tool_pose(np.asarray(p["grasp_pose"])),
                    self.grasp_width,
                    sim_tool_pose(np.asarray(p["place_pose"])),
                )
                if self.sim.get_state().held_object is not None:
                    self.sim.release()
        except (PreconditionError, ValidationError) as exc:
            return False, f"refused: {exc}", False
        moved = any(
            float(np.linalg.norm(np.asarray(a.position) - np.asarray(b.position))) > 0.005
            for a, b in zip(r.before.objects, r.after.objects, strict=False)
        )
        return bool(r.success), r.message, moved

    def _grasp_target(
        self, d: Decision, scenario: ShelfScenario, target_pose: np.ndarray
    ) -> tuple[bool, str]:
        """Grasp the target with the planner's best grasp, then the other candidates of its
        pose, highest first, until the simulator accepts one: it checks reachability and
        collisions of the whole robot with the shelf and the objects itself (its hand and arm are
        bulkier than the planner's gripper and links 6-7, and its approach is 10 cm, not 30)."""
        from sqmanip.grasping.reachability import sim_tool_pose

        _, ev, _ = self.planner.models(self.shelf, scenario.target, self.camera)
        i = int(d.params["grid_index"])
        T, valid = self.planner.target_grasps(ev, i, target_pose)
        keep = d.params.get("executable")  # the grasps SimGraspCheck passed, if it ran
        ks = [k for k in range(len(T)) if valid[k] and (keep is None or k in keep)]
        # the grasps belong to the nearest grid pose: move them onto the observed target
        shift = np.zeros(3)
        shift[:2] = target_pose[:2, 3] - ev.em.grid.xy[i].double().numpy()
        best = np.asarray(d.params["grasp_pose"], np.float64).copy()
        best[:3, 3] += shift
        # highest first: the hand then keeps farthest from the floor board (the best stays first)
        poses = [best] + sorted((T[k] for k in ks), key=lambda p: -p[2, 3])
        last = "no grasp candidate"
        for pose in poses[:21]:
            try:
                r = self.sim.grasp(sim_tool_pose(pose), self.grasp_width)
            except (PreconditionError, ValidationError) as exc:
                last = f"refused ({len(poses[:21])} grasps tried; last: {exc})"
                continue
            return bool(r.success), r.message
        return False, last


def _to_floor(part: Superquadric, floor_z: float) -> Superquadric:
    """Objects stand on the shelf floor (Ch. 5: no stacking): a recognized shape whose bottom
    floats above the floor (only its top was seen over an occluder) is extended down to it along
    its most vertical axis (when that axis is within 25 deg of vertical)."""
    T = np.asarray(part.pose, np.float64)
    a = np.abs(np.asarray(part.size, np.float64))
    col = np.abs(T[2, :3])
    gap = T[2, 3] - float(col @ a) - floor_z
    j = int(np.argmax(col))
    if gap <= 0.005 or col[j] < 0.9 or part.kind != "superellipsoid":
        return part
    size = a.copy()
    size[j] += gap / 2 / col[j]
    pose = T.copy()
    pose[2, 3] -= gap / 2
    return dataclasses.replace(part, size=tuple(float(v) for v in size), pose=pose)


def _shoved_to(em, objects: list[Superquadric], d: Decision, margin: float) -> torch.Tensor:
    """``(P,)``: after the executed push ``d``, grid poses no longer to be remembered as seen
    empty, because the push may have shoved the target there: where the target would meet the
    pushed object (grown by ``margin``) at some point of its slide, when that slide passes a
    pose where the target may have stood (``f = 1`` at the decision). A slide through poses
    seen empty met no target and forgets nothing. Before, every pose within 10 cm of the
    pusher's path was forgotten: the object pushed aside then hid poses the planner counted
    as seen, and it pushed and carried the same object back and forth for all 10 steps while
    the target stayed hidden (scenario seed 8713; ours). R-Search-for-Grasp, paired in one
    session: 70 of 124 saved seed-300/500/700 scenes grasped against 66 (7 won, 3 lost; 8
    objects 33 of 62 against 29, ``benchmarks/results/search_r_sfg_*_shove.json``), 19 of 36
    new seed-900 scenes against 20 (none won, 1 lost)."""
    i = int(d.params["object"])
    one = SceneState.from_objects([objects[i]])
    one.params[:, :3] = one.params[:, :3].abs() + margin
    v = torch.as_tensor(np.asarray(d.params["displacement"], np.float64)[:2], dtype=one.poses.dtype)
    swept = torch.zeros(len(em.grid), dtype=torch.bool)
    for t in torch.linspace(0.0, 1.0, max(2, int(float(v.norm()) / 0.01) + 1)):
        at = one.poses.clone()
        at[:, :2, 3] += t * v
        swept |= em.object_collisions(SceneState(one.params, at, one.kinds), 0)
    f = torch.as_tensor(np.asarray(d.f_map).reshape(-1) > 0)
    return swept if bool((swept & f).any()) else torch.zeros_like(swept)


class TargetMemory:
    """The grid poses known not to hold the target, from the camera images so far: each
    step's ``f`` is at most :meth:`prior` (the non-increasing uncertainty of 5.4.2 across real
    steps).

    Only images rule poses out. The rollouts' ``f_{t+1} = f_t f(s_{t+1})`` (5.4.5) also keep
    out where a recognized object stood (``f_c = 0``) after it moved; remembering that here
    too (the target stands still, so it was never there) gave 75 grasped against 77 of the 124
    saved seed-300/500/700 scenes (``benchmarks/results/search_r_sfg_6_8_*_occupied.json``)."""

    def __init__(self, grid: PoseGrid, target_radius: float) -> None:
        self.grid = grid
        self.target_radius = float(target_radius)
        """Once seen, the target is looked for within this distance (m) of where it stood."""
        self.empty = torch.zeros(len(grid), dtype=torch.bool)

    def observe(self, seen_empty: torch.Tensor, target_pose: np.ndarray | None = None) -> None:
        """Adds the poses an image showed empty. A seen target (``target_pose``) stands still
        (Ch. 5), so every pose farther than :attr:`target_radius` from it is empty too: when a
        moved object hides it again, the search looks for it only there. Before, it looked
        everywhere not yet seen empty (scenario seed 8734: ``|f|`` went from 1 to 66 after a
        push hid the seen target, and the episode ended with no valid action at step 4).
        R-Search-for-Grasp on the 124 saved seed-300/500/700 scenes, paired in one session: 77
        grasped against 76 (1 won, none lost; ``benchmarks/results/*_memory.json`` against
        ``*_passed.json``)."""
        self.empty |= seen_empty.bool()
        if target_pose is not None:
            at = torch.as_tensor(np.asarray(target_pose)[:2, 3], dtype=self.grid.xy.dtype)
            self.empty |= (self.grid.xy - at).norm(dim=-1) > self.target_radius

    def forget(self, poses: torch.Tensor) -> None:
        """The target may stand at ``poses`` again (an executed push may have shoved it)."""
        self.empty &= ~poses.bool()

    def prior(self) -> torch.Tensor | None:
        """``(P,)`` bool: where the target may still stand; None before anything is known."""
        return ~self.empty if bool(self.empty.any()) else None


class RefusedActions:
    """Actions the robot refused, or after which nothing moved, kept out of the next decisions.

    A push is known by its direction and start, a pick-and-place by its grasp (when the grasp
    part was refused) or its grasp and place spot; a new action matches a kept one within
    :attr:`tolerance` (the recognized pose, and with it the action, shifts a few mm from one
    observation to the next). A kinematic refusal (unreachable, a joint flip or limit) depends
    on where the hand must go only and is kept for the whole episode; a collision, or a push
    that moved nothing, may clear when something moves (:meth:`something_moved`). Before, each
    refusal was forgotten after any executed action and matched only to the centimetre, and
    the planner asked for the same unreachable push in 6 of 10 steps (scenario seed 4508)."""

    tolerance = 0.015
    """Largest distance (m) between the points of two actions taken as the same."""

    def __init__(self) -> None:
        self._kept: list[tuple[str, int, np.ndarray, bool]] = []  # kind, direction, points, lasts

    def __bool__(self) -> bool:
        return bool(self._kept)

    @staticmethod
    def _points(a, kind: str) -> np.ndarray:
        if kind == "push":
            return np.asarray(a.start, np.float64)[:3]
        grasp = np.asarray(a.grasp_pose, np.float64)[:3, 3]
        if kind == "pick":
            return grasp
        return np.concatenate([grasp, np.asarray(a.place_pose, np.float64)[:2, 3]])

    def add(self, a, message: str) -> None:
        """Keep ``a``; ``message`` is the robot's refusal ("" when the action moved nothing)."""
        if isinstance(a, Push):
            kind, direction = "push", int(a.direction)
        else:
            kind = "pick" if ("grasp" in message or "lift" in message) else "place"
            direction = 0
        lasts = bool(message) and "collides" not in message
        self._kept.append((kind, direction, self._points(a, kind), lasts))

    def __call__(self, a) -> bool:
        """Whether ``a`` matches a kept action."""
        for kind, direction, pts, _ in self._kept:
            if (kind == "push") != isinstance(a, Push) or (
                kind == "push" and a.direction != direction
            ):
                continue
            if np.abs(self._points(a, kind) - pts).max() <= self.tolerance:
                return True
        return False

    def something_moved(self) -> None:
        """Forget the refusals a moved object may have cleared (keep the kinematic ones)."""
        self._kept = [k for k in self._kept if k[3]]


def _summary(d: Decision) -> dict[str, Any]:
    out: dict[str, Any] = {"objective": float(d.objective), "reason": d.reason}
    for k, v in d.params.items():
        out[k] = v.tolist() if isinstance(v, np.ndarray) else v
    return out
