"""gRPC Perception server: a thin adapter over :class:`sqmanip.perception.pipeline.Recognizer`.

``python -m sqmanip.perception.server [--host H] [--port P] [--workers W]``. The recognizer is
CPU-bound and synchronous, so calls run in a thread pool (``--workers``, default 1 on this 2-core
machine: torch already uses both cores); at most ``--max-queue`` requests wait, more are answered
RESOURCE_EXHAUSTED (HTTP 429). Errors are mapped by the one interceptor in ``sqmanip.rpc.errors``.
When Zenoh is enabled (``SQMANIP_ZENOH_ENABLED``), each recognized scene is also published on
``sqmanip/perception/scene`` (``sqmanip.v1.Scene`` bytes) through the stack's router.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import sys
from typing import Protocol

import grpc

from sqmanip.errors import ResourceExhaustedError
from sqmanip.perception.types import RecognizeRequest, Scene
from sqmanip.rpc import convert
from sqmanip.rpc.server import configure_logging, run_service, service_parser
from sqmanip.settings import StackSettings, get_settings
from sqmanip.v1 import perception_pb2, perception_pb2_grpc

log = logging.getLogger("sqmanip.perception.server")


class SceneRecognizer(Protocol):
    def recognize(self, request: RecognizeRequest) -> Scene: ...


class ScenePublisher(Protocol):
    def publish(self, message) -> None: ...


class PerceptionServicer(perception_pb2_grpc.PerceptionServicer):
    """``Recognize``: proto -> domain request, recognizer in a worker thread, Scene -> proto."""

    def __init__(
        self, recognizer: SceneRecognizer, *, workers: int = 1, max_queue: int = 16
    ) -> None:
        self._recognizer = recognizer
        self._pool = concurrent.futures.ThreadPoolExecutor(workers, "recognize")
        self._publish_pool = concurrent.futures.ThreadPoolExecutor(1, "publish")
        self._max_pending = workers + max_queue
        self._pending = 0
        self.publisher: ScenePublisher | None = None

    async def Recognize(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        if self._pending >= self._max_pending:
            raise ResourceExhaustedError(f"perception busy: {self._pending} requests in progress")
        req = convert.recognize_request_from_proto(request)
        self._pending += 1
        try:
            loop = asyncio.get_running_loop()
            scene = await loop.run_in_executor(self._pool, self._recognizer.recognize, req)
        finally:
            self._pending -= 1
        msg = convert.scene_to_proto(scene)
        if self.publisher is not None:
            self._publish_pool.submit(self.publisher.publish, msg)
        return perception_pb2.RecognizeResponse(scene=msg)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._publish_pool.shutdown(wait=False, cancel_futures=True)


def registrar(servicer: PerceptionServicer):
    """``Register`` callback for :func:`sqmanip.rpc.server.start_server`."""

    def register(server: grpc.aio.Server) -> list[str]:
        perception_pb2_grpc.add_PerceptionServicer_to_server(servicer, server)
        return [perception_pb2.DESCRIPTOR.services_by_name["Perception"].full_name]

    return register


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("perception", "sqmanip.perception.server", __doc__)
    parser.add_argument("--workers", type=int, default=1, help="recognition threads (default 1)")
    parser.add_argument("--max-queue", type=int, default=16, help="waiting requests before 429")
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    settings: StackSettings = get_settings()

    from sqmanip.perception.pipeline import Recognizer  # heavy (torch): after arg parsing

    servicer = PerceptionServicer(Recognizer(), workers=args.workers, max_queue=args.max_queue)
    from sqmanip import streams

    # Drops messages until the router answers.
    servicer.publisher = streams.Publisher(streams.SCENE_KEY)
    return run_service(
        servicer,
        registrar(servicer),
        settings,
        name="perception",
        host=args.host,
        port=args.port,
        publisher=servicer.publisher,
    )


if __name__ == "__main__":
    sys.exit(main())
