"""gRPC GraspPlanner server: a thin adapter over :class:`sqmanip.grasping.GraspPlanner`.

``python -m sqmanip.grasping.server [--host H] [--port P] [--max-queue Q]``. ``Plan`` decodes the
request (:func:`sqmanip.rpc.convert.plan_grasps_request_from_proto`: the target's parts, the other
objects as obstacles, environment, gripper, options), runs
:meth:`GraspPlanner.plan_detailed` in a worker thread and answers the ranked grasps with the
plan's counts and timings. Domain errors are mapped by the one interceptor in
``sqmanip.rpc.errors``: bad values -> INVALID_ARGUMENT naming the field, an unknown
``target_id`` -> NOT_FOUND.

Kinematic feasibility (settings ``SQMANIP_GRASP_REACHABILITY``):

- ``panda_ik`` (default): :class:`sqmanip.grasping.reachability.PandaIKReachability`, the
  simulator's own pinocchio IK for the pre-grasp, grasp and lift poses of the Panda on its
  pedestal at ``sim.config.ROBOT_BASE_POSITION``; a grasp it accepts is one ``Simulator.grasp``
  can execute. It models the Franka hand for the flange offset whatever gripper a request sends.
- ``workspace``: :class:`sqmanip.grasping.WorkspaceReachability`, a flange-radius stand-in.

A request with ``options.check_reachability = false`` skips the check (geometry only).

One worker thread: the IK's memo cache and pinocchio's model data are not thread-safe, and torch
already parallelises inside a plan; scale out with more processes behind a load balancer. At most
``--max-queue`` requests wait, more are answered RESOURCE_EXHAUSTED (HTTP 429).

Torch threads (``SQMANIP_GRASP_TORCH_THREADS``, default 1): see the dynamics server's docstring
(:mod:`sqmanip.dynamics.server`) for the measurement behind the default; every stack service
shares the same few cores.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import sys
from typing import Literal

import grpc
from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from sqmanip.errors import ResourceExhaustedError
from sqmanip.rpc import convert
from sqmanip.rpc.server import configure_logging, run_service, service_parser
from sqmanip.settings import StackSettings, get_settings
from sqmanip.v1 import grasp_pb2, grasp_pb2_grpc

from .config import Reachability, WorkspaceReachability, always_reachable
from .planner import GraspPlanner, PlanResult

log = logging.getLogger("sqmanip.grasping.server")

ReachabilityName = Literal["panda_ik", "workspace"]


class GraspServiceSettings(BaseSettings):
    """Settings of the grasp service (env prefix ``SQMANIP_GRASP_``)."""

    model_config = SettingsConfigDict(env_prefix="SQMANIP_GRASP_", extra="ignore")

    reachability: ReachabilityName = "panda_ik"
    """Kinematic feasibility: the Panda IK of the simulator, or the workspace-radius stand-in."""
    torch_threads: int = Field(1, ge=1)
    """``torch.set_num_threads`` of the service process."""
    max_queue: int = Field(16, ge=0)
    """Requests that may wait for the worker; more are answered RESOURCE_EXHAUSTED."""


def make_reachability(name: ReachabilityName) -> Reachability:
    """The feasibility check named by the settings (``panda_ik`` imports pinocchio)."""
    if name == "panda_ik":
        from .reachability import PandaIKReachability

        return PandaIKReachability()
    if name == "workspace":
        return WorkspaceReachability()
    raise ValueError(f"reachability must be 'panda_ik' or 'workspace', got {name!r}")


class GraspPlannerServicer(grasp_pb2_grpc.GraspPlannerServicer):
    """``Plan``: proto -> domain arguments, ``plan_detailed`` on the worker thread -> proto."""

    def __init__(self, planner: GraspPlanner | None = None, *, max_queue: int = 16) -> None:
        self.planner = planner or GraspPlanner(make_reachability("panda_ik"))
        # Same gripper/options defaults, no kinematic check (options.check_reachability=false).
        self.geometry_planner = GraspPlanner(
            always_reachable,
            gripper=self.planner.gripper,
            options=self.planner.options,
            dtype=self.planner.dtype,
        )
        self._pool = concurrent.futures.ThreadPoolExecutor(1, "grasp")
        self._max_pending = 1 + max_queue
        self._pending = 0

    def _plan(self, args: convert.PlanGraspsArgs) -> PlanResult:
        planner = self.planner if args.check_reachability else self.geometry_planner
        return planner.plan_detailed(
            args.target,
            args.obstacles,
            args.environment,
            args.gripper,
            args.options,
            args.observed_points,
        )

    async def Plan(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        if self._pending >= self._max_pending:
            raise ResourceExhaustedError(
                f"grasp planner busy: {self._pending} requests in progress"
            )
        args = convert.plan_grasps_request_from_proto(request)
        self._pending += 1
        try:
            loop = asyncio.get_running_loop()
            result = await loop.run_in_executor(self._pool, self._plan, args)
        finally:
            self._pending -= 1
        return convert.plan_result_to_proto(result, args.target_id)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


def registrar(servicer: GraspPlannerServicer):
    """``Register`` callback for :func:`sqmanip.rpc.server.start_server`."""

    def register(server: grpc.aio.Server) -> list[str]:
        grasp_pb2_grpc.add_GraspPlannerServicer_to_server(servicer, server)
        return [grasp_pb2.DESCRIPTOR.services_by_name["GraspPlanner"].full_name]

    return register


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("grasp", "sqmanip.grasping.server", __doc__)
    parser.add_argument("--max-queue", type=int, default=None, help="waiting requests before 429")
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    settings: StackSettings = get_settings()
    service = GraspServiceSettings()

    import torch

    torch.set_num_threads(service.torch_threads)
    planner = GraspPlanner(make_reachability(service.reachability))
    log.info(
        "grasp planner: reachability=%s torch_threads=%d", service.reachability,
        service.torch_threads,
    )  # fmt: skip
    max_queue = args.max_queue if args.max_queue is not None else service.max_queue
    servicer = GraspPlannerServicer(planner, max_queue=max_queue)
    return run_service(
        servicer, registrar(servicer), settings, name="grasp", host=args.host, port=args.port
    )


if __name__ == "__main__":
    sys.exit(main())
