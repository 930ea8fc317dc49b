"""The viewer's pure parts: stream decoding, colours, coalescing, pose and glyph geometry."""

from __future__ import annotations

import types

import numpy as np
import pytest
from sqmanip.geometry.types import Superquadric
from sqmanip.perception.types import RecognizedObject, Scene, SupportPlane
from sqmanip.rpc import convert
from sqmanip.settings import StackSettings
from sqmanip.v1 import planner_pb2, sim_pb2
from sqmanip.viewer import decode, draw
from sqmanip.viewer.controls import reduce_maps
from sqmanip.viewer.feeds import Feed


def test_scene_payload_decodes_to_the_recognized_objects():
    pose = np.eye(4)
    pose[:3, 3] = (0.5, 0.1, 0.05)
    sq = Superquadric(size=(0.03, 0.04, 0.05), shape=(0.3, 0.8), pose=pose)
    scene = Scene(
        [RecognizedObject(7, [sq], np.arange(4)), RecognizedObject(9, [sq, sq], np.arange(2))],
        SupportPlane((0.0, 0.0, 1.0), 0.0),
        {"total": 12.5},
    )
    payload = convert.scene_to_proto(scene).SerializeToString()
    update = decode.decode(decode.SCENE_KEY, payload)
    assert isinstance(update, decode.SceneUpdate)
    assert [o.id for o in update.scene.objects] == [7, 9]
    assert len(update.scene.objects[1].parts) == 2
    np.testing.assert_allclose(update.scene.objects[0].parts[0].pose[:3, 3], (0.5, 0.1, 0.05))
    assert update.scene.timings_ms == {"total": 12.5}


def test_observation_colours_come_from_the_rgb_pixel_of_each_point():
    h, w = 2, 3
    rgb = np.arange(h * w * 3, dtype=np.uint8).reshape(h, w, 3)
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32)
    pixels = np.array([5, 0, 3], dtype="<i4")
    msg = sim_pb2.Observation(camera="wrist", height=h, width=w, rgb=rgb.tobytes(),
                              point_pixels=pixels.tobytes())  # fmt: skip
    msg.cloud.CopyFrom(convert.cloud_to_proto(pts, None, np.array([0, -2, 1], dtype=np.int32)))
    update = decode.decode(decode.OBSERVATION_KEY, msg.SerializeToString())
    assert isinstance(update, decode.CloudUpdate)
    np.testing.assert_array_equal(update.rgb, rgb.reshape(-1, 3)[pixels])
    np.testing.assert_array_equal(update.labels, [0, -2, 1])
    assert update.source == "sim/wrist"


def test_large_clouds_are_subsampled_deterministically():
    idx = decode.subsample(1000, 100, seed=3)
    assert idx.shape == (100,) and np.all(np.diff(idx) > 0)
    np.testing.assert_array_equal(idx, decode.subsample(1000, 100, seed=3))
    np.testing.assert_array_equal(decode.subsample(50, 100), np.arange(50))
    with pytest.raises(ValueError, match="limit"):
        decode.subsample(10, 0)


def test_mpc_event_decodes_with_poses_by_object_id():
    msg = planner_pb2.EpisodeEvent(step=2, status="pushed", action=[0.4, 0, 0.02, 0.1, 0, 0])
    msg.predicted.add(object_id=1, x=0.5, y=0.0, z=0.03, yaw=0.2)
    update = decode.decode(decode.MPC_EPISODE_KEY, msg.SerializeToString())
    assert update.kind == "mpc" and update.event["step"] == 2
    assert update.event["predicted"] == {"1": [0.5, 0.0, 0.03, 0.2]}


def test_unknown_key_is_refused_by_name():
    with pytest.raises(ValueError, match="sqmanip/other"):
        decode.decode("sqmanip/other", b"")


def test_label_colours_and_colormap():
    c = decode.label_colors(np.array([0, 1, -1, -2, -3, 15]))
    assert tuple(c[0]) == decode.object_color(0) and tuple(c[5]) == decode.object_color(0)
    assert len({tuple(x) for x in c[2:5]}) == 3  # background, static, robot differ
    m = decode.colormap(np.array([0.0, 0.5, 1.0, np.nan]))
    assert tuple(m[0]) == (68, 1, 84) and tuple(m[2]) == (253, 231, 37)
    assert tuple(m[3]) == tuple(m[0])
    assert np.all(decode.colormap(np.zeros(3)) == m[0])


def test_feed_keeps_the_newest_frame_and_every_episode_event():
    feed = Feed(StackSettings())
    for key, payload in [
        (decode.OBSERVATION_KEY, b"o1"),
        (decode.MPC_EPISODE_KEY, b"e1"),
        (decode.OBSERVATION_KEY, b"o2"),
        (decode.MPC_EPISODE_KEY, b"e2"),
        (decode.SCENE_KEY, b"s1"),
    ]:
        feed.put(key, payload)
    got = [p for _, p in feed.take(timeout=0.1)]
    assert got == [b"e1", b"o2", b"e2", b"s1"]
    assert feed.take(timeout=0.01) == []


def test_search_maps_reduce_over_orientations():
    shape = (2, 3, 4)
    f = np.random.default_rng(0).random(shape)
    g = np.random.default_rng(1).random(shape)
    xy = np.stack(np.meshgrid(np.arange(2), np.arange(3), np.arange(4), indexing="ij"), -1)
    maps = types.SimpleNamespace(shape=shape, f=f, g=g, grid_xy=xy[..., :2].reshape(-1, 2))
    grid, fr, fg = reduce_maps(maps)
    assert grid.shape == (6, 2) and fr.shape == (6,)
    np.testing.assert_allclose(fr, f.max(-1).reshape(-1))
    np.testing.assert_allclose(fg, (f * g).max(-1).reshape(-1))
    np.testing.assert_array_equal(grid[4], (1, 1))


def test_yaw_pose_keeps_roll_and_pitch():
    from scipy.spatial.transform import Rotation

    t = np.eye(4)
    t[:3, :3] = Rotation.from_euler("xyz", (0.3, 0.0, 0.5)).as_matrix()
    out = draw.yaw_pose(t, 1.0, 2.0, 3.0, -0.4)
    assert np.arctan2(out[1, 0], out[0, 0]) == pytest.approx(-0.4)
    assert out[2, 2] == pytest.approx(t[2, 2])
    np.testing.assert_allclose(out[:3, 3], (1, 2, 3))


def test_gripper_glyph_fingers_are_width_apart_along_the_closing_axis():
    pose = np.eye(4)
    pose[:3, 3] = (0.5, 0.0, 0.1)
    segs = draw.gripper_segments(pose, 0.06)
    assert segs.shape == (4, 2, 3)
    assert segs[1, 0, 1] - segs[0, 0, 1] == pytest.approx(0.06)
    assert np.all(segs[:, :, 2] <= 0.1 + 1e-12)  # everything behind the pads (approach +z)
