"""The GraspPlanner servicer in-process (grpc.aio on loopback) and the gateway's ``POST /grasps``
in front of it (ASGI in the same loop): RemoteGraspPlanner equals the in-process planner, status
codes map to HTTP (bad values 400 naming the field, unknown target id 404, model errors 422),
and the server keeps answering after errors."""

from __future__ import annotations

import grpc
import httpx
import numpy as np
import pytest
from sqmanip.errors import NotFoundError, ValidationError
from sqmanip.gateway.app import create_app
from sqmanip.gateway.config import GatewaySettings
from sqmanip.geometry import Superquadric
from sqmanip.grasping import Environment, GraspPlanner, PlanOptions, WorkspaceReachability
from sqmanip.grasping.server import GraspPlannerServicer, registrar
from sqmanip.rpc import convert
from sqmanip.rpc.client import RemoteGraspPlanner, aio_channel
from sqmanip.rpc.server import start_server
from sqmanip.settings import StackSettings
from sqmanip.v1 import grasp_pb2_grpc

FAST = PlanOptions(n_samples=64, gripper_points=128, max_results=10)


def box(x: float, y: float, size=(0.05, 0.05, 0.05)) -> Superquadric:
    T = np.eye(4)
    T[:3, 3] = (x, y, size[2] / 2)
    return Superquadric(size=tuple(s / 2 for s in size), shape=(0.2, 0.2), pose=T)


def part_json(sq: Superquadric) -> dict:
    return {
        "kind": sq.kind,
        "size": list(sq.size),
        "shape": list(sq.shape),
        "pose": {"position": sq.pose[:3, 3].tolist(), "orientation": [0, 0, 0, 1]},
    }


def on_box_surface(points: np.ndarray, sq: Superquadric, tol: float = 2e-3) -> np.ndarray:
    local = np.abs(points - sq.pose[:3, 3])
    a = np.asarray(sq.size)
    inside = np.all(local <= a + tol, axis=1)
    on_face = np.any(np.abs(local - a) <= tol, axis=1)
    return inside & on_face


@pytest.fixture
async def served():
    planner = GraspPlanner(WorkspaceReachability(), options=FAST)
    servicer = GraspPlannerServicer(planner)
    running = await start_server(registrar(servicer), StackSettings(), port=0)
    address = f"127.0.0.1:{running.port}"
    channel = aio_channel(address)
    app = create_app(GatewaySettings(gateway_services=["grasp"], request_timeout_s=60))
    app.state.channels = {"grasp": channel}  # ASGITransport runs no lifespan
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://gw") as http:
        yield planner, address, grasp_pb2_grpc.GraspPlannerStub(channel), http
    await channel.close()
    await running.stop(0)
    servicer.close()


async def test_remote_planner_equals_the_in_process_planner(served) -> None:
    planner, address, _, _ = served
    target, neighbour = [box(0.45, 0.0)], [box(0.45, 0.09)]
    local = planner.plan(target, [neighbour], Environment.table(), options=FAST)
    import asyncio

    def remote():
        with RemoteGraspPlanner(address) as rp:
            return rp.plan(target, [neighbour], Environment.table(), options=FAST)

    got = await asyncio.to_thread(remote)
    assert len(got) == len(local) > 0
    for a, b in zip(got, local, strict=True):
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-9)
        np.testing.assert_allclose(a.contacts, b.contacts, atol=1e-12)
        assert a.width == pytest.approx(b.width) and a.score == pytest.approx(b.score)


async def test_grpc_errors_map_to_status_codes_and_the_server_keeps_answering(served) -> None:
    _, _, stub, _ = served
    msg = convert.plan_grasps_request_to_proto([box(0.45, 0)], options=FAST)
    msg.target_id = 3
    with pytest.raises(grpc.aio.AioRpcError) as err:
        await stub.Plan(msg, timeout=60)
    assert err.value.code() is grpc.StatusCode.NOT_FOUND
    assert "target_id" in err.value.details()
    msg.target_id = 0
    msg.options.n_samples = 0
    with pytest.raises(grpc.aio.AioRpcError) as err:
        await stub.Plan(msg, timeout=60)
    assert err.value.code() is grpc.StatusCode.INVALID_ARGUMENT
    assert err.value.details().startswith("options.n_samples")
    msg.options.n_samples = 64
    ok = await stub.Plan(msg, timeout=60)
    assert len(ok.grasps) > 0 and ok.stats.n_candidates > 0


