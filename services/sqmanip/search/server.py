"""gRPC Search server: the shelf-search orchestrator (Ch. 5) as a service.

``python -m sqmanip.search.server [--host H] [--port P]`` (default ``settings.search_port``).

- ``Evaluate`` computes the existence ``f`` (C.2) and graspability ``g``, ``g_c,m`` (C.3) maps of
  one scene over the target pose grid, in-process (:class:`~sqmanip.search.SearchPlanner`'s
  models, cached per shelf, target, camera and grid). Nothing else is called, so it answers
  without the other services.
- ``RunEpisode`` runs :class:`~sqmanip.search.episode.EpisodeRunner` against the Simulator
  service and, for ``shapes = "recognized"``, the Perception service; push dynamics are
  ``"kinematic"`` (in-process rigid slide, the default while no SQPD-Net checkpoint ships) or a
  model of the Dynamics service (SQPD-Net lowered to the shelf floor,
  :class:`~sqmanip.search.actions.SQPDNetDynamics`). The C.3 rule-based grasp candidates of
  the target and of the objects come from the GraspPlanner service (``method = rule_based``,
  the object alone, no reachability check; one call per object shape and orientation, reused by
  translation, :class:`~sqmanip.search.actions.GraspSource`); the search's own afterimage checks
  (C.3) stay in-process. Before the episode each needed service must answer its health
  check (concurrently) within ``SQMANIP_SEARCH_PROBE_TIMEOUT_S`` (2 s), else the call ends UNAVAILABLE naming
  it. Every remote call has a deadline (the smaller of ``call_timeout_s`` and the incoming
  call's remaining time); idempotent calls (observe, state, recognize, predict) are retried at
  most ``retries`` times on UNAVAILABLE with a short back-off; actions (push, grasp,
  pick-and-place, reset) are never retried. Events are streamed and published on Zenoh
  ``sqmanip/search/episode``; the last event carries the result. The simulator is one shared
  world, so one episode runs at a time (a second one is RESOURCE_EXHAUSTED).
"""

from __future__ import annotations

import json
import logging
import sys
import time
from typing import Any

import grpc
import numpy as np
from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from sqmanip.errors import (
    DeadlineExceededError,
    PreconditionError,
    UnavailableError,
    ValidationError,
)
from sqmanip.planning.server import (
    Lane,
    deadline_of,
    stream_generator,
)
from sqmanip.rpc import convert
from sqmanip.rpc.client import (
    RemoteDynamics,
    RemoteGraspPlanner,
    RemoteRecognizer,
    RemoteSimulator,
)
from sqmanip.rpc.server import configure_logging, run_service, service_parser
from sqmanip.settings import StackSettings, get_settings
from sqmanip.streams import Publisher
from sqmanip.v1 import search_pb2, search_pb2_grpc

log = logging.getLogger("sqmanip.search.server")

EPISODE_KEY = "sqmanip/search/episode"
_IDEMPOTENT = frozenset({"observe", "get_state", "recognize", "predict", "plan_grasps"})


class SearchServiceSettings(BaseSettings):
    """Settings of the search service (env prefix ``SQMANIP_SEARCH_``)."""

    model_config = SettingsConfigDict(env_prefix="SQMANIP_SEARCH_", extra="ignore")

    probe_timeout_s: float = Field(2.0, gt=0)
    call_timeout_s: float = Field(60.0, gt=0)
    retries: int = Field(2, ge=0, le=5)
    """Extra attempts of an idempotent call answered UNAVAILABLE."""
    retry_backoff_s: float = Field(0.25, ge=0)
    max_queue: int = Field(2, ge=0)
    """``Evaluate`` calls that may wait; more are RESOURCE_EXHAUSTED."""
    max_cached_planners: int = Field(8, ge=1)


class Deadline:
    """Per-call timeouts from an absolute deadline (``time.monotonic()``) and a cap."""

    def __init__(self, deadline: float | None, cap: float) -> None:
        self.deadline, self.cap = deadline, cap

    def timeout(self, what: str) -> float:
        if self.deadline is None:
            return self.cap
        left = self.deadline - time.monotonic()
        if left <= 0.05:
            raise DeadlineExceededError(f"{what}: the episode's deadline has passed")
        return min(self.cap, left)


