"""The Dynamics servicer in-process (grpc.aio on loopback) and the gateway's ``POST /predict`` in
front of it: a checkpoint saved to a temporary model dir answers exactly what the in-process
model predicts, a missing checkpoint is FAILED_PRECONDITION with the training command, bad
shapes are 400 naming the field, and the physics model runs on one dedicated thread."""

from __future__ import annotations

import asyncio
import threading

import grpc
import httpx
import numpy as np
import pytest
import torch
from sqmanip.dynamics.config import cpu_config
from sqmanip.dynamics.model import make_model
from sqmanip.dynamics.server import DynamicsServicer, DynamicsServiceSettings, registrar
from sqmanip.errors import PreconditionError, ValidationError
from sqmanip.gateway.app import create_app
from sqmanip.gateway.config import GatewaySettings
from sqmanip.rpc import convert
from sqmanip.rpc.client import RemoteDynamics, aio_channel
from sqmanip.rpc.server import start_server
from sqmanip.settings import StackSettings
from sqmanip.v1 import dynamics_pb2_grpc


def save_checkpoint(directory, seed: int = 0):
    torch.manual_seed(seed)
    config = cpu_config()
    model = make_model(config).eval()
    directory.mkdir(parents=True)
    config.save(directory / "config.json")
    torch.save(model.state_dict(), directory / "model.pt")
    return model


def scene(n: int = 3, k: int = 20, seed: int = 0):
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    yaw = rng.uniform(-np.pi, np.pi, n)
    poses[:, 0, 0] = poses[:, 1, 1] = np.cos(yaw)
    poses[:, 1, 0], poses[:, 0, 1] = np.sin(yaw), -np.sin(yaw)
    poses[:, :2, 3] = rng.uniform(-0.15, 0.15, (n, 2)) + [0.45, 0.0]
    poses[:, 2, 3] = 0.03
    params = np.tile([0.03, 0.02, 0.03, 0.2, 0.2, 0.0, 0.0, 0.0, 0.0], (n, 1))
    params[:, :3] += rng.uniform(0, 0.01, (n, 3))
    actions = np.column_stack(
        [rng.uniform(0.3, 0.6, (k, 2)), np.full(k, 0.02), rng.normal(0, 0.05, (k, 2)), np.zeros(k)]
    ).astype(np.float32)
    return poses, params, actions


class FakePhysics:
    """Stands in for PhysicsDynamics: records its threads, moves every object up by 1 cm and
    flags odd actions as failed."""

    threads: set[int] = set()

    def __init__(self) -> None:
        FakePhysics.threads.add(threading.get_ident())
        self.last_failed = np.zeros(0, dtype=bool)

    def predict(self, poses, params, actions, kinds=None):
        FakePhysics.threads.add(threading.get_ident())
        k = len(actions)
        out = np.broadcast_to(poses, (k, *poses.shape)).copy()
        out[..., 2, 3] += 0.01
        self.last_failed = np.arange(k) % 2 == 1
        return torch.as_tensor(out)


@pytest.fixture
async def served(tmp_path):
    model = save_checkpoint(tmp_path / "models" / "sqpdnet")
    settings = DynamicsServiceSettings(model_dir=tmp_path / "models" / "sqpdnet",
                                       physics_max_actions=4)  # fmt: skip
    servicer = DynamicsServicer(settings, physics_factory=FakePhysics)
    running = await start_server(registrar(servicer), StackSettings(), port=0)
    address = f"127.0.0.1:{running.port}"
    channel = aio_channel(address)
    app = create_app(GatewaySettings(gateway_services=["dynamics"], request_timeout_s=60))
    app.state.channels = {"dynamics": channel}
    async with httpx.AsyncClient(
        transport=httpx.ASGITransport(app=app), base_url="http://gw"
    ) as http:
        yield model, address, dynamics_pb2_grpc.DynamicsStub(channel), http, tmp_path
    await channel.close()
    await running.stop(0)
    servicer.close()


