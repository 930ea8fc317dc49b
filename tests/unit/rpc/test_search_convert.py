"""search.proto <-> sqmanip.search: Evaluate requests/responses and episode requests/events round
trip; malformed messages raise ValidationError naming the field."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric
from sqmanip.rpc import convert
from sqmanip.search.episode import EpisodeResult, StepEvent
from sqmanip.search.shelf import ShelfSpec, TargetSpec
from sqmanip.v1 import search_pb2


def shelf_box(x: float, y: float) -> Superquadric:
    T = np.eye(4)
    T[:3, 3] = [x, y, 0.28]
    return Superquadric(size=(0.03, 0.1, 0.08), shape=(0.2, 0.2), pose=T)


def test_evaluate_request_round_trip():
    shelf = ShelfSpec(front_x=0.55, depth=0.3)
    cam = shelf.camera(320, 180)
    pose = np.eye(4)
    pose[:3, 3] = [0.7, 0.05, 0.25]
    msg = convert.evaluate_request_to_proto(
        [shelf_box(0.62, 0.0)], TargetSpec.box(0.04, 0.06, 0.1), shelf, cam,
        target_visible=True, target_pose=pose, resolution=0.03, n_theta=4,
    )  # fmt: skip
    args = convert.evaluate_request_from_proto(
        search_pb2.EvaluateRequest.FromString(msg.SerializeToString())
    )
    assert args.shelf == shelf and args.target == TargetSpec.box(0.04, 0.06, 0.1)
    assert (args.camera.width, args.camera.height) == (320, 180)
    np.testing.assert_allclose(args.camera.pose, cam.pose, atol=1e-9)
    np.testing.assert_allclose(args.target_pose, pose)
    assert (args.resolution, args.n_theta, args.target_visible) == (0.03, 4, True)
    np.testing.assert_allclose(args.objects[0].pose, shelf_box(0.62, 0.0).pose)


def test_evaluate_request_defaults_and_errors():
    args = convert.evaluate_request_from_proto(convert.evaluate_request_to_proto([]))
    assert args.shelf == ShelfSpec() and args.target.kind == "cylinder"
    assert (args.camera.width, args.camera.height) == (1280, 720)
    assert (args.resolution, args.n_theta, args.target_pose) == (0.02, 8, None)
    with pytest.raises(ValidationError, match="^target_pose:"):
        convert.evaluate_request_from_proto(search_pb2.EvaluateRequest(target_visible=True))
    with pytest.raises(ValidationError, match="^resolution:"):
        convert.evaluate_request_from_proto(convert.evaluate_request_to_proto([], resolution=0.0))
    bad = convert.evaluate_request_to_proto([], TargetSpec.cylinder(0.02, 0.1))
    bad.target.size.y = 0.05  # a cylinder needs a1 == a2
    with pytest.raises(ValidationError, match="^target"):
        convert.evaluate_request_from_proto(bad)


def test_evaluate_response_round_trip():
    rng = np.random.default_rng(0)
    shape = (4, 5)
    r = convert.EvaluateResult(
        shape=shape, f=(rng.random(shape) > 0.5).astype(np.float32),
        g=rng.random(shape).astype(np.float32), g_m=rng.random(shape).astype(np.float32),
        grid_xy=rng.random((20, 2)).astype(np.float32), resolution=0.02, objective=3.5,
        timings_ms={"f_g": 1.0},
    )  # fmt: skip
    msg = convert.evaluate_response_to_proto(r)
    assert len(msg.f) == 4 * 20
    back = convert.evaluate_response_from_proto(
        search_pb2.EvaluateResponse.FromString(msg.SerializeToString())
    )
    assert back.shape == shape and back.f.shape == shape
    for name in ("f", "g", "g_m", "grid_xy"):
        np.testing.assert_array_equal(getattr(back, name), getattr(r, name))
    assert (back.objective, back.resolution, back.timings_ms) == (3.5, 0.02, {"f_g": 1.0})
    msg.g = msg.g[:-4]
    with pytest.raises(ValidationError, match="^g:"):
        convert.evaluate_response_from_proto(msg)


def test_search_episode_request_round_trip_and_errors():
    scenario = {"n_objects": 1, "seed": 3, "scene": {"kind": "shelf", "objects": []},
                "target": {"size": [0.025, 0.025, 0.05]}}  # fmt: skip
    msg = convert.search_episode_request_to_proto(
        scenario, method="search_and_grasp", shapes="recognized", actions="push",
        dynamics_model="sqpdnet", max_steps=3, num_sequences=5, plan_seed=9,
    )  # fmt: skip
    a = convert.search_episode_request_from_proto(msg)
    assert a.scenario == scenario
    assert (a.method, a.shapes, a.actions, a.dynamics_model) == (
        "search_and_grasp", "recognized", "push", "sqpdnet",
    )  # fmt: skip
    assert (a.max_steps, a.num_sequences, a.plan_seed) == (3, 5, 9)
    d = convert.search_episode_request_from_proto(convert.search_episode_request_to_proto())
    assert (d.scenario, d.n_objects, d.method, d.shapes, d.dynamics_model) == (
        None, 2, "search_for_grasp", "oracle", "kinematic",
    )  # fmt: skip
    with pytest.raises(ValidationError, match="^method:"):
        convert.search_episode_request_from_proto(search_pb2.SearchEpisodeRequest(method="x"))
    with pytest.raises(ValidationError, match="^scenario_json:"):
        convert.search_episode_request_from_proto(
            search_pb2.SearchEpisodeRequest(scenario_json="{]")
        )
    with pytest.raises(ValidationError, match="^n_objects:"):
        convert.search_episode_request_from_proto(search_pb2.SearchEpisodeRequest(n_objects=40))


def test_search_event_and_result_to_dicts():
    ev = StepEvent(
        step=1, action="push", params={"start": np.array([0.6, 0.1, 0.28]), "objective": -0.5},
        f_sum=12.0, fg_sum=3.0, visible=False, graspable=False, target_pixels=7,
        executed=True, message="pushed", timings_ms={"observe": 5.0},
        f_map=np.ones((2, 2)),
    )  # fmt: skip
    d = convert.search_event_from_proto(convert.search_event_to_proto(ev))
    assert d["params"] == {"start": [0.6, 0.1, 0.28], "objective": -0.5}
    assert (d["step"], d["action"], d["f_sum"], d["fg_sum"], d["target_pixels"]) == (
        1, "push", 12.0, 3.0, 7,
    )  # fmt: skip
    assert d["executed"] and not d["visible"] and d["timings_ms"] == {"observe": 5.0}
    res = EpisodeResult(True, False, 0, None, 2, "step limit (2) reached", [])
    scen = json.dumps({"n_objects": 1})
    out = convert.search_event_from_proto(
        convert.search_result_to_proto(res, wall_s=4.0, scenario_json=scen)
    )
    assert out["result"] == {
        "found": True, "grasped": False, "find_steps": 0, "grasp_steps": None, "steps": 2,
        "reason": "step limit (2) reached", "wall_s": 4.0, "scenario": {"n_objects": 1},
    }  # fmt: skip