def call_with_retries(fn, name: str, deadline: Deadline, retries: int, backoff: float):
    """``fn(timeout)``; idempotent ``name``s are retried on UNAVAILABLE (bounded)."""
    attempts = 1 + (retries if name in _IDEMPOTENT else 0)
    for attempt in range(attempts):
        try:
            return fn(deadline.timeout(name))
        except UnavailableError:
            if attempt + 1 >= attempts:
                raise
            log.warning("%s unavailable, retry %d/%d", name, attempt + 1, attempts - 1)
            time.sleep(backoff * (2**attempt))
    raise AssertionError("unreachable")  # pragma: no cover


class ShelfSim:
    """A :class:`RemoteSimulator` with what the search code reads from an in-process
    ``Simulator``: ``config`` (the service's default :class:`SimConfig`, whose shelf the
    scenarios use) and ``camera_pose(name)`` for the fixed cameras; every call has a deadline,
    idempotent ones are retried."""

    def __init__(self, remote: RemoteSimulator, deadline: Deadline, retries: int, backoff: float):
        from sqmanip.sim.config import SimConfig

        self.remote, self.deadline = remote, deadline
        self.retries, self.backoff = retries, backoff
        self.config = SimConfig()

    def camera_pose(self, camera: str) -> np.ndarray:
        from sqmanip.sim import Simulator

        if camera in ("shelf", "overview"):
            return Simulator.camera_pose(self, camera)  # fixed cameras depend on config only
        from sqmanip.sim import Intrinsics

        tiny = Intrinsics(8, 8, 8.0, 8.0, 3.5, 3.5, 0.05, 3.0)
        return self.observe(camera, intrinsics=tiny, noise=False).camera_pose

    def _call(self, name: str, *args: Any, **kwargs: Any):
        def once(timeout: float):
            self.remote.timeout = timeout
            return getattr(self.remote, name)(*args, **kwargs)

        return call_with_retries(once, name, self.deadline, self.retries, self.backoff)

    def reset(self, *args, **kwargs):
        return self._call("reset", *args, **kwargs)

    def observe(self, *args, **kwargs):
        return self._call("observe", *args, **kwargs)

    def push(self, *args, **kwargs):
        return self._call("push", *args, **kwargs)

    def grasp(self, *args, **kwargs):
        return self._call("grasp", *args, **kwargs)

    def pick_and_place(self, *args, **kwargs):
        return self._call("pick_and_place", *args, **kwargs)

    def release(self, *args, **kwargs):
        return self._call("release", *args, **kwargs)

    def get_state(self):
        return self._call("get_state")


class _Recognizer:
    def __init__(self, remote: RemoteRecognizer, deadline: Deadline, retries: int, backoff: float):
        self.remote, self.deadline, self.retries, self.backoff = remote, deadline, retries, backoff

    def recognize(self, request):
        return call_with_retries(
            lambda t: self.remote.recognize(request, timeout=t),
            "recognize", self.deadline, self.retries, self.backoff,
        )  # fmt: skip


class _Dynamics:
    """``predict`` through the Dynamics service with deadlines and retries."""

    def __init__(self, remote: RemoteDynamics, model: str, deadline: Deadline, retries, backoff):
        self.remote, self.model, self.deadline = remote, model, deadline
        self.retries, self.backoff = retries, backoff

    def predict(self, poses, params, actions, kinds=None):
        return call_with_retries(
            lambda t: self.remote.predict(poses, params, actions, kinds, model=self.model,
                                          timeout=t),
            "predict", self.deadline, self.retries, self.backoff,
        )  # fmt: skip


