"""Simulator domain <-> proto conversion (sim.proto): round trips through serialized bytes, and
size/field errors that name the field. Real values come from one in-process Simulator."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sqmanip.errors import ValidationError
from sqmanip.rpc import convert
from sqmanip.sim import Intrinsics, ObjectSpec, SceneSpec, Simulator
from sqmanip.v1 import sim_pb2

SCENE = SceneSpec(
    objects=(
        ObjectSpec("box", position=(0.42, -0.1, 0.025), size=(0.05, 0.05, 0.05), name="red box"),
        ObjectSpec("cylinder", position=(0.5, 0.1, 0.04), radius=0.03, height=0.08),
        ObjectSpec(
            "superquadric",
            position=(0.35, 0.12, 0.05),
            orientation=(0.0, 0.0, 0.3826834, 0.9238795),
            params=(0.03, 0.02, 0.05, 0.4, 0.8, 0.2, 0.0, 0.0, 0.0),
        ),
    ),
    seed=5,
)


@pytest.fixture(scope="module")
def sim():
    s = Simulator()
    s.reset(SCENE)
    yield s
    s.close()


def _wire(msg):
    return type(msg).FromString(msg.SerializeToString())


def _assert_states_equal(a, b) -> None:
    assert (a.time, a.scene_kind, a.held_object) == (b.time, b.scene_kind, b.held_object)
    np.testing.assert_allclose(a.joint_positions, b.joint_positions, atol=0)
    assert a.gripper_width == b.gripper_width
    np.testing.assert_allclose(a.tcp_pose, b.tcp_pose, atol=1e-9)
    assert len(a.objects) == len(b.objects)
    for oa, ob in zip(a.objects, b.objects, strict=True):
        assert (oa.id, oa.name, oa.kind) == (ob.id, ob.name, ob.kind)
        np.testing.assert_allclose(oa.pose, ob.pose, atol=1e-9)
        np.testing.assert_allclose(oa.position, ob.position, atol=1e-12)
        assert abs(abs(np.dot(oa.quaternion, ob.quaternion)) - 1.0) < 1e-9  # q ~ -q
        if oa.superquadric is None:
            assert ob.superquadric is None
        else:
            np.testing.assert_allclose(oa.superquadric.params(), ob.superquadric.params())
            assert oa.superquadric.kind == ob.superquadric.kind
            np.testing.assert_allclose(oa.superquadric.pose, ob.superquadric.pose, atol=1e-9)


def test_sim_state_round_trip_keeps_poses_joints_and_superquadrics(sim) -> None:
    state = sim.get_state()
    back = convert.sim_state_from_proto(_wire(convert.sim_state_to_proto(state)))
    _assert_states_equal(state, back)
    assert back.objects[0].name == "red box" and back.objects[2].superquadric.taper == 0.2


def test_held_object_survives_including_object_zero() -> None:
    msg = sim_pb2.SimState(held_object=0)
    assert convert.sim_state_from_proto(_wire(msg)).held_object == 0
    assert convert.sim_state_from_proto(sim_pb2.SimState()).held_object is None


def test_observation_round_trip_keeps_images_cloud_labels_and_truth(sim) -> None:
    obs = sim.observe(intrinsics=Intrinsics.scaled(160, 120))
    msg = _wire(convert.observation_to_proto(obs))
    assert (msg.height, msg.width) == (120, 160)
    assert len(msg.depth) == 4 * 120 * 160 and len(msg.rgb) == 3 * 120 * 160
    assert msg.cloud.num_points == obs.points.shape[0] > 0
    back = convert.observation_from_proto(msg)
    assert back.camera == obs.camera and back.intrinsics == obs.intrinsics
    np.testing.assert_array_equal(back.depth, obs.depth)
    np.testing.assert_array_equal(back.rgb, obs.rgb)
    np.testing.assert_array_equal(back.segmentation, obs.segmentation)
    np.testing.assert_array_equal(back.point_labels, obs.point_labels)
    np.testing.assert_array_equal(back.point_pixels, obs.point_pixels)
    # float32 on the wire: sub-micrometre error at these ranges
    assert back.points.dtype == np.float64
    assert np.abs(back.points - obs.points).max() < 1e-6
    np.testing.assert_allclose(back.camera_pose, obs.camera_pose, atol=1e-9)
    assert back.time == obs.time and len(back.objects) == 3
    back.depth[0, 0] = 1.0  # writable copies, not views of the message bytes


def test_observation_plane_size_mismatch_names_the_plane(sim) -> None:
    msg = convert.observation_to_proto(sim.observe(intrinsics=Intrinsics.scaled(32, 24)))
    bad = sim_pb2.Observation()
    bad.CopyFrom(msg)
    bad.depth = bad.depth[:-4]
    with pytest.raises(ValidationError, match=r"observation.depth: expected 24 x 32 float32"):
        convert.observation_from_proto(bad)
    bad.CopyFrom(msg)
    bad.point_pixels = b""
    with pytest.raises(ValidationError, match="observation.point_pixels"):
        convert.observation_from_proto(bad)


def test_action_result_round_trip(sim) -> None:
    sim.reset(SCENE)
    result = sim.push([0.36, -0.10, 0.02], [0.05, 0.0, 0.0])
    back = convert.action_result_from_proto(_wire(convert.action_result_to_proto(result)))
    assert (back.success, back.message, back.held_object) == (True, result.message, None)
    assert back.sim_time == result.sim_time > 0
    _assert_states_equal(result.before, back.before)
    _assert_states_equal(result.after, back.after)


def test_scene_spec_json_round_trip_through_a_reset_request() -> None:
    msg = _wire(convert.reset_request_to_proto(SCENE.to_dict()))
    kwargs = convert.reset_request_from_proto(msg)
    assert kwargs == {"scene": SCENE, "seed": None}
    seeded = convert.reset_request_from_proto(
        _wire(convert.reset_request_to_proto(seed=0, n_objects=0, kind="shelf"))
    )
    assert seeded == {"scene": None, "seed": 0, "n_objects": 0, "kind": "shelf"}
    assert convert.scene_spec_from_json(convert.scene_spec_to_json(SCENE)) == SCENE


@pytest.mark.parametrize(
    ("msg", "needle"),
    [
        (sim_pb2.ResetRequest(scene_json="{nope"), "scene_json: not valid JSON"),
        (sim_pb2.ResetRequest(scene_json="[1, 2]"), "scene_json: expected a JSON object"),
        (
            sim_pb2.ResetRequest(scene_json=json.dumps({"objects": [{"kind": "box", "sz": 1}]})),
            r"scene_json: unknown object fields \['sz'\]",
        ),
        (
            sim_pb2.ResetRequest(scene_json=json.dumps({"objects": [{"kind": "blob"}]})),
            "scene_json: object kind must be one of",
        ),
        (sim_pb2.ResetRequest(seed=1, kind="garden"), "kind: expected one of"),
        (sim_pb2.ResetRequest(seed=1, object_kinds=["mesh"]), "object_kinds: expected values"),
    ],
)
def test_bad_reset_requests_name_the_field(msg, needle) -> None:
    with pytest.raises(ValidationError, match=needle):
        convert.reset_request_from_proto(msg)


def test_action_requests_round_trip_and_require_their_poses() -> None:
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]
    T[:3, 3] = (0.45, 0.0, 0.03)
    pose, width = convert.grasp_request_from_proto(_wire(convert.grasp_request_to_proto(T, 0.06)))
    np.testing.assert_allclose(pose, T, atol=1e-12)
    assert width == 0.06
    g, w, place = convert.pick_and_place_request_from_proto(
        _wire(convert.pick_and_place_request_to_proto(T, 0.05, T @ np.diag([1, 1, 1, 1.0])))
    )
    np.testing.assert_allclose(place, T, atol=1e-12)
    p, v, upright = convert.push_request_from_proto(
        _wire(convert.push_request_to_proto([1, 2, 3], [4, 5, 6]))
    )
    assert p.tolist() == [1, 2, 3] and v.tolist() == [4, 5, 6] and upright is False
    assert convert.push_request_from_proto(
        _wire(convert.push_request_to_proto([1, 2, 3], [4, 5, 6], upright=True))
    )[2]
    with pytest.raises(ValidationError, match="pose: required"):
        convert.grasp_request_from_proto(sim_pb2.GraspRequest(width=0.05))
    with pytest.raises(ValidationError, match="place_pose: required"):
        convert.pick_and_place_request_from_proto(
            sim_pb2.PickAndPlaceRequest(grasp_pose=convert.pose_to_proto(T), width=0.05)
        )
    with pytest.raises(ValidationError, match="v: required"):
        convert.push_request_from_proto(sim_pb2.PushRequest(p=convert.vec3_to_proto([0, 0, 0])))


def test_observe_request_defaults_and_overrides() -> None:
    assert convert.observe_request_from_proto(sim_pb2.ObserveRequest()) == {
        "camera": "default",
        "intrinsics": None,
        "camera_pose": None,
        "noise": True,
    }
    k = Intrinsics.scaled(64, 48)
    T = np.eye(4)
    T[:3, 3] = (0.1, 0.2, 0.9)
    kw = convert.observe_request_from_proto(
        _wire(
            convert.observe_request_to_proto("overview", intrinsics=k, camera_pose=T, noise=False)
        )
    )
    assert kw["camera"] == "overview" and kw["intrinsics"] == k and kw["noise"] is False
    np.testing.assert_allclose(kw["camera_pose"], T)
    with pytest.raises(ValidationError, match="camera size"):
        convert.intrinsics_from_proto(sim_pb2.CameraIntrinsics(width=0, height=10, fx=1, fy=1))
