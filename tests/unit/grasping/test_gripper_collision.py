"""The gripper point cloud (B.5, C.3) and implicit-function collision checks (3.7.15, B.5.12)."""

import numpy as np
import pytest
import torch
from grasp_helpers import box, dense_min_implicit, pose
from hypothesis import given, settings
from hypothesis import strategies as st
from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric
from sqmanip.grasping import (
    PANDA_HAND,
    Environment,
    GripperSpec,
    build_scene,
    check_collisions,
    gripper_boxes,
    gripper_points,
    transform_gripper_points,
)


def top_down(x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    """Gripper pose pointing straight down (approach -z), closing axis at ``yaw`` from world x."""
    T = np.eye(4)
    y_ax = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    z_ax = np.array([0.0, 0.0, -1.0])
    T[:3, :3] = np.stack([np.cross(y_ax, z_ax), y_ax, z_ax], -1)
    T[:3, 3] = (x, y, z)
    return T


def _on_box_surface(p: np.ndarray, lo: np.ndarray, hi: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    inside = ((p >= lo - tol) & (p <= hi + tol)).all(-1)
    on_face = (np.abs(p - lo) < tol).any(-1) | (np.abs(p - hi) < tol).any(-1)
    return inside & on_face


def test_gripper_points_lie_on_the_boxes_with_about_the_requested_count():
    pts = gripper_points(PANDA_HAND, 512)
    assert 0.9 * 512 <= len(pts) <= 1.1 * 512
    boxes = gripper_boxes(PANDA_HAND)
    on_any = np.zeros(len(pts), dtype=bool)
    for lo, hi in boxes:
        on_any |= _on_box_surface(pts, lo, hi)
    assert on_any.all()
    # open fingers: inner faces at +-max_opening / 2, fingertips tip_offset past the TCP
    assert np.isclose(pts[:, 2].max(), PANDA_HAND.tip_offset)
    fingers = pts[pts[:, 2] > PANDA_HAND.palm_bottom + 1e-9]  # nothing between the open fingers
    assert np.abs(fingers[:, 1]).min() >= PANDA_HAND.max_opening / 2 - 1e-12
    assert np.isclose(pts[:, 2].min(), -PANDA_HAND.flange_offset)


def test_swept_gripper_with_wrist_reaches_back_along_the_approach():
    pts = gripper_points(PANDA_HAND, 2048, include_wrist=True, approach_distance=0.3)
    assert 0.9 * 2048 <= len(pts) <= 1.1 * 2048
    lowest = -PANDA_HAND.flange_offset - 0.3 - PANDA_HAND.wrist_length
    assert np.isclose(pts[:, 2].min(), lowest)
    assert np.isclose(pts[:, 2].max(), PANDA_HAND.tip_offset)


def test_gripper_spec_validation_names_the_field():
    with pytest.raises(ValidationError, match="max_opening"):
        GripperSpec(max_opening=-0.01)
    with pytest.raises(ValidationError, match="palm_size"):
        GripperSpec(max_opening=0.3)
    with pytest.raises(ValidationError, match="n_points"):
        gripper_points(PANDA_HAND, 3)


def test_transform_gripper_points_matches_the_pose():
    T = top_down(0.4, 0.1, 0.2, yaw=0.7)
    world = transform_gripper_points(
        torch.as_tensor(T[None]), np.array([[0.0, 0.0, 0.0], [0, 0, 1]])
    )
    assert torch.allclose(world[0, 0], torch.tensor([0.4, 0.1, 0.2], dtype=torch.float64))
    assert torch.allclose(world[0, 1], torch.tensor([0.4, 0.1, -0.8], dtype=torch.float64))
    with pytest.raises(ValidationError, match=r"\(K, 4, 4\)"):
        transform_gripper_points(torch.eye(4), np.zeros((1, 3)))


def test_support_plane_collision_by_signed_distance():
    env = Environment.table(height=0.1)
    scene = build_scene(env, clearance=0.0)
    pts = gripper_points(PANDA_HAND)
    tip = PANDA_HAND.tip_offset
    poses = np.stack([top_down(0.5, 0, 0.1 + tip + 0.001), top_down(0.5, 0, 0.1 + tip - 0.001)])
    res = check_collisions(scene, transform_gripper_points(torch.as_tensor(poses), pts))
    assert res.collides.tolist() == [False, True]
    assert res.obstacle_labels() == [None, "support"]


def test_a_gripper_next_to_a_neighbour_collides_and_names_it():
    target = box((0.02, 0.05, 0.04), pose(0.5, 0.0, 0.04))
    neighbour = box((0.02, 0.05, 0.04), pose(0.545, 0.0, 0.04))  # 5 mm gap
    scene = build_scene(Environment.table(), [[neighbour]], [target])
    pts = gripper_points(PANDA_HAND)
    across_x = top_down(0.5, 0.0, 0.06, yaw=0.0)  # right finger lands in the neighbour
    far = across_x.copy()
    far[0, 3] = 0.2  # same grasp on an empty spot of the table
    res = check_collisions(
        scene, transform_gripper_points(torch.as_tensor(np.stack([across_x, far])), pts)
    )
    assert res.collides.tolist() == [True, False]
    assert res.obstacle_labels()[0] == "object:0"
    assert scene.labels == ("support", "object:0", "target")
    assert res.per_obstacle[0].tolist() == [False, True, False]


def test_boxes_of_the_environment_are_obstacles():
    shelf_board = Superquadric((0.2, 0.2, 0.01), (0.2, 0.2), pose(0.5, 0.0, 0.3))
    env = Environment(support_normal=None, boxes=(shelf_board,))
    scene = build_scene(env)
    pts = gripper_points(PANDA_HAND)
    # fingertips just above the board (z = 0.29..0.31) / palm (0.045..0.103 above the TCP) in it
    poses = np.stack([top_down(0.5, 0, 0.325), top_down(0.5, 0, 0.2)])
    res = check_collisions(scene, transform_gripper_points(torch.as_tensor(poses), pts))
    assert res.collides.tolist() == [False, True]
    assert res.obstacle_labels()[1] == "box:0"


@settings(max_examples=15, deadline=None)
@given(
    xs=st.lists(st.floats(-0.08, 0.08), min_size=6, max_size=6),
    yaw=st.floats(-np.pi, np.pi),
    tilt=st.floats(-1.0, 1.0),
)
def test_culled_check_equals_dense_world_implicit(xs, yaw, tilt):
    parts = [
        Superquadric((0.03, 0.02, 0.04), (0.3, 0.8), pose(0.5, 0.0, 0.04, (0.0, 0.0, 0.4))),
        Superquadric((0.02, 0.02, 0.05), (0.6, 1.0), pose(0.55, 0.06, 0.05, (0.3, 0, 0)), bend=4.0),
        Superquadric((0.02, 0.03, 0.03), (0.5, 0.5), pose(0.45, -0.07, 0.03), taper=0.5),
    ]
    env = Environment(support_normal=None)
    scene = build_scene(env, [[p] for p in parts], dtype=torch.float64)
    poses = []
    for i in range(0, 6, 3):
        T = top_down(0.5 + xs[i], xs[i + 1], 0.06 + abs(xs[i + 2]), yaw)
        c, s = np.cos(tilt), np.sin(tilt)
        T[:3, :3] = T[:3, :3] @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        poses.append(T)
    poses = np.stack(poses)
    res = check_collisions(
        scene, transform_gripper_points(torch.as_tensor(poses), gripper_points(PANDA_HAND))
    )
    dense = dense_min_implicit(poses, parts, PANDA_HAND)
    assert res.collides.numpy().tolist() == (dense < 1.0).tolist()
    mins = res.min_value.amin(-1).numpy()
    hit = dense < 1.0
    assert np.allclose(mins[hit], dense[hit], rtol=1e-9)


def test_margin_inflates_every_gripper_box():
    plain = gripper_boxes(PANDA_HAND)
    padded = gripper_boxes(PANDA_HAND, margin=0.003)
    for k, ((lo, hi), (plo, phi)) in enumerate(zip(plain, padded, strict=True)):
        grow_lo, grow_hi = np.full(3, 0.003), np.full(3, 0.003)
        if k == 0:  # left finger: its pad (inner face, lowest y) stays at +opening / 2
            grow_lo[1] = 0.0
        if k == 1:  # right finger: its pad (highest y) stays at -opening / 2
            grow_hi[1] = 0.0
        assert np.allclose(plo, lo - grow_lo) and np.allclose(phi, hi + grow_hi)
    with pytest.raises(ValidationError, match="margin"):
        gripper_boxes(PANDA_HAND, margin=-0.001)


def test_open_gripper_points_move_only_the_fingers_to_the_execution_opening():
    from sqmanip.grasping.gripper import gripper_points_and_sides, open_gripper_points

    pts, sides = gripper_points_and_sides(PANDA_HAND, 512)
    assert set(np.unique(sides).tolist()) == {-1, 0, 1}
    T = torch.as_tensor(np.stack([top_down(0.5, 0.1, 0.2, 0.3), top_down(0.4, 0.0, 0.1)]))
    world = open_gripper_points(T, pts, sides, torch.tensor([0.08, 0.03]), PANDA_HAND.max_opening)
    # at the built opening nothing moves; at 3 cm each finger moves 2.5 cm inwards
    assert torch.allclose(world[0], transform_gripper_points(T[:1], pts)[0], atol=1e-12)
    local = (world[1] - T[1, :3, 3]) @ T[1, :3, :3]  # back to the gripper frame
    fingers = local[torch.as_tensor(sides != 0)]
    assert torch.isclose(fingers[:, 1].abs().min(), torch.tensor(0.015, dtype=local.dtype))
    palm = torch.as_tensor(sides == 0)
    assert torch.allclose(local[palm], torch.as_tensor(pts[sides == 0]), atol=1e-12)
