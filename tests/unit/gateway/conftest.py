"""A real Perception gRPC server (real Recognizer) on a loopback port, and the real gateway app
in front of it, shared by the gateway and SDK tests of this package."""

from __future__ import annotations

import asyncio
import threading

import pytest
from fastapi.testclient import TestClient
from sqmanip.gateway.app import create_app
from sqmanip.gateway.config import GatewaySettings
from sqmanip.launch import free_port
from sqmanip.perception.server import PerceptionServicer, registrar
from sqmanip.rpc.server import start_server


class ServerThread:
    """grpc.aio server on its own event loop in a daemon thread."""

    def __init__(self, register, settings) -> None:
        self.loop = asyncio.new_event_loop()
        self.ready = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(register, settings), daemon=True)
        self.thread.start()
        if not self.ready.wait(30):
            raise RuntimeError("perception test server did not start")

    def _run(self, register, settings) -> None:
        asyncio.set_event_loop(self.loop)
        self.running = self.loop.run_until_complete(start_server(register, settings, port=0))
        self.port = self.running.port
        self.ready.set()
        self.loop.run_forever()

    def stop(self) -> None:
        fut = asyncio.run_coroutine_threadsafe(self.running.stop(0), self.loop)
        fut.result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)


@pytest.fixture(scope="session")
def perception_server():
    from sqmanip.perception.pipeline import Recognizer

    servicer = PerceptionServicer(Recognizer())
    server = ServerThread(registrar(servicer), GatewaySettings())
    yield server
    server.stop()
    servicer.close()


@pytest.fixture(scope="session")
def gateway_settings(perception_server) -> GatewaySettings:
    return GatewaySettings(
        perception_port=perception_server.port,
        gateway_max_body_bytes=16 * 1024 * 1024,
        request_timeout_s=60.0,
    )


@pytest.fixture(scope="session")
def client(gateway_settings):
    with TestClient(create_app(gateway_settings), raise_server_exceptions=False) as c:
        yield c


@pytest.fixture
def dead_backend_client():
    """Gateway whose perception address has nothing listening."""
    settings = GatewaySettings(perception_port=free_port(), request_timeout_s=2.0)
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c
