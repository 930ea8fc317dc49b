"""The Planner and Search servicers in-process (grpc.aio on loopback): ``Plan`` goes through a
real Dynamics servicer (with a stand-in physics model that moves every object by the push) and
picks the push toward the goal; malformed tasks are INVALID_ARGUMENT naming the field; a missing
dynamics / simulator service is UNAVAILABLE within seconds, not a hang; ``Evaluate`` answers maps
of the pose grid's shape; the gateway maps all of it to HTTP (400 / 503 / 404)."""

from __future__ import annotations

import time

import grpc
import httpx
import numpy as np
import pytest
import torch
from sqmanip.dynamics.server import DynamicsServicer, DynamicsServiceSettings
from sqmanip.dynamics.server import registrar as dynamics_registrar
from sqmanip.gateway.app import create_app
from sqmanip.gateway.config import GatewaySettings
from sqmanip.geometry import Superquadric
from sqmanip.grasping.config import WorkspaceReachability
from sqmanip.launch import settings_on_free_ports
from sqmanip.planning.mpc import ROBOT_BASE
from sqmanip.planning.server import PlannerServicer
from sqmanip.planning.server import registrar as planner_registrar
from sqmanip.planning.tasks import GraspingTask, MovingTask
from sqmanip.rpc import convert
from sqmanip.rpc.client import aio_channel
from sqmanip.rpc.server import start_server
from sqmanip.search.server import SearchServicer
from sqmanip.search.server import registrar as search_registrar
from sqmanip.search.shelf import ShelfSpec, TargetSpec, make_pose_grid
from sqmanip.v1 import planner_pb2_grpc, search_pb2_grpc


class Shift:
    """Physics stand-in: every object moves by the push's displacement."""

    def predict(self, poses, params, actions, kinds=None):
        poses = np.asarray(poses, dtype=np.float64)
        actions = np.asarray(actions, dtype=np.float64)
        out = np.repeat(poses[None], len(actions), axis=0)
        out[:, :, :3, 3] += actions[:, None, 3:]
        self.last_failed = np.zeros(len(actions), dtype=bool)
        return torch.as_tensor(out)


def box(x: float, y: float) -> Superquadric:
    T = np.eye(4)
    T[:3, 3] = [x, y, 0.03]
    return Superquadric(size=(0.03, 0.03, 0.03), shape=(0.2, 0.2), pose=T)


@pytest.fixture
async def served(tmp_path):
    # sim, perception, dynamics addresses on free ports where nothing listens ...
    settings = settings_on_free_ports(zenoh_enabled=False)
    dyn = DynamicsServicer(
        DynamicsServiceSettings(model_dir=tmp_path / "none"), physics_factory=Shift
    )
    dyn_running = await start_server(dynamics_registrar(dyn), settings, port=0)
    # ... but the planner's dynamics is the servicer above
    planner_settings = settings.model_copy(update={"dynamics_port": dyn_running.port})
    planner = PlannerServicer(planner_settings,
                              reachability=WorkspaceReachability(base=ROBOT_BASE))  # fmt: skip
    search = SearchServicer(settings)
    p_running = await start_server(planner_registrar(planner), settings, port=0)
    s_running = await start_server(search_registrar(search), settings, port=0)
    channels = {
        "mpc": aio_channel(f"127.0.0.1:{p_running.port}"),
        "search": aio_channel(f"127.0.0.1:{s_running.port}"),
    }
    app = create_app(GatewaySettings(gateway_services=["mpc", "search"], request_timeout_s=30))
    app.state.channels = channels
    async with httpx.AsyncClient(
        transport=httpx.ASGITransport(app=app), base_url="http://gw"
    ) as http:
        yield (
            planner_pb2_grpc.PlannerStub(channels["mpc"]),
            search_pb2_grpc.SearchStub(channels["search"]),
            http,
            planner,
        )
    for ch in channels.values():
        await ch.close()
    for r in (p_running, s_running, dyn_running):
        await r.stop(0)
    planner.close()
    search.close()
    dyn.close()


async def test_plan_chooses_the_push_toward_the_goal(served) -> None:
    stub, _, _, _ = served
    task = MovingTask.to_positions({0: [0.65, 0.0, 0.03]})
    msg = convert.plan_request_to_proto([([box(0.55, 0.0)], 0)], task, num_sequences=16,
                                        seed=0, dynamics_model="physics")  # fmt: skip
    r = convert.plan_response_from_proto(await stub.Plan(msg, timeout=30))
    assert r.action is not None and r.n_candidates == 16
    moved = r.predicted_next[0][:2, 3]
    # the stand-in moves the box by v: the best of 16 pushes points roughly along +x
    assert r.action[3] > 0.05 and np.linalg.norm(moved - [0.65, 0.0]) < 0.05
    assert r.cost < r.current_cost