async def test_remote_prediction_equals_the_in_process_model(served) -> None:
    model, address, _, _, _ = served
    poses, params, actions = scene()
    local = model.predict(poses, params, actions).numpy()

    def remote():
        with RemoteDynamics(address) as rd:
            return rd.predict(poses, params, actions)

    got = await asyncio.to_thread(remote)
    assert got.shape == (20, 3, 4, 4)
    np.testing.assert_allclose(got.numpy(), local, atol=2e-6)
    assert np.abs(local - poses).max() > 1e-4  # the random network does move things


async def test_remote_predict_batch_rolls_each_scene_in_one_call(served) -> None:
    """The MPC's later horizon steps: K different scenes, one push each, one round trip."""
    model, address, stub, _, _ = served
    poses, params, actions = scene(3, 6, seed=2)
    scenes = model.predict(poses, params, actions).numpy().astype(np.float64)  # 6 scenes
    local = model.predict_batch(scenes, params, actions).numpy()

    def remote():
        with RemoteDynamics(address) as rd:
            out = rd.predict_batch(scenes, params, actions)
            with pytest.raises(ValidationError, match="scene_poses"):
                rd.predict_batch(scenes[:2], params, actions)  # K scenes for K pushes
            return out

    got = await asyncio.to_thread(remote)
    assert got.shape == (6, 3, 4, 4)
    np.testing.assert_allclose(got.numpy(), local, atol=2e-6)
    shared = model.predict(scenes[0], params, actions).numpy()
    assert np.abs(local[1:] - shared[1:]).max() > 1e-4  # each push acted on its own scene
    bad = convert.predict_request_to_proto(poses, params, actions)
    bad.scene_poses = b"\0" * 12  # not K x N x 4 x 4 float32
    with pytest.raises(grpc.aio.AioRpcError) as err:
        await stub.Predict(bad)
    assert err.value.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "scene_poses" in err.value.details()


async def test_gateway_predict_returns_k_by_n_poses(served) -> None:
    model, _, _, http, _ = served
    poses, params, actions = scene(2, 5, seed=1)
    objects = [
        {"size": params[i, :3].tolist(), "shape": [0.2, 0.2],
         "pose": convert_pose(poses[i])} for i in range(2)
    ]  # fmt: skip
    r = await http.post("/predict", json={"objects": objects, "actions": actions.tolist()})
    assert r.status_code == 200, r.text
    out = r.json()
    assert (out["num_actions"], out["num_objects"], out["model"]) == (5, 2, "sqpdnet")
    assert len(out["poses"]) == 5 and all(len(row) == 2 for row in out["poses"])
    local = model.predict(poses, params, actions).numpy()
    np.testing.assert_allclose(out["poses"][3][1]["position"], local[3, 1, :3, 3], atol=1e-5)


def convert_pose(T: np.ndarray) -> dict:
    msg = convert.pose_to_proto(T)
    q = msg.orientation
    return {"position": T[:3, 3].tolist(), "orientation": [q.x, q.y, q.z, q.w]}


async def test_missing_checkpoint_is_a_precondition_naming_the_training_command(served) -> None:
    _, _, stub, http, tmp_path = served
    empty = DynamicsServicer(DynamicsServiceSettings(model_dir=tmp_path / "nothing"))
    poses, params, actions = scene(1, 2)
    msg = convert.predict_request_to_proto(poses, params, actions)
    with pytest.raises(
        PreconditionError, match=r"no SQPD-Net checkpoint at .*nothing.*sqmanip train sqpdnet"
    ):
        await empty.Predict(msg, None)
    empty.close()
    # Unknown checkpoint names are 404, malformed ones 400; the server keeps answering.
    msg.model = "sqpdnet_v9"
    with pytest.raises(grpc.aio.AioRpcError) as err:
        await stub.Predict(msg, timeout=30)
    assert err.value.code() is grpc.StatusCode.NOT_FOUND and "sqpdnet_v9" in err.value.details()
    msg.model = "../etc"
    with pytest.raises(grpc.aio.AioRpcError) as err:
        await stub.Predict(msg, timeout=30)
    assert err.value.code() is grpc.StatusCode.INVALID_ARGUMENT
    msg.model = ""
    assert (await stub.Predict(msg, timeout=30)).num_actions == 2