async def test_remote_planner_raises_domain_exceptions(served) -> None:
    import asyncio

    _, address, _, _ = served

    def call(**kw):
        with RemoteGraspPlanner(address) as rp:
            return rp.plan([box(0.45, 0)], options=FAST, **kw)

    with pytest.raises(ValidationError, match="observed_points"):
        await asyncio.to_thread(call, observed_points=np.zeros((4, 2)))
    opts = PlanOptions(n_samples=64, gripper_points=128, score="uncertainty")
    with pytest.raises(ValidationError, match="observed_points"):
        await asyncio.to_thread(
            lambda: RemoteGraspPlanner(address).plan([box(0.45, 0)], options=opts)
        )
    assert NotFoundError.code == "NOT_FOUND"


async def test_reachability_check_can_be_skipped_per_request(served) -> None:
    _, _, _, http = served
    far = {"objects": [{"id": 0, "parts": [part_json(box(1.5, 0.0))]}], "target_id": 0,
           "options": {"n_samples": 64, "gripper_points": 128}}  # fmt: skip
    r = await http.post("/grasps", json=far)
    assert r.status_code == 200, r.text
    target = r.json()["targets"][0]
    assert target["grasps"] == [] and target["stats"]["n_unreachable"] > 0
    far["options"]["check_reachability"] = False
    r = await http.post("/grasps", json=far)
    assert r.status_code == 200 and len(r.json()["targets"][0]["grasps"]) > 0


async def test_gateway_plans_every_object_with_the_others_as_obstacles(served) -> None:
    _, _, _, http = served
    a, b = box(0.45, 0.0), box(0.45, 0.15, (0.04, 0.12, 0.06))
    body = {
        "objects": [{"id": 4, "parts": [part_json(a)]}, {"id": 9, "parts": [part_json(b)]}],
        "options": {"n_samples": 64, "gripper_points": 128, "max_results": 5},
    }
    r = await http.post("/grasps", json=body)
    assert r.status_code == 200, r.text
    out = r.json()
    assert [t["target_id"] for t in out["targets"]] == [4, 9]
    assert out["support_plane"] == {"normal": [0.0, 0.0, 1.0], "offset": 0.0}
    for t, sq in zip(out["targets"], (a, b), strict=True):
        assert 0 < len(t["grasps"]) <= 5
        scores = np.round([g["score"] for g in t["grasps"]], 6)  # ranked at 6 decimals
        assert (np.diff(scores) <= 0).all()
        for g in t["grasps"]:
            assert g["width"] < 0.08 and len(g["pose"]["orientation"]) == 4
            assert on_box_surface(np.asarray(g["contacts"]), sq).all()


@pytest.mark.parametrize(
    ("body", "status", "field"),
    [
        ({"objects": [{"id": 0, "parts": [{"size": [0.02, 0.02], "shape": [0.2, 0.2],
          "pose": {"position": [0.45, 0, 0.02]}}]}]}, 400, "objects[0].parts[0].size"),
        ({"objects": [{"id": 0, "parts": [{"size": [0.02, 0.02, -0.02], "shape": [0.2, 0.2],
          "pose": {"position": [0.45, 0, 0.02]}}]}]}, 400, "objects[0].parts[0]"),
        ({"objects": [{"id": 0, "parts": [{"size": [0.02] * 3, "shape": [0.2, 0.2],
          "pose": {"position": [0.45, 0, 0.02]}}]}], "target_id": 5}, 404, "target_id"),
        ({"objects": [{"id": 0, "parts": [{"size": [0.02] * 3, "shape": [0.2, 0.2],
          "pose": {"position": [0.45, 0, 0.02]}}]}], "options": {"n_samples": 0}}, 400,
         "options.n_samples"),
        ({"objects": [{"id": 0, "parts": [{"size": [0.02] * 3, "shape": [0.2, 0.2],
          "pose": {"position": [0.45, 0, 0.02]}}]}], "gripper": {"max_opening": -1}}, 400,
         "gripper.max_opening"),
        ({"objects": [{"id": 0, "parts": []}]}, 422, "objects.0.parts"),
        ({"target_id": 0}, 422, "body"),
        ({"objects": [{"id": 0, "parts": [{"size": [0.02] * 3, "shape": [0.2, 0.2],
          "pose": {"position": [0.45, 0, 0.02]}}]}], "options": {"score": "best"}}, 422,
         "options.score"),
    ],
)  # fmt: skip
async def test_gateway_errors_name_the_field(served, body, status, field) -> None:
    _, _, _, http = served
    r = await http.post("/grasps", json=body)
    assert r.status_code == status, r.text
    assert r.json()["field"] == field, r.json()
