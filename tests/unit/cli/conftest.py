"""A real gateway (uvicorn on a free loopback port, in a thread) in front of a real Perception
gRPC server (in-process, real Recognizer): what ``sqmanip recognize --gateway URL`` talks to."""

from __future__ import annotations

import asyncio
import threading
import time

import pytest


class _PerceptionThread:
    """grpc.aio Perception server on its own event loop in a daemon thread."""

    def __init__(self, settings) -> None:
        from sqmanip.perception.pipeline import Recognizer
        from sqmanip.perception.server import PerceptionServicer, registrar

        self.servicer = PerceptionServicer(Recognizer())
        self._register = registrar(self.servicer)
        self.loop = asyncio.new_event_loop()
        self.ready = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(settings,), daemon=True)
        self.thread.start()
        if not self.ready.wait(60):
            raise RuntimeError("perception test server did not start")

    def _run(self, settings) -> None:
        from sqmanip.rpc.server import start_server

        asyncio.set_event_loop(self.loop)
        self.running = self.loop.run_until_complete(start_server(self._register, settings, port=0))
        self.port = self.running.port
        self.ready.set()
        self.loop.run_forever()

    def stop(self) -> None:
        asyncio.run_coroutine_threadsafe(self.running.stop(0), self.loop).result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.servicer.close()


@pytest.fixture(scope="module")
def gateway_url():
    import uvicorn
    from sqmanip.gateway.app import create_app
    from sqmanip.gateway.config import GatewaySettings
    from sqmanip.launch import free_port

    perception = _PerceptionThread(GatewaySettings())
    settings = GatewaySettings(
        perception_port=perception.port, request_timeout_s=60.0, zenoh_enabled=False
    )
    port = free_port()
    server = uvicorn.Server(
        uvicorn.Config(create_app(settings), host="127.0.0.1", port=port, log_level="warning")
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 60
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError("gateway test server did not start")
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(10)
        perception.stop()