async def test_named_checkpoints_next_to_the_default_are_served(served) -> None:
    _, _, stub, _, tmp_path = served
    other = save_checkpoint(tmp_path / "models" / "variant", seed=5)
    poses, params, actions = scene(2, 3)
    msg = convert.predict_request_to_proto(poses, params, actions, model="variant")
    got, _ = convert.predict_response_from_proto(await stub.Predict(msg, timeout=30))
    np.testing.assert_allclose(got, other.predict(poses, params, actions).numpy(), atol=2e-6)


@pytest.mark.parametrize(
    ("body", "status", "field"),
    [
        ({"objects": [{"size": [0.03] * 3, "shape": [0.2, 0.2],
          "pose": {"position": [0.4, 0, 0.03]}}], "actions": [[0.3, 0, 0.02, 0.05, 0]]},
         400, "actions"),
        ({"objects": [{"size": [0.03] * 2, "shape": [0.2, 0.2],
          "pose": {"position": [0.4, 0, 0.03]}}], "actions": [[0.3, 0, 0.02, 0.05, 0, 0]]},
         400, "objects[0].size"),
        ({"objects": [{"size": [0.03] * 3, "shape": [0.2, 0.2],
          "pose": {"position": [0.4, 0, 0.03]}}] * 5, "actions": [[0.3, 0, 0.02, 0.05, 0, 0]]},
         400, None),
        ({"objects": [{"size": [0.03] * 3, "shape": [0.2, 0.2],
          "pose": {"position": [0.4, 0, 0.03]}}], "actions": [[0.3, 0, 0.02, 0.05, 0, 0]] * 5,
          "model": "physics"}, 400, "actions"),
        ({"objects": [], "actions": "no"}, 422, "actions"),
    ],
)  # fmt: skip
async def test_gateway_errors_name_the_field(served, body, status, field) -> None:
    _, _, _, http, _ = served
    r = await http.post("/predict", json=body)
    assert r.status_code == status, r.text
    if field is not None:
        assert r.json()["field"] == field, r.json()
    else:
        assert "max_objects" in r.json()["detail"]


async def test_physics_model_runs_on_one_thread_and_reports_failures(served) -> None:
    _, _, stub, _, _ = served
    FakePhysics.threads.clear()
    poses, params, actions = scene(2, 4)
    msg = convert.predict_request_to_proto(poses, params, actions, model="physics")
    results = await asyncio.gather(*(stub.Predict(msg, timeout=30) for _ in range(3)))
    for res in results:
        got, failed = convert.predict_response_from_proto(res)
        np.testing.assert_allclose(
            got[:, :, 2, 3], np.broadcast_to(poses[:, 2, 3] + 0.01, (4, 2)), atol=1e-6
        )
        assert failed.tolist() == [False, True, False, True] and res.model == "physics"
    assert len(FakePhysics.threads) == 1 and threading.get_ident() not in FakePhysics.threads


async def test_async_sdk_predict_returns_typed_arrays(served) -> None:
    import sqmanip_client as sdk

    model, _, _, http, _ = served
    poses, params, actions = scene(2, 4, seed=2)
    parts = [
        sdk.SuperquadricPart("superellipsoid", tuple(params[i, :3]), (0.2, 0.2), 0.0, 0.0, 0.0,
                             sdk.Pose(**convert_pose(poses[i])))
        for i in range(2)
    ]  # fmt: skip
    client = sdk.AsyncClient("http://gw", http_client=http)
    result = await client.predict(parts, actions)
    assert isinstance(result, sdk.Prediction) and result.poses.shape == (4, 2, 4, 4)
    np.testing.assert_allclose(
        result.poses, model.predict(poses, params, actions).numpy(), atol=1e-5
    )
    with pytest.raises(sdk.NotFoundError):
        await client.predict(parts, actions, model="missing")
