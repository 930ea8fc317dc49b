"""End to end (issue 4, items 5-6): the launcher starts the real stack (Zenoh router, perception,
sim, gateway) on free loopback ports; the simulator is driven through the gateway with the SDK
and raw HTTP, through gRPC with the CLI, and its observations are received over Zenoh.
One stack serves the whole module."""

from __future__ import annotations

import contextlib
import io
import json
import queue

import httpx
import numpy as np
import pytest
import sqmanip_client as sdk
from sqmanip import streams
from sqmanip.cli import main as cli_main
from sqmanip.launch import running_stack
from sqmanip.sim.server import OBSERVATION_KEY
from sqmanip.v1 import sim_pb2

pytestmark = pytest.mark.integration


def box(size, x, y) -> dict:
    return {"kind": "box", "size": list(size), "position": [x, y, size[2] / 2 + 1e-4]}


def top_grasp(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]
    T[:3, 3] = (x, y, z)
    return T


@pytest.fixture(scope="module")
def stack():
    with running_stack(services=("perception", "sim"), zenoh=True) as s:
        yield s


@pytest.fixture(scope="module")
def client(stack):
    with sdk.Client(stack.gateway_url, timeout=60) as c:
        yield c


def _surface_distance(obj: sdk.SimObject, points: np.ndarray) -> np.ndarray:
    """Distance of world points to a box's or cylinder's surface, from the ground truth."""
    T = obj.pose.matrix()
    local = (points - T[:3, 3]) @ T[:3, :3]
    a = np.asarray(obj.superquadric.size[:3])
    if obj.kind == "box":
        d = np.abs(local) - a
    else:  # cylinder: radius a1, half height a3
        d = np.stack([np.linalg.norm(local[:, :2], axis=1) - a[0], np.abs(local[:, 2]) - a[2]], 1)
    outside = np.linalg.norm(np.maximum(d, 0.0), axis=1)
    return np.abs(outside + np.minimum(d.max(axis=1), 0.0))


def test_reset_with_the_same_seed_gives_the_same_object_poses(client) -> None:
    a = client.sim_reset(seed=7, n_objects=3)
    b = client.sim_reset(seed=7, n_objects=3)
    assert len(a.state.objects) == 3
    for oa, ob in zip(a.state.objects, b.state.objects, strict=True):
        assert oa.pose == ob.pose
    c = client.sim_reset(seed=8, n_objects=3)
    assert c.state.objects[0].pose != a.state.objects[0].pose
    replay = client.sim_reset(scene=a.scene)  # the returned scene replays exactly
    for oa, orp in zip(a.state.objects, replay.state.objects, strict=True):
        np.testing.assert_allclose(oa.pose.position, orp.pose.position, atol=1e-9)


def test_observed_object_points_lie_near_the_ground_truth(client) -> None:
    client.sim_reset(seed=4, n_objects=3)
    obs = client.sim_observe()
    assert obs.depth.shape == (576, 640) and obs.rgb.shape == (576, 640, 3)
    assert obs.points.shape == (obs.num_points, 3) and obs.point_labels.shape == (obs.num_points,)
    assert obs.segmentation.dtype == np.int32 and obs.depth.dtype == np.float32
    seen = 0
    for o in obs.objects:
        pts = obs.points[obs.point_labels == o.id]
        if len(pts) < 50:  # hidden behind another object from the wrist camera
            continue
        seen += 1
        d = _surface_distance(o, pts.astype(np.float64))
        assert np.median(d) < 0.002, f"object {o.id}: median {np.median(d) * 1000:.2f} mm"
        assert np.mean(d < 0.005) > 0.98, f"object {o.id}"
    assert seen >= 2


def test_push_along_x_moves_a_box_along_x(client) -> None:
    client.sim_reset(scene={"objects": [box((0.05, 0.05, 0.05), 0.42, -0.10)]})
    res = client.sim_push([0.36, -0.10, 0.02], [0.12, 0.0, 0.0])
    assert res.success, res.message
    d = np.subtract(res.after.objects[0].pose.position, res.before.objects[0].pose.position)
    assert d[0] > 0.04 and abs(d[1]) < 0.02
    assert client.sim_state().objects[0].pose == res.after.objects[0].pose


def test_push_outside_the_workspace_is_400_naming_the_problem_then_service_answers(
    stack, client
) -> None:
    before = client.sim_reset(scene={"objects": [box((0.05, 0.05, 0.05), 0.45, 0.0)]})
    r = httpx.post(
        f"{stack.gateway_url}/sim/push", json={"p": [0.9, 0.0, 0.02], "v": [0.1, 0.0, 0.0]}
    )
    assert r.status_code == 400
    assert "push start p" in r.json()["detail"] and "out of workspace" in r.json()["detail"]
    with pytest.raises(sdk.BadRequestError, match="out of workspace"):
        client.sim_push([0.6, 0.0, 0.02], [0.2, 0.0, 0.0])
    with pytest.raises(sdk.BadRequestError, match="shelf scene only"):  # upright: shelf only
        client.sim_push([0.40, 0.0, 0.02], [0.1, 0.0, 0.0], upright=True)
    after = client.sim_state()  # still answering, and nothing moved
    assert after.joint_positions == before.state.joint_positions