class _GraspPlanner:
    """``plan`` through the GraspPlanner service with deadlines and retries, geometry only (the
    search wants the candidates; the robot's feasibility is the simulator's to judge)."""

    def __init__(self, remote: RemoteGraspPlanner, deadline: Deadline, retries, backoff):
        self.remote, self.deadline = remote, deadline
        self.retries, self.backoff = retries, backoff

    def plan(self, target, obstacles=(), environment=None, gripper=None, options=None):
        return call_with_retries(
            lambda t: self.remote.plan(target, obstacles, environment, gripper, options,
                                       check_reachability=False, timeout=t),
            "plan_grasps", self.deadline, self.retries, self.backoff,
        )  # fmt: skip


class SearchServicer(search_pb2_grpc.SearchServicer):
    """``Evaluate`` and ``RunEpisode`` (see the module docstring)."""

    def __init__(
        self, settings: StackSettings | None = None, service: SearchServiceSettings | None = None
    ) -> None:
        self.settings = settings or get_settings()
        self.service = service or SearchServiceSettings()
        self._planners: dict[tuple, Any] = {}
        self._eval_lane = Lane("evaluate", self.service.max_queue)
        self._episode_lane = Lane("episode", 0)
        self.publisher = Publisher(EPISODE_KEY)

    # -- Evaluate ----------------------------------------------------------------------------------

    def _planner_for(self, resolution: float, n_theta: int):
        from .actions import KinematicPushDynamics
        from .config import SearchConfig
        from .mpc import SearchPlanner

        key = (round(resolution, 6), n_theta)
        planner = self._planners.get(key)
        if planner is None:
            if len(self._planners) >= self.service.max_cached_planners:
                self._planners.clear()
            cfg = SearchConfig(resolution=resolution, n_theta=n_theta)
            planner = self._planners[key] = SearchPlanner(KinematicPushDynamics(), None, cfg)
        return planner

    def _evaluate(self, args: convert.EvaluateArgs) -> convert.EvaluateResult:
        from .shelf import SceneState

        t0 = time.perf_counter()
        planner = self._planner_for(args.resolution, args.n_theta)
        grid, ev, _ = planner.models(args.shelf, args.target, args.camera)
        t1 = time.perf_counter()
        scene = SceneState.from_objects(args.objects)
        maps = ev.maps(scene, visible=args.target_visible, target_pose=args.target_pose,
                       prior=None)  # fmt: skip
        t2 = time.perf_counter()
        return convert.EvaluateResult(
            shape=tuple(int(s) for s in grid.shape),
            f=maps.f.reshape(grid.shape).numpy(),
            g=maps.g.reshape(grid.shape).numpy(),
            g_m=maps.g_m.reshape(grid.shape).numpy(),
            grid_xy=grid.xy.reshape(-1, 2).numpy(),
            resolution=float(grid.resolution),
            objective=float(maps.J),
            timings_ms={
                "setup": 1e3 * (t1 - t0),
                "f_g": 1e3 * (t2 - t1),
                "total": 1e3 * (t2 - t0),
            },  # fmt: skip
        )

    async def Evaluate(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        args = convert.evaluate_request_from_proto(request)
        result = await self._eval_lane.run(self._evaluate, args, what="search evaluate busy")
        return convert.evaluate_response_to_proto(result)

    # -- RunEpisode ----------------------------------------------------------------------------------

    def _episode(self, args: convert.SearchEpisodeArgs, deadline: float | None):
        from .actions import KinematicPushDynamics, SQPDNetDynamics
        from .config import SearchConfig
        from .episode import EpisodeRunner
        from .mpc import SearchPlanner
        from .scenarios import ScenarioBuilder, ShelfScenario, shelf_spec

        s, svc = self.settings, self.service
        t_start = time.perf_counter()
        dl = Deadline(deadline, svc.call_timeout_s)
        retry = (svc.retries, svc.retry_backoff_s)
        clients: list[Any] = []
        try:
            remote = RemoteSimulator(s.address("sim"), s)
            clients.append(remote)
            sim = ShelfSim(remote, dl, *retry)
            rg = RemoteGraspPlanner(s.address("grasp"), s)
            clients.append(rg)
            grasps = _GraspPlanner(rg, dl, *retry)
            kw: dict[str, Any] = {"method": args.method, "actions": args.actions,
                                  "seed": args.plan_seed}  # fmt: skip
            if args.max_steps is not None:
                kw["max_steps"] = args.max_steps
            if args.num_sequences is not None:
                kw["n_sequences"] = args.num_sequences
            cfg = SearchConfig(**kw)
            if args.scenario is not None:
                try:
                    scenario = ShelfScenario.from_dict(args.scenario)
                except (KeyError, TypeError, ValueError) as exc:
                    raise ValidationError(f"scenario_json: {exc}") from None
            else:
                scenario = ScenarioBuilder(sim, cfg, grasp_planner=grasps).make(
                    args.n_objects, args.seed
                )
                if scenario is None:
                    raise PreconditionError(
                        f"seed: no valid scenario with {args.n_objects} objects for seed "
                        f"{args.seed} (the target cannot be hidden and graspable, 5.5.1); "
                        "try another seed"
                    )
            if args.dynamics_model == "kinematic":
                dynamics: Any = KinematicPushDynamics()
            else:
                rd = RemoteDynamics(s.address("dynamics"), s)
                clients.append(rd)
                dyn = _Dynamics(rd, args.dynamics_model, dl, *retry)
                dynamics = SQPDNetDynamics(dyn, shelf_spec(sim).floor_z)
            recognizer = None
            if args.shapes == "recognized":
                rr = RemoteRecognizer(s.address("perception"), s)
                clients.append(rr)
                recognizer = _Recognizer(rr, dl, *retry)
            planner = SearchPlanner(dynamics, None, cfg, grasp_planner=grasps)
            runner = EpisodeRunner(sim, planner, shapes=args.shapes, recognizer=recognizer,
                                   max_steps=args.max_steps)  # fmt: skip
            result = yield from runner.events(scenario, args.plan_seed)
            return result, time.perf_counter() - t_start, json.dumps(scenario.to_dict())
        finally:
            for c in clients:
                c.close()

    def _event(self, ev) -> search_pb2.SearchEvent:
        msg = convert.search_event_to_proto(ev)
        self.publisher.publish(msg)
        return msg

    def _result(self, value) -> search_pb2.SearchEvent:
        result, wall_s, scenario_json = value
        msg = convert.search_result_to_proto(result, wall_s=wall_s, scenario_json=scenario_json)
        self.publisher.publish(msg)
        return msg

    async def RunEpisode(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        from sqmanip.errors import SQManipError
        from sqmanip.rpc.errors import status_for

        try:
            args = convert.search_episode_request_from_proto(request)
        except SQManipError as exc:
            code, message = status_for(exc)
            await context.abort(code, message)
        deadline = deadline_of(context)
        s = self.settings
        deps = [("sim", s.address("sim")), ("grasp", s.address("grasp"))]
        if args.shapes == "recognized":
            deps.append(("perception", s.address("perception")))
        if args.dynamics_model != "kinematic":
            deps.append(("dynamics", s.address("dynamics")))
        async for msg in stream_generator(
            self._episode_lane,
            lambda: self._episode(args, deadline),
            self._event,
            self._result,
            context,
            what="a search episode is already running",
            deps=deps,
            probe_timeout=self.service.probe_timeout_s,
        ):
            yield msg

    def close(self) -> None:
        for lane in (self._eval_lane, self._episode_lane):
            lane.pool.shutdown(wait=False, cancel_futures=True)


def registrar(servicer: SearchServicer):
    """``Register`` callback for :func:`sqmanip.rpc.server.start_server`."""

    def register(server: grpc.aio.Server) -> list[str]:
        search_pb2_grpc.add_SearchServicer_to_server(servicer, server)
        return [search_pb2.DESCRIPTOR.services_by_name["Search"].full_name]

    return register


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("search", "sqmanip.search.server", __doc__)
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    import torch

    torch.set_num_threads(1)
    settings = get_settings()
    servicer = SearchServicer(settings)

    return run_service(
        servicer,
        registrar(servicer),
        settings,
        name="search",
        host=args.host,
        port=args.port,
        publisher=servicer.publisher,
    )


if __name__ == "__main__":
    sys.exit(main())
