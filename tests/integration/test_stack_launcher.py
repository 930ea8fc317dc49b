"""The launcher's supervision, Zenoh publication and health, on real processes (fast: MVBB)."""

import contextlib
import queue
import signal
import threading
import time

import httpx
import numpy as np
import pytest
import sqmanip_client as sdk
from sqmanip import streams
from sqmanip.launch import Stack, running_stack, settings_on_free_ports
from sqmanip.perception.synthetic import make_single_view
from sqmanip.rpc.health_probe import main as probe_main
from sqmanip.v1 import common_pb2

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def scene():
    return make_single_view("box", seed=1)


def test_zenoh_subscriber_receives_the_recognized_scene(scene) -> None:
    with running_stack(services=("perception",), zenoh=True) as stack:
        session, sub = streams.subscribe(streams.SCENE_KEY, stack.settings)
        try:
            for _ in range(10):  # until the subscription has reached perception's publisher
                result = sdk.Client(stack.gateway_url).recognize(scene.points, method="mvbb")
                with contextlib.suppress(queue.Empty):
                    key, payload = sub.get(timeout=2)
                    break
            else:
                pytest.fail("no scene on Zenoh after 10 recognitions")
        finally:
            sub.close()
            session.close()
    assert key == streams.SCENE_KEY
    published = common_pb2.Scene.FromString(payload)
    assert len(published.objects) == len(result.objects) == 1


def test_health_probe_cli_and_launcher_addresses(capsys) -> None:
    with running_stack(services=("perception",), zenoh=False) as stack:
        assert probe_main([stack.address("perception")]) == 0
        assert "SERVING" in capsys.readouterr().out
        assert httpx.get(stack.gateway_url + "/healthz").json()["status"] == "ok"
        perception_pid = stack._proc("perception").popen.pid
    with pytest.raises(OSError):  # torn down: the process is gone
        import os

        os.kill(perception_pid, 0)
    assert probe_main([stack.address("perception"), "--timeout", "0.5"]) == 1


def test_stack_stops_everything_when_a_service_dies() -> None:
    stack = Stack(settings_on_free_ports(), ("perception",), zenoh=False)
    try:
        stack.start(90)
        code: list[int] = []
        t = threading.Thread(target=lambda: code.append(stack.supervise(poll_s=0.1)))
        t.start()
        stack.kill("perception", signal.SIGKILL)
        t.join(30)
        assert code == [1]
        assert all(not p.alive() for p in stack.procs)
    finally:
        stack.stop()


def test_dead_service_gives_503_then_is_restarted(scene) -> None:
    with running_stack(services=("perception",), zenoh=False, restart=True) as stack:
        client = sdk.Client(stack.gateway_url, timeout=30)
        stack.kill("perception", signal.SIGKILL)
        stack._proc("perception").popen.wait(10)
        with pytest.raises(sdk.ServiceUnavailableError):
            client.recognize(scene.points, method="mvbb")
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                result = client.recognize(scene.points, method="mvbb")
                break
            except sdk.ServiceUnavailableError:
                time.sleep(0.5)
        else:
            pytest.fail("perception was not restarted within 60 s")
        assert len(result.objects) == 1 and stack._proc("perception").restarts == 1


def test_grpc_channel_limits_allow_large_clouds() -> None:
    """A 1 M point cloud (12 MB) passes the gRPC size limits end to end."""
    pts = np.random.default_rng(0).uniform(-0.01, 0.01, size=(1_000_000, 3)).astype(np.float32)
    with running_stack(services=("perception",), zenoh=False) as stack:
        result = sdk.Client(stack.gateway_url, timeout=120).recognize(
            pts, method="mvbb", remove_support=False
        )
    assert isinstance(result, sdk.Scene)
