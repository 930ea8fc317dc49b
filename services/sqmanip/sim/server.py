"""gRPC Simulator server: a thin adapter over one :class:`sqmanip.sim.Simulator`.

``python -m sqmanip.sim.server [--host H] [--port P] [--max-queue Q]``. PyBullet clients must
never be touched from two threads, so the servicer owns ONE single-thread executor: the
simulator is created, used and closed on that thread only, and every RPC (including the
conversion of large observations to protobuf, which would otherwise block the event loop) runs
there in arrival order. At most ``--max-queue`` calls wait; more are answered
RESOURCE_EXHAUSTED (HTTP 429). Domain errors are mapped by the one interceptor in
``sqmanip.rpc.errors`` (ValidationError -> INVALID_ARGUMENT, PreconditionError ->
FAILED_PRECONDITION), so a refused action is answered and the server keeps running.

When Zenoh is enabled (``SQMANIP_ZENOH_ENABLED``), every observation is also published on
:data:`OBSERVATION_KEY` (``sqmanip.v1.Observation`` bytes) from a separate publisher thread,
never from the event loop.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import sys
from collections.abc import Callable
from typing import Any, Protocol, TypeVar

import grpc

from sqmanip.errors import ResourceExhaustedError, ValidationError
from sqmanip.rpc import convert
from sqmanip.rpc.server import configure_logging, run_service, service_parser
from sqmanip.settings import StackSettings, get_settings
from sqmanip.v1 import sim_pb2, sim_pb2_grpc

log = logging.getLogger("sqmanip.sim.server")

OBSERVATION_KEY = "sqmanip/sim/observation"
"""Zenoh key of the observation stream (payload: serialized ``sqmanip.v1.Observation``)."""

BYTES_PER_PIXEL = 4 + 3 + 4 + 12 + 4 + 4
"""Wire bytes per pixel of an Observation at most: depth, rgb, segmentation, and one cloud point
(xyz 12, label 4, pixel index 4) per pixel."""

T = TypeVar("T")


class ObservationPublisher(Protocol):
    def publish(self, message) -> None: ...


class SimulatorServicer(sim_pb2_grpc.SimulatorServicer):
    """Every RPC: proto -> domain arguments, the simulator call on the sim thread, -> proto.

    ``factory`` builds the simulator (default :class:`sqmanip.sim.Simulator`); it is called on
    the sim thread, which is where the PyBullet client lives from then on.
    """

    def __init__(
        self,
        factory: Callable[[], Any] | None = None,
        *,
        max_queue: int = 16,
        max_message_bytes: int | None = None,
    ) -> None:
        if factory is None:
            from sqmanip.sim import Simulator

            factory = Simulator
        self._pool = concurrent.futures.ThreadPoolExecutor(1, "sim")
        self._publish_pool = concurrent.futures.ThreadPoolExecutor(1, "publish")
        self._sim = self._pool.submit(factory).result()
        self._max_pending = 1 + max_queue
        self._pending = 0
        self._max_bytes = max_message_bytes or get_settings().grpc_max_message_bytes
        self.publisher: ObservationPublisher | None = None

    async def _run(self, fn: Callable[..., T], *args: Any) -> T:
        """Run ``fn(*args)`` on the sim thread (the only thread that touches PyBullet)."""
        if self._pending >= self._max_pending:
            raise ResourceExhaustedError(f"simulator busy: {self._pending} requests in progress")
        self._pending += 1
        try:
            return await asyncio.get_running_loop().run_in_executor(self._pool, fn, *args)
        finally:
            self._pending -= 1

    # --- RPCs -------------------------------------------------------------------------------------

    async def Reset(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        kwargs = convert.reset_request_from_proto(request)

        def call() -> sim_pb2.ResetResponse:
            state = self._sim.reset(**kwargs)
            return sim_pb2.ResetResponse(
                state=convert.sim_state_to_proto(state),
                scene_json=convert.scene_spec_to_json(self._sim.scene_spec),
            )

        return await self._run(call)

    async def Observe(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        kwargs = convert.observe_request_from_proto(request)
        k = kwargs["intrinsics"]
        if k is not None and k.width * k.height * BYTES_PER_PIXEL > self._max_bytes:
            raise ValidationError(
                f"intrinsics: {k.width} x {k.height} px needs up to "
                f"{k.width * k.height * BYTES_PER_PIXEL} bytes per observation; the message limit "
                f"is {self._max_bytes} bytes (at most {self._max_bytes // BYTES_PER_PIXEL} pixels)"
            )

        def call() -> sim_pb2.Observation:
            return convert.observation_to_proto(self._sim.observe(**kwargs))

        msg = await self._run(call)
        if self.publisher is not None:
            self._publish_pool.submit(self.publisher.publish, msg)  # best effort, never blocks
        return msg

    async def Push(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        p, v, upright = convert.push_request_from_proto(request)
        return await self._run(
            lambda: convert.action_result_to_proto(self._sim.push(p, v, upright))
        )

    async def Grasp(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        pose, width = convert.grasp_request_from_proto(request)
        return await self._run(lambda: convert.action_result_to_proto(self._sim.grasp(pose, width)))

    async def PickAndPlace(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        grasp_pose, width, place_pose = convert.pick_and_place_request_from_proto(request)
        return await self._run(
            lambda: convert.action_result_to_proto(
                self._sim.pick_and_place(grasp_pose, width, place_pose)
            )
        )

    async def Release(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        return await self._run(lambda: convert.action_result_to_proto(self._sim.release()))

    async def GetState(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        return await self._run(lambda: convert.sim_state_to_proto(self._sim.get_state()))

    def close(self) -> None:
        """Close the simulator on its own thread, then stop the threads."""
        try:
            self._pool.submit(self._sim.close).result(10)
        except Exception:  # noqa: BLE001 - shutting down anyway
            log.exception("closing the simulator failed")
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._publish_pool.shutdown(wait=False, cancel_futures=True)


def registrar(servicer: SimulatorServicer):
    """``Register`` callback for :func:`sqmanip.rpc.server.start_server`."""

    def register(server: grpc.aio.Server) -> list[str]:
        sim_pb2_grpc.add_SimulatorServicer_to_server(servicer, server)
        return [sim_pb2.DESCRIPTOR.services_by_name["Simulator"].full_name]

    return register


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("sim", "sqmanip.sim.server", __doc__)
    parser.add_argument("--max-queue", type=int, default=16, help="waiting requests before 429")
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    settings: StackSettings = get_settings()

    servicer = SimulatorServicer(
        max_queue=args.max_queue, max_message_bytes=settings.grpc_max_message_bytes
    )
    from sqmanip import streams

    # Drops messages until the router answers.
    servicer.publisher = streams.Publisher(OBSERVATION_KEY)
    return run_service(
        servicer,
        registrar(servicer),
        settings,
        name="sim",
        host=args.host,
        port=args.port,
        publisher=servicer.publisher,
    )


if __name__ == "__main__":
    sys.exit(main())
