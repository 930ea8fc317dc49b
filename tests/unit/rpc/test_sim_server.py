"""The Simulator servicer in-process (grpc.aio on loopback, real PyBullet): every simulator call
runs on one thread, domain errors become INVALID_ARGUMENT / FAILED_PRECONDITION with the reason,
observations are handed to the publisher, and RemoteSimulator mirrors the domain API."""

from __future__ import annotations

import asyncio
import threading

import grpc
import numpy as np
import pytest
from sqmanip import errors
from sqmanip.rpc import convert
from sqmanip.rpc.client import RemoteSimulator, aio_channel
from sqmanip.rpc.server import start_server
from sqmanip.settings import StackSettings
from sqmanip.sim import Intrinsics, ObjectSpec, SceneSpec, Simulator
from sqmanip.sim.server import SimulatorServicer, registrar
from sqmanip.v1 import sim_pb2, sim_pb2_grpc

BOX_SCENE = SceneSpec(
    objects=(ObjectSpec("box", position=(0.45, 0.0, 0.025), size=(0.05, 0.05, 0.05)),)
)


class ThreadRecordingSimulator(Simulator):
    """A real Simulator that records the thread of every public call."""

    threads: set[int]

    def __init__(self) -> None:
        self.threads = {threading.get_ident()}
        super().__init__()

    def __getattribute__(self, name: str):
        attr = super().__getattribute__(name)
        if not name.startswith("_") and callable(attr) and name != "threads":
            super().__getattribute__("threads").add(threading.get_ident())
        return attr


class ListPublisher:
    def __init__(self) -> None:
        self.messages: list[sim_pb2.Observation] = []
        self.event = threading.Event()

    def publish(self, message) -> None:
        self.messages.append(message)
        self.event.set()


def top_grasp(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]
    T[:3, 3] = (x, y, z)
    return T


@pytest.fixture
async def served():
    servicer = SimulatorServicer(ThreadRecordingSimulator)
    servicer.publisher = ListPublisher()
    running = await start_server(registrar(servicer), StackSettings(), port=0)
    channel = aio_channel(f"127.0.0.1:{running.port}")
    yield servicer, sim_pb2_grpc.SimulatorStub(channel), running.port
    await channel.close()
    await running.stop(0)
    servicer.close()


async def test_all_simulator_calls_run_on_one_thread_even_when_concurrent(served) -> None:
    servicer, stub, _ = served
    await stub.Reset(convert.reset_request_to_proto(BOX_SCENE), timeout=30)
    small = convert.observe_request_to_proto(intrinsics=Intrinsics.scaled(64, 48))
    results = await asyncio.gather(
        stub.GetState(sim_pb2.GetStateRequest(), timeout=30),
        stub.Observe(small, timeout=30),
        stub.Push(convert.push_request_to_proto([0.36, 0.0, 0.02], [0.04, 0, 0]), timeout=30),
        stub.GetState(sim_pb2.GetStateRequest(), timeout=30),
    )
    assert results[2].success
    assert len(servicer._sim.threads) == 1
    assert threading.get_ident() not in servicer._sim.threads


async def test_observation_is_returned_and_handed_to_the_publisher(served) -> None:
    servicer, stub, _ = served
    await stub.Reset(convert.reset_request_to_proto(BOX_SCENE), timeout=30)
    msg = await stub.Observe(
        convert.observe_request_to_proto(intrinsics=Intrinsics.scaled(80, 60)), timeout=30
    )
    assert (msg.height, msg.width) == (60, 80) and msg.cloud.num_points > 0
    assert await asyncio.to_thread(servicer.publisher.event.wait, 5)
    assert servicer.publisher.messages[0].SerializeToString() == msg.SerializeToString()


async def test_refused_actions_map_to_status_codes_and_the_server_keeps_answering(served) -> None:
    _, stub, _ = served
    await stub.Reset(convert.reset_request_to_proto(BOX_SCENE), timeout=30)
    with pytest.raises(grpc.aio.AioRpcError) as err:
        await stub.Push(convert.push_request_to_proto([0.9, 0, 0.02], [0.1, 0, 0]), timeout=30)
    assert err.value.code() is grpc.StatusCode.INVALID_ARGUMENT
    assert "out of workspace" in err.value.details()
    with pytest.raises(grpc.aio.AioRpcError) as err:
        await stub.Grasp(convert.grasp_request_to_proto(top_grasp(1.2, 0, 0.05), 0.05), timeout=30)
    assert err.value.code() is grpc.StatusCode.FAILED_PRECONDITION
    assert "unreachable" in err.value.details()
    with pytest.raises(grpc.aio.AioRpcError) as err:
        await stub.Reset(sim_pb2.ResetRequest(), timeout=30)
    assert err.value.code() is grpc.StatusCode.INVALID_ARGUMENT
    assert "scene spec or a seed" in err.value.details()
    with pytest.raises(grpc.aio.AioRpcError) as err:
        await stub.Observe(
            sim_pb2.ObserveRequest(intrinsics=convert.intrinsics_to_proto(Intrinsics(4096, 4096))),
            timeout=30,
        )
    assert err.value.code() is grpc.StatusCode.INVALID_ARGUMENT
    assert "message limit" in err.value.details()
    state = await stub.GetState(sim_pb2.GetStateRequest(), timeout=30)
    assert len(state.objects) == 1


async def test_remote_simulator_mirrors_the_domain_api(served) -> None:
    _, _, port = served

    def use_remote() -> None:
        with RemoteSimulator(f"127.0.0.1:{port}") as remote:
            a = remote.reset(seed=3, n_objects=2)
            assert len(a.objects) == 2 and len(remote.scene_spec.objects) == 2
            b = remote.reset(remote.scene_spec)
            for oa, ob in zip(a.objects, b.objects, strict=True):
                np.testing.assert_allclose(oa.position, ob.position, atol=1e-9)
            remote.reset(BOX_SCENE)
            res = remote.grasp(top_grasp(0.45, 0.0, 0.03), 0.08)
            assert res.success, res.message
            assert res.before.held_object is None and res.held_object == 0
            assert remote.get_state().held_object == 0
            with pytest.raises(errors.PreconditionError, match="holding object 0"):
                remote.push([0.3, 0.0, 0.02], [0.1, 0.0, 0.0])
            assert remote.release().after.held_object is None
            obs = remote.observe("overview", intrinsics=Intrinsics.scaled(64, 48), noise=False)
            assert obs.camera == "overview" and obs.depth.shape == (48, 64)
            with pytest.raises(errors.ValidationError, match="width"):
                remote.grasp(top_grasp(0.45, 0, 0.03), 0.2)

    await asyncio.to_thread(use_remote)
