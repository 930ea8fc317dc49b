"""End to end (issue 5 item 2, issue 7 item 4): the launcher starts perception, grasp and dynamics
(and the gateway) on free loopback ports; ``POST /grasps`` plans on recognized objects and on a
raw point cloud, ``POST /predict`` answers exactly what the in-process model predicts from the
checkpoint the service loaded, and malformed requests are 4xx while the services keep
answering. One stack serves the whole module."""

from __future__ import annotations

import os

import httpx
import numpy as np
import pytest
import sqmanip_client as sdk
import torch
from sqmanip.dynamics.config import cpu_config
from sqmanip.dynamics.model import make_model
from sqmanip.launch import running_stack
from sqmanip.perception.synthetic import make_tabletop_scene

pytestmark = pytest.mark.integration

WORKSPACE_CENTRE = np.array([0.45, 0.0, 0.0])
"""Synthetic scenes are centred on the origin; the Panda (base at the origin) reaches 0.45 m out."""
FAST = {"n_samples": 64, "gripper_points": 256}


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    directory = tmp_path_factory.mktemp("models") / "sqpdnet"
    directory.mkdir()
    torch.manual_seed(3)
    config = cpu_config()
    model = make_model(config).eval()
    config.save(directory / "config.json")
    torch.save(model.state_dict(), directory / "model.pt")
    return directory, model


@pytest.fixture(scope="module")
def stack(model_dir):
    old = os.environ.get("SQMANIP_DYNAMICS_MODEL_DIR")
    os.environ["SQMANIP_DYNAMICS_MODEL_DIR"] = str(model_dir[0])
    try:
        with running_stack(services=("perception", "grasp", "dynamics"), zenoh=False) as s:
            yield s
    finally:
        if old is None:
            os.environ.pop("SQMANIP_DYNAMICS_MODEL_DIR", None)
        else:
            os.environ["SQMANIP_DYNAMICS_MODEL_DIR"] = old


@pytest.fixture(scope="module")
def client(stack):
    with sdk.Client(stack.gateway_url, timeout=60) as c:
        yield c


def box_part(x: float, y: float, half: float = 0.025) -> dict:
    return {
        "kind": "superellipsoid",
        "size": [half, half, half],
        "shape": [0.2, 0.2],
        "taper": 0.0,
        "bend": 0.0,
        "bend_direction": 0.0,
        "pose": {"position": [x, y, half], "orientation": [0.0, 0.0, 0.0, 1.0]},
    }


def test_lone_box_gets_narrow_grasps_with_contacts_on_the_box(client) -> None:
    objects = [{"id": 0, "parts": [box_part(0.45, 0.0)], "point_indices": [], "residual": 0.0}]
    plan = client.plan_grasps(objects, target_id=0, **FAST)
    grasps = plan.for_target(0).grasps
    assert len(grasps) > 0
    for g in grasps:
        assert g.width < 0.08
        local = np.abs(g.contacts - [0.45, 0.0, 0.025])
        assert np.all(local <= 0.025 + 2e-3)  # inside the box's bounds ...
        assert np.all(np.any(np.abs(local - 0.025) <= 2e-3, axis=1))  # ... and on a face
        assert g.pose.matrix()[2, 2] < 0.0  # the best grasps approach from above
    assert plan.support_plane.normal == (0.0, 0.0, 1.0)


def test_point_cloud_is_recognized_then_grasped(client) -> None:
    scene = make_tabletop_scene(2, seed=1, kinds=("box", "cylinder"))
    points = scene.points + WORKSPACE_CENTRE
    plan = client.plan_grasps(
        points=points, viewpoint=scene.viewpoint + WORKSPACE_CENTRE, **FAST, max_results=5
    )
    assert plan.objects is not None and len(plan.objects) == 2
    assert plan.support_plane is not None and abs(plan.support_plane.normal[2]) > 0.99
    assert [t.target_id for t in plan.targets] == [o.id for o in plan.objects]
    assert sum(len(t.grasps) for t in plan.targets) > 0
    for t in plan.targets:
        assert all(g.width < 0.08 for g in t.grasps)


def test_predict_equals_the_in_process_model(client, model_dir) -> None:
    _, model = model_dir
    rng = np.random.default_rng(0)
    n, k = 3, 16
    parts, poses, params = [], np.tile(np.eye(4), (n, 1, 1)), np.zeros((n, 9))
    for i in range(n):
        xy = WORKSPACE_CENTRE[:2] + rng.uniform(-0.15, 0.15, 2)
        half = rng.uniform(0.02, 0.04, 3)
        part = box_part(float(xy[0]), float(xy[1]))
        part["size"] = half.tolist()
        part["pose"]["position"] = [float(xy[0]), float(xy[1]), float(half[2])]
        parts.append(part)
        poses[i, :3, 3] = part["pose"]["position"]
        params[i] = [*half, 0.2, 0.2, 0, 0, 0, 0]
    actions = np.column_stack(
        [rng.uniform(0.3, 0.6, (k, 2)), np.full(k, 0.02), rng.normal(0, 0.05, (k, 2)), np.zeros(k)]
    ).astype(np.float32)
    result = client.predict(parts, actions)
    assert result.poses.shape == (k, n, 4, 4) and result.model == "sqpdnet"
    local = model.predict(poses, params, actions).numpy()
    np.testing.assert_allclose(result.poses, local, atol=1e-5)


def test_malformed_requests_are_4xx_and_the_services_keep_answering(stack, client) -> None:
    url = stack.gateway_url
    bad = [
        ("/grasps", {"objects": [{"id": 0, "parts": [box_part(0.45, 0)]}], "target_id": 7}, 404),
        (
            "/grasps",
            {"objects": [{"id": 0, "parts": [{**box_part(0.45, 0), "size": [1, 2]}]}]},
            400,
        ),
        ("/grasps", {"points": [[0, 0]], "target_id": 0}, 400),
        ("/grasps", {"objects": "nope"}, 422),
        ("/predict", {"objects": [box_part(0.45, 0)], "actions": [[1, 2, 3]]}, 400),
        ("/predict", {"objects": [box_part(0.45, 0)], "actions": [[0] * 6], "model": "nope"}, 404),
        ("/predict", {"objects": [box_part(0.45, 0)]}, 422),
    ]
    with httpx.Client(timeout=60) as http:
        for path, body, status in bad:
            r = http.post(url + path, json=body)
            assert r.status_code == status, (path, body, r.text)
            assert r.json()["detail"]
        r = http.post(
            url + "/grasps", content=b"{not json", headers={"content-type": "application/json"}
        )
        assert 400 <= r.status_code < 500
    health = client.health()
    assert health["status"] == "ok"
    assert {s["status"] for s in health["services"].values()} == {"SERVING"}
    assert client.predict([box_part(0.45, 0)], np.zeros((2, 6))).poses.shape == (2, 1, 4, 4)
    assert len(client.plan_grasps([{"id": 0, "parts": [box_part(0.45, 0)]}], **FAST).targets) == 1