def test_unreachable_grasp_is_400_with_the_reason(stack, client) -> None:
    client.sim_reset(scene={"objects": []})
    with pytest.raises(sdk.BadRequestError) as err:
        client.sim_grasp(top_grasp(1.2, 0.0, 0.05), 0.05)
    assert err.value.status == 400 and "unreachable" in err.value.detail
    r = httpx.post(
        f"{stack.gateway_url}/sim/grasp",
        json={"pose": {"position": [0.45, 0.0, 0.05], "orientation": [0, 0, 0, 0]}, "width": 0.05},
    )
    assert r.status_code == 422 and r.json()["field"] == "pose.orientation"


def test_grasp_release_and_pick_and_place_through_the_sdk(client) -> None:
    client.sim_reset(scene={"objects": [box((0.05, 0.05, 0.05), 0.40, -0.10)]})
    res = client.sim_pick_and_place(
        top_grasp(0.40, -0.10, 0.03), 0.08, top_grasp(0.50, 0.10, 0.035)
    )
    assert res.success, res.message
    assert np.linalg.norm(np.subtract(res.after.objects[0].pose.position[:2], [0.5, 0.1])) < 0.03
    grasped = client.sim_grasp(sdk.Pose((0.5, 0.1, 0.03), (1.0, 0.0, 0.0, 0.0)), 0.08)
    assert grasped.success and grasped.held_object == 0, grasped.message
    assert client.sim_release().after.held_object is None


def test_observe_summary_include_points_and_npz_download(stack) -> None:
    url = f"{stack.gateway_url}/sim/observe"
    body = {"intrinsics": {"width": 160, "height": 144}, "noise": False}
    summary = httpx.post(url, json=body, timeout=60).json()
    assert summary["points"] is None and summary["arrays"]["depth"]["shape"] == [144, 160]
    n = summary["num_points"]
    assert summary["arrays"]["points"] == {"shape": [n, 3], "dtype": "float32"}
    assert sum(summary["point_counts"].values()) == n
    full = httpx.post(url, json=body, params={"include": "points"}, timeout=60).json()
    assert len(full["points"]) == len(full["point_labels"]) == n
    r = httpx.post(url, json=body, params={"format": "npz"}, timeout=60)
    assert r.status_code == 200 and "observation.npz" in r.headers["content-disposition"]
    with np.load(io.BytesIO(r.content)) as npz:
        assert npz["depth"].shape == (144, 160) and npz["points"].shape == (n, 3)
        np.testing.assert_allclose(npz["points"], np.asarray(full["points"], np.float32))
        assert json.loads(npz["meta"].tobytes())["num_points"] == n
    bad = httpx.post(url, json={"camera": "ceiling"}, timeout=60)
    assert bad.status_code == 422 and bad.json()["field"] == "camera"


def test_zenoh_subscriber_receives_an_observation(stack, client) -> None:
    settings = stack.settings  # the stack's router endpoint; client mode, multicast off
    session, sub = streams.subscribe(OBSERVATION_KEY, settings)
    try:
        for _ in range(10):  # until the subscription has reached the sim's publisher
            obs = client.sim_observe(width=320, height=288, arrays=False)
            with contextlib.suppress(queue.Empty):
                key, payload = sub.get(timeout=2)
                break
        else:
            pytest.fail("no observation on Zenoh after 10 observes")
    finally:
        sub.close()
        session.close()
    assert key == OBSERVATION_KEY
    msg = sim_pb2.Observation.FromString(payload)
    assert (msg.width, msg.height) == (320, 288)
    assert msg.cloud.num_points == obs.num_points and len(msg.objects) == len(obs.objects)


async def test_async_client_drives_the_simulator(stack) -> None:
    async with sdk.AsyncClient(stack.gateway_url, timeout=60) as c:
        reset = await c.sim_reset(seed=3, n_objects=2)
        state = await c.sim_state()
        assert [o.pose for o in state.objects] == [o.pose for o in reset.state.objects]
        obs = await c.sim_observe("overview", width=96, height=72)
        assert obs.camera == "overview" and obs.depth.shape == (72, 96)
        with pytest.raises(sdk.BadRequestError, match="out of workspace"):
            await c.sim_push([0.9, 0.0, 0.02], [0.1, 0.0, 0.0])


def test_cli_reset_saves_a_scene_that_replays_and_observe_writes_npz(stack, tmp_path, capsys):
    address = stack.address("sim")
    scene = tmp_path / "scene.json"
    assert cli_main(["sim", "reset", "--seed", "5", "--n-objects", "2", "--save", str(scene),
                     "--address", address]) == 0  # fmt: skip
    first = capsys.readouterr().out
    assert "2 objects" in first and len(json.loads(scene.read_text())["objects"]) == 2
    assert cli_main(["sim", "reset", "--scene", str(scene), "--address", address]) == 0
    replay = capsys.readouterr().out
    assert first.splitlines()[1:4] == replay.splitlines()[1:4]  # same table of poses
    out = tmp_path / "frame.npz"
    assert cli_main(["sim", "observe", "--width", "64", "--height", "48", "--out", str(out),
                     "--address", address]) == 0  # fmt: skip
    with np.load(out) as npz:
        assert npz["depth"].shape == (48, 64) and npz["points"].shape[1] == 3
    assert cli_main(["sim", "observe", "--width", "5000", "--address", address]) == 1
    assert "camera size" in capsys.readouterr().err