async def test_malformed_tasks_are_invalid_argument_and_the_service_keeps_answering(
    served,
) -> None:
    stub, _, http, _ = served
    objs = [([box(0.55, 0.0)], 0)]
    for task, opts, field in [
        (GraspingTask(4), {}, "task.target_id"),
        (MovingTask.to_positions({0: [2.0, 0.0, 0.03]}), {}, "task.goals[0]"),
        (MovingTask.to_positions({0: [0.6, 0.0, 0.03]}), {"num_sequences": 0},
         "options.num_sequences"),
        (MovingTask.to_positions({0: [0.6, 0.0, 0.03]}), {"dynamics_model": "physics"},
         "options.num_sequences"),  # physics needs an explicit, small K
    ]:  # fmt: skip
        with pytest.raises(grpc.aio.AioRpcError) as err:
            await stub.Plan(convert.plan_request_to_proto(objs, task, **opts), timeout=30)
        assert err.value.code() == grpc.StatusCode.INVALID_ARGUMENT
        assert err.value.details().startswith(field + ":"), err.value.details()
    body = {
        "objects": [{"id": 0, "parts": [{"size": [0.03, 0.03, 0.03], "shape": [0.2, 0.2],
                                         "pose": {"position": [0.55, 0, 0.03]}}]}],
        "task": {"kind": "moving", "goals": [{"id": 3, "position": [0.6, 0, 0.03]}]},
        "options": {"num_sequences": 4, "dynamics_model": "physics"},
    }  # fmt: skip
    r = await http.post("/plan", json=body)
    assert r.status_code == 400 and r.json()["field"] == "task.goals"
    body["task"]["goals"][0]["id"] = 0
    r = await http.post("/plan", json=body)
    assert r.status_code == 200 and r.json()["has_action"], r.text


async def test_missing_dynamics_is_unavailable_quickly(served) -> None:
    stub, _, _, planner = served
    planner.settings = planner.settings.model_copy(
        update={"dynamics_port": settings_on_free_ports().dynamics_port}
    )
    planner._dynamics = None
    msg = convert.plan_request_to_proto(
        [([box(0.55, 0.0)], 0)], MovingTask.to_positions({0: [0.6, 0.0, 0.03]}),
        num_sequences=4, dynamics_model="physics",
    )  # fmt: skip
    t0 = time.monotonic()
    with pytest.raises(grpc.aio.AioRpcError) as err:
        await stub.Plan(msg, timeout=20)
    assert err.value.code() == grpc.StatusCode.UNAVAILABLE
    assert time.monotonic() - t0 < 5.0


async def test_episodes_without_a_simulator_are_503(served) -> None:
    _, search, http, _ = served
    t0 = time.monotonic()
    r = await http.post("/search/episodes", json={"n_objects": 2})
    assert r.status_code == 503 and "sim service unavailable" in r.json()["detail"], r.text
    r = await http.post("/mpc/episodes", json={"kind": "moving", "objects": "ground_truth"})
    assert r.status_code == 503 and "sim service unavailable" in r.json()["detail"], r.text
    assert time.monotonic() - t0 < 8.0
    with pytest.raises(grpc.aio.AioRpcError) as err:
        async for _ in search.RunEpisode(convert.search_episode_request_to_proto(), timeout=20):
            pass
    assert err.value.code() == grpc.StatusCode.UNAVAILABLE
    assert (await http.get("/search/episodes/unknown")).status_code == 404
    assert (await http.get("/mpc/episodes/unknown")).status_code == 404
    r = await http.post("/search/episodes", json={"method": "nope"})
    assert r.status_code == 422 and r.json()["field"] == "method"


async def test_evaluate_answers_maps_of_the_grid_shape(served) -> None:
    _, search, _, _ = served
    shelf = ShelfSpec()
    target = TargetSpec.cylinder(0.025, 0.10)
    T = np.eye(4)
    T[:3, 3] = [shelf.front_x + 0.10, 0.0, shelf.bottom_z + 0.08]
    wall = Superquadric(size=(0.03, 0.12, 0.08), shape=(0.2, 0.2), pose=T)
    msg = convert.evaluate_request_to_proto(
        [wall], target, shelf, shelf.camera(320, 180), resolution=0.04
    )
    r = convert.evaluate_response_from_proto(await search.Evaluate(msg, timeout=60))
    grid = make_pose_grid(shelf, target, 0.04)
    assert r.shape == tuple(grid.shape) and r.f.shape == r.g.shape == tuple(grid.shape)
    np.testing.assert_allclose(r.grid_xy, grid.xy.numpy(), atol=1e-6)
    hidden = r.grid_xy[r.f.reshape(-1) > 0]
    assert len(hidden) > 0 and np.all(hidden[:, 0] > T[0, 3])
    bad = convert.evaluate_request_to_proto([wall], resolution=0.5)
    with pytest.raises(grpc.aio.AioRpcError) as err:
        await search.Evaluate(bad, timeout=10)
    assert err.value.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert err.value.details().startswith("resolution:")
