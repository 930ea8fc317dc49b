"""POST /recognize with method=network | hybrid through the real gateway and a real Perception
gRPC server whose Recognizer loads a tiny checkpoint made in the test; and the answer when the
checkpoint is missing (400 naming the model path, the service keeps answering)."""

from __future__ import annotations

import asyncio
import threading

import numpy as np
import pytest
import torch
from fastapi.testclient import TestClient
from sqmanip.gateway.app import create_app
from sqmanip.gateway.config import GatewaySettings
from sqmanip.perception.config import PerceptionSettings
from sqmanip.perception.learned import serving
from sqmanip.perception.learned.config import TrainConfig, model_config
from sqmanip.perception.learned.models import build_model
from sqmanip.perception.learned.train import save_model_dir
from sqmanip.perception.pipeline import Recognizer
from sqmanip.perception.server import PerceptionServicer, registrar
from sqmanip.perception.synthetic import make_single_view
from sqmanip.rpc.server import start_server

BIN = {"content-type": "application/octet-stream"}


class _Server:
    """grpc.aio Perception server on its own event loop in a daemon thread."""

    def __init__(self, recognizer: Recognizer) -> None:
        self.servicer = PerceptionServicer(recognizer)
        self.loop = asyncio.new_event_loop()
        ready = threading.Event()

        def run() -> None:
            asyncio.set_event_loop(self.loop)
            self.running = self.loop.run_until_complete(
                start_server(registrar(self.servicer), GatewaySettings(), port=0)
            )
            ready.set()
            self.loop.run_forever()

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        if not ready.wait(30):
            raise RuntimeError("perception test server did not start")

    def stop(self) -> None:
        asyncio.run_coroutine_threadsafe(self.running.stop(0), self.loop).result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.servicer.close()


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    torch.manual_seed(0)
    cfg = model_config("dsqnet", k=4, edge_widths=(8, 8), global_dim=16, head_widths=(16,))
    out = tmp_path_factory.mktemp("dsqnet_tiny")
    save_model_dir(out, build_model("dsqnet", cfg), cfg, TrainConfig(), {"note": "test"})
    return out


def _client(settings: PerceptionSettings):
    server = _Server(Recognizer(settings))
    gw = GatewaySettings(perception_port=server.running.port, request_timeout_s=60.0)
    return server, TestClient(create_app(gw), raise_server_exceptions=False)


@pytest.fixture(scope="module")
def scene():
    return make_single_view("box", seed=3, include_table=True)


def _post(client, scene, method: str):
    params = {"method": method, "viewpoint": ",".join(map(str, scene.viewpoint))}
    return client.post(
        "/recognize", content=scene.points.astype("<f4").tobytes(), headers=BIN, params=params
    )


def test_network_and_hybrid_answer_through_grpc_and_gateway(tiny_model, scene):
    serving.clear_cache()
    server, client = _client(PerceptionSettings(network_model_dir=tiny_model))
    try:
        with client:
            for method in ("network", "hybrid"):
                r = _post(client, scene, method)
                assert r.status_code == 200, r.text
                body = r.json()
                assert len(body["objects"]) == 1
                part = body["objects"][0]["parts"][0]
                assert all(np.isfinite(part["size"])) and min(part["size"]) > 0
                centre = np.asarray(part["pose"]["position"])
                seen = scene.points[body["objects"][0]["point_indices"]]
                assert np.linalg.norm(centre - seen.mean(0)) < 0.1
                assert body["timings_ms"]["network"] > 0
    finally:
        server.stop()
        serving.clear_cache()


def test_missing_checkpoint_is_answered_400_naming_the_path(tmp_path, scene):
    serving.clear_cache()
    missing = tmp_path / "no_dsqnet_here"
    server, client = _client(PerceptionSettings(network_model_dir=missing))
    try:
        with client:
            r = _post(client, scene, "network")
            assert r.status_code == 400, r.text
            assert "no_dsqnet_here" in r.json()["detail"]
            assert _post(client, scene, "mvbb").status_code == 200  # still answering
    finally:
        server.stop()
