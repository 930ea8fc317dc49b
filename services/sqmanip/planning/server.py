"""gRPC Planner server: one pushing-MPC step (``Plan``) and closed-loop episodes (``RunEpisode``).

``python -m sqmanip.planning.server [--host H] [--port P]`` (default ``settings.mpc_port``).

- ``Plan`` decodes the objects, the task and the options, and runs one
  :meth:`~sqmanip.planning.mpc.PushMPC.plan` step (B.4) on a worker thread. The dynamics model is
  the Dynamics service (:class:`~sqmanip.rpc.client.RemoteDynamics`, model named by
  ``options.dynamics_model``), every call with the *remaining time of the incoming call* as its
  deadline, so a slow or missing dynamics service ends the call with DEADLINE_EXCEEDED or
  UNAVAILABLE instead of outliving it. Grasp feasibility (grasping task) runs in-process with
  the Panda IK (:class:`~sqmanip.grasping.reachability.PandaIKReachability`). The table, the
  push workspace and the reachability are the simulator's (:func:`.episode.sim_planner`), so a
  plan from ``/recognize`` output of the simulator's camera can be executed there.
- ``RunEpisode`` runs :class:`~sqmanip.planning.episode.EpisodeRunner` against the Simulator
  service (:class:`~sqmanip.rpc.client.RemoteSimulator`) and, for ``objects = "recognition"``,
  the Perception service; every step event is streamed and published on Zenoh
  ``sqmanip/mpc/episode``; the last event carries the result. The simulator is one shared world,
  so one episode runs at a time (a second one is RESOURCE_EXHAUSTED). A dependency that is not
  SERVING is UNAVAILABLE within ``SQMANIP_MPC_PROBE_TIMEOUT_S`` (2 s).

The physics model (PyBullet re-simulation, 100 pushes of 4 objects in 8-20 s) takes at most
``SQMANIP_MPC_PHYSICS_MAX_SEQUENCES`` (100) sequences per step (the Dynamics service's limit).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import sys
import threading
import time
from collections.abc import AsyncIterator, Callable, Iterator
from typing import Any

import grpc
from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from sqmanip.errors import (
    DeadlineExceededError,
    ResourceExhaustedError,
    SQManipError,
    UnavailableError,
    ValidationError,
)
from sqmanip.rpc import convert
from sqmanip.rpc.client import RemoteDynamics, RemoteRecognizer, RemoteSimulator
from sqmanip.rpc.errors import status_for
from sqmanip.rpc.server import configure_logging, run_service, service_parser
from sqmanip.settings import StackSettings, get_settings
from sqmanip.streams import Publisher
from sqmanip.v1 import planner_pb2, planner_pb2_grpc

log = logging.getLogger("sqmanip.planning.server")

EPISODE_KEY = "sqmanip/mpc/episode"


class PlannerServiceSettings(BaseSettings):
    """Settings of the planner service (env prefix ``SQMANIP_MPC_``)."""

    model_config = SettingsConfigDict(env_prefix="SQMANIP_MPC_", extra="ignore")

    physics_max_sequences: int = Field(100, ge=1)
    """Most sequences per step with the ``physics`` model (the Dynamics service's limit)."""
    max_queue: int = Field(4, ge=0)
    """``Plan`` calls that may wait for the planning thread; more are RESOURCE_EXHAUSTED."""
    probe_timeout_s: float = Field(2.0, gt=0)
    """Health probe of a dependency before an episode starts (s)."""
    episode_call_timeout_s: float = Field(60.0, gt=0)
    """Deadline of each simulator / perception / dynamics call inside an episode (s)."""


# --- shared server helpers (also used by sqmanip.search.server) ----------------------------------


class DeadlineDynamics:
    """``predict`` and ``predict_batch`` of a :class:`RemoteDynamics` bounded by an absolute
    deadline: each call gets the time left (``time.monotonic()`` based), at most ``cap``
    seconds; none left is DEADLINE_EXCEEDED before anything is sent."""

    def __init__(
        self, remote: RemoteDynamics, model: str, deadline: float | None, cap: float = 30.0
    ) -> None:
        self.remote, self.model, self.deadline, self.cap = remote, model, deadline, cap
        self.calls = 0

    def timeout(self) -> float:
        if self.deadline is None:
            return self.cap
        left = self.deadline - time.monotonic()
        if left <= 0.05:
            raise DeadlineExceededError("dynamics: the call's deadline passed during planning")
        return min(self.cap, left)

    def predict(self, poses, params, actions, kinds=None):
        self.calls += 1
        return self.remote.predict(
            poses, params, actions, kinds, model=self.model, timeout=self.timeout()
        )

    def predict_batch(self, poses, params, actions, kinds=None):
        """K different scenes in one call (``RemoteDynamics.predict_batch``): a horizon step
        of the MPC is one round trip, not one per sequence."""
        self.calls += 1
        return self.remote.predict_batch(
            poses, params, actions, kinds, model=self.model, timeout=self.timeout()
        )


def deadline_of(context: grpc.aio.ServicerContext) -> float | None:
    """The incoming call's deadline on the ``time.monotonic()`` clock (None: no deadline)."""
    left = context.time_remaining()
    return None if left is None else time.monotonic() + float(left)


class Lane:
    """One worker thread with a bounded number of waiting calls."""

    def __init__(self, name: str, max_queue: int) -> None:
        self.pool = concurrent.futures.ThreadPoolExecutor(1, name)
        self.name, self.max_pending, self.pending = name, 1 + max_queue, 0

    def acquire(self, what: str) -> None:
        if self.pending >= self.max_pending:
            raise ResourceExhaustedError(f"{what}: {self.pending} {self.name} call(s) in progress")
        self.pending += 1

    def release(self) -> None:
        self.pending -= 1

    async def run(self, fn: Callable[..., Any], *args: Any, what: str = "busy") -> Any:
        self.acquire(what)
        try:
            return await asyncio.get_running_loop().run_in_executor(self.pool, fn, *args)
        finally:
            self.release()


async def preflight(deps: list[tuple[str, str]], timeout: float) -> None:
    """UNAVAILABLE (naming the service and address) unless every ``(name, address)`` answers
    its health check SERVING within ``timeout`` seconds (checked concurrently)."""
    from sqmanip.rpc.health_probe import check_async

    statuses = await asyncio.gather(*(check_async(a, timeout=timeout) for _, a in deps))
    for (name, address), status in zip(deps, statuses, strict=True):
        if status != "SERVING":
            raise UnavailableError(f"{name} service unavailable at {address}: {status}")


async def stream_generator(
    lane: Lane,
    start: Callable[[], Iterator[Any]],
    on_event: Callable[[Any], Any],
    on_result: Callable[[Any], Any],
    context: grpc.aio.ServicerContext,
    *,
    what: str,
    deps: list[tuple[str, str]] = (),
    probe_timeout: float = 2.0,
) -> AsyncIterator[Any]:
    """Run a domain generator (``yield`` events, ``return`` a result) on ``lane``'s thread and
    yield ``on_event(event)`` / ``on_result(result)`` messages as they come.

    Before anything runs, the lane must be free (else RESOURCE_EXHAUSTED) and every dependency
    in ``deps`` SERVING (else UNAVAILABLE); then the initial metadata is sent, so a client that
    awaits it knows the episode started. Streaming handlers bypass the error-mapping
    interceptor, so domain errors are mapped here (:func:`sqmanip.rpc.errors.status_for`). A
    cancelled call stops the generator at its next step."""
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[tuple[str, Any]] = asyncio.Queue()
    stop = threading.Event()

    def put(kind: str, value: Any) -> None:
        loop.call_soon_threadsafe(queue.put_nowait, (kind, value))

    def work() -> None:
        try:
            gen = start()
            while not stop.is_set():
                try:
                    ev = next(gen)
                except StopIteration as done:
                    put("result", on_result(done.value))
                    return
                put("event", on_event(ev))
            gen.close()
        except BaseException as exc:  # noqa: BLE001 - handed to the event loop
            put("error", exc)
        finally:
            put("end", None)

    try:
        lane.acquire(what)
    except SQManipError as exc:
        code, message = status_for(exc)
        await context.abort(code, message)
    try:
        try:
            await preflight(list(deps), probe_timeout)
        except SQManipError as exc:
            code, message = status_for(exc)
            await context.abort(code, message)
        await context.send_initial_metadata((("x-episode", "started"),))
        loop.run_in_executor(lane.pool, work)
        while True:
            kind, value = await queue.get()
            if kind == "end":
                break
            if kind == "error":
                code, message = status_for(value)
                if code is grpc.StatusCode.INTERNAL:
                    log.error("%s failed", what, exc_info=value)
                await context.abort(code, message)
            yield value
    finally:
        stop.set()
        lane.release()


# --- the servicer ---------------------------------------------------------------------------------


class PlannerServicer(planner_pb2_grpc.PlannerServicer):
    """``Plan`` and ``RunEpisode`` (see the module docstring)."""

    def __init__(
        self,
        settings: StackSettings | None = None,
        service: PlannerServiceSettings | None = None,
        *,
        reachability=None,
    ) -> None:
        self.settings = settings or get_settings()
        self.service = service or PlannerServiceSettings()
        self._reachability = reachability
        self._dynamics: RemoteDynamics | None = None
        self._plan_lane = Lane("plan", self.service.max_queue)
        self._episode_lane = Lane("episode", 0)
        self.publisher = Publisher(EPISODE_KEY)

    @property
    def reachability(self):
        if self._reachability is None:
            from .scenarios import sim_reachability

            self._reachability = sim_reachability()
        return self._reachability

    def dynamics_client(self) -> RemoteDynamics:
        if self._dynamics is None:
            self._dynamics = RemoteDynamics(self.settings.address("dynamics"), self.settings)
        return self._dynamics

    def _check_physics(self, options: convert.MPCArgs) -> int | None:
        k = options.num_sequences
        limit = self.service.physics_max_sequences
        if options.dynamics_model == "physics":
            if k is None:
                raise ValidationError(
                    f"options.num_sequences: required with the physics model (at most {limit}; "
                    "it re-simulates every push, 100 in 8-20 s)"
                )
            if k > limit:
                raise ValidationError(
                    f"options.num_sequences: the physics model takes at most {limit}, got {k}"
                )
        return k

    def planner(self, dynamics, options: convert.MPCArgs):
        from .episode import sim_planner

        k = self._check_physics(options)
        # the physics model re-simulates every push: it scores K draws, never every push
        every = {"score_every_single_push": ()} if options.dynamics_model == "physics" else {}
        return sim_planner(
            dynamics, k or 100, reachability=self.reachability, horizon=options.horizon, **every
        )

    def _plan(self, args: convert.PlanArgs, deadline: float | None):
        dyn = DeadlineDynamics(self.dynamics_client(), args.options.dynamics_model, deadline)
        mpc = self.planner(dyn, args.options)
        return mpc.plan(args.objects, args.task, args.options.seed)

    async def Plan(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        args = convert.plan_request_from_proto(request)
        self._check_physics(args.options)
        deadline = deadline_of(context)
        result = await self._plan_lane.run(self._plan, args, deadline, what="planner busy")
        return convert.plan_response_to_proto(result, args.options.dynamics_model)

    # -- episodes ----------------------------------------------------------------------------------

    def _episode(self, args: convert.EpisodeArgs, deadline: float | None):
        from .episode import EpisodeRunner
        from .recognition import GroundTruthObjects, PerceptionObjects
        from .scenarios import make_scenario, sim_table

        s, cap = self.settings, self.service.episode_call_timeout_s
        scenario = make_scenario(args.kind, args.index, args.seed)
        sim = RemoteSimulator(s.address("sim"), s, timeout=cap)
        recognizer = None
        try:
            if args.objects == "recognition":
                recognizer = RemoteRecognizer(s.address("perception"), s)
                objects = PerceptionObjects(_TimedRecognizer(recognizer, cap), table=sim_table())
            else:
                objects = GroundTruthObjects()
            dyn = DeadlineDynamics(self.dynamics_client(), args.options.dynamics_model, deadline,
                                   cap)  # fmt: skip
            runner = EpisodeRunner(sim, objects, self.planner(dyn, args.options), args.max_steps)
            result = yield from runner.run(scenario, args.options.seed)
            return result
        finally:
            sim.close()
            if recognizer is not None:
                recognizer.close()

    def _event(self, ev) -> planner_pb2.EpisodeEvent:
        msg = convert.episode_event_to_proto(ev)
        self.publisher.publish(msg)
        return msg

    def _result(self, result) -> planner_pb2.EpisodeEvent:
        msg = convert.episode_result_to_proto(result)
        self.publisher.publish(msg)
        return msg

    async def RunEpisode(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        try:
            args = convert.episode_request_from_proto(request)
            self._check_physics(args.options)
        except SQManipError as exc:
            code, message = status_for(exc)
            await context.abort(code, message)
        deadline = deadline_of(context)
        s = self.settings
        deps = [(n, s.address(n)) for n in ("sim", "dynamics")]
        if args.objects == "recognition":
            deps.append(("perception", s.address("perception")))
        async for msg in stream_generator(
            self._episode_lane,
            lambda: self._episode(args, deadline),
            self._event,
            self._result,
            context,
            what="an MPC episode is already running",
            deps=deps,
            probe_timeout=self.service.probe_timeout_s,
        ):
            yield msg

    def close(self) -> None:
        for lane in (self._plan_lane, self._episode_lane):
            lane.pool.shutdown(wait=False, cancel_futures=True)
        if self._dynamics is not None:
            self._dynamics.close()


class _TimedRecognizer:
    """``recognize(request)`` of a remote recognizer with a fixed per-call deadline."""

    def __init__(self, remote: RemoteRecognizer, timeout: float) -> None:
        self.remote, self.timeout = remote, timeout

    def recognize(self, request):
        return self.remote.recognize(request, timeout=self.timeout)


def registrar(servicer: PlannerServicer):
    """``Register`` callback for :func:`sqmanip.rpc.server.start_server`."""

    def register(server: grpc.aio.Server) -> list[str]:
        planner_pb2_grpc.add_PlannerServicer_to_server(servicer, server)
        return [planner_pb2.DESCRIPTOR.services_by_name["Planner"].full_name]

    return register


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("mpc", "sqmanip.planning.server", __doc__)
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    import torch

    torch.set_num_threads(1)
    settings = get_settings()
    servicer = PlannerServicer(settings)

    return run_service(
        servicer,
        registrar(servicer),
        settings,
        name="mpc",
        host=args.host,
        port=args.port,
        publisher=servicer.publisher,
    )


if __name__ == "__main__":
    sys.exit(main())
