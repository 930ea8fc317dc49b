"""Physics baseline (4.7.4): superquadrics re-simulated in PyBullet under the same predict API,
batched in one world of scene copies (default) and the sequential full-robot reference."""

from __future__ import annotations

import numpy as np
import pytest
from sqmanip.dynamics.physics import PhysicsDynamics

BOX = [0.03, 0.03, 0.03, 0.2, 0.2, 0, 0, 0, 0]
CYLINDER = [0.025, 0.025, 0.03, 0.2, 1.0, 0, 0, 0, 0]


@pytest.fixture(scope="module")
def physics():
    with PhysicsDynamics() as model:
        yield model


@pytest.fixture(scope="module")
def reference():
    with PhysicsDynamics(batched=False) as model:
        yield model


def _scene(*positions: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Upright boxes (first) and cylinders (then) of 6 cm height standing at ``positions``."""
    poses = np.eye(4)[None].repeat(len(positions), 0)
    poses[:, :2, 3] = positions
    poses[:, 2, 3] = 0.03 + 1e-4
    params = np.array([BOX if i == 0 else CYLINDER for i in range(len(positions))], float)
    return poses, params


def _yaw(T: np.ndarray) -> np.ndarray:
    return np.arctan2(T[..., 1, 0], T[..., 0, 0])


def test_push_along_x_moves_lone_box_along_x_and_leaves_far_object_in_place(physics):
    poses, params = _scene((0.45, 0.0), (0.45, 0.18))
    actions = np.array([[0.37, 0.0, 0.03, 0.10, 0.0, 0.0]])  # finger front meets the box at 5 cm
    out = physics.predict(poses, params, actions)
    assert out.shape == (1, 2, 4, 4) and out.dtype.is_floating_point
    assert physics.last_failed.tolist() == [False]
    moved = out[0, 0, :3, 3].numpy() - poses[0, :3, 3]
    assert 0.04 < moved[0] < 0.08 and abs(moved[1]) < 0.01 and abs(moved[2]) < 0.003
    assert abs(_yaw(out[0, 0].numpy())) < np.deg2rad(5)
    np.testing.assert_allclose(out[0, 1].numpy(), poses[1], atol=1e-3)  # never touched


def test_identical_pushes_in_different_copies_give_identical_predictions(physics):
    poses, params = _scene((0.45, 0.0), (0.45, 0.09))
    push = [0.45, -0.085, 0.03, 0.0, 0.10, 0.0]  # pushes the box into the cylinder (~2.5 cm)
    out = physics.predict(poses, params, np.array([push] * 3)).numpy()
    assert np.linalg.norm(out[0, 1, :3, 3] - poses[1, :3, 3]) > 0.005  # the chain happened
    np.testing.assert_array_equal(out[1], out[0])  # copies do not interact
    np.testing.assert_array_equal(out[2], out[0])


def test_predict_batch_pushes_each_scene_like_predict_on_that_scene(physics):
    poses, params = _scene((0.45, 0.0))
    moved = poses.copy()
    moved[0, :3, 3] = (0.40, 0.10, 0.03 + 1e-4)
    scenes = np.stack([poses, moved])
    actions = np.array([[0.37, 0.0, 0.03, 0.10, 0.0, 0.0], [0.40, 0.02, 0.03, 0.0, 0.10, 0.0]])
    out = physics.predict_batch(scenes, params, actions).numpy()
    for k in range(2):
        single = physics.predict(scenes[k], params, actions[k : k + 1]).numpy()
        np.testing.assert_array_equal(out[k], single[0])
    assert out[1, 0, 1, 3] - moved[0, 1, 3] > 0.03  # the second box went +y


def test_batched_agrees_with_the_full_robot_reference(physics, reference):
    poses, params = _scene((0.42, 0.03), (0.50, -0.12))
    actions = np.array([
        [0.34, 0.05, 0.03, 0.10, 0.0, 0.0],    # off-centre: the box slides and turns
        [0.50, -0.21, 0.03, 0.0, 0.10, 0.0],   # the cylinder along +y
    ])  # fmt: skip
    fast = physics.predict(poses, params, actions).numpy()
    ref = reference.predict(poses, params, actions).numpy()
    assert physics.last_failed.tolist() == reference.last_failed.tolist() == [False, False]
    for k, i in ((0, 0), (1, 1)):  # the pushed objects moved ~4-7 cm
        assert np.linalg.norm(ref[k, i, :3, 3] - poses[i, :3, 3]) > 0.03
        assert np.linalg.norm(fast[k, i, :3, 3] - ref[k, i, :3, 3]) < 0.005  # measured 3, 1 mm
        dyaw = (_yaw(fast[k, i]) - _yaw(ref[k, i]) + np.pi) % (2 * np.pi) - np.pi
        assert abs(dyaw) < np.deg2rad(5)  # measured 3.3, 0.3 deg
    np.testing.assert_allclose(fast[0, 1], ref[0, 1], atol=2e-3)  # untouched in both
    np.testing.assert_allclose(fast[1, 0], ref[1, 0], atol=2e-3)


def test_pushes_the_robot_refuses_are_flagged_and_leave_the_poses_unchanged(physics, reference):
    poses, params = _scene((0.60, 0.20))
    actions = np.array([
        [0.45, 0.10, 0.03, 1e-6, 0.0, 0.0],       # |v| ~ 0: invalid
        [0.10, 0.00, 0.03, 0.10, 0.0, 0.0],       # start outside the workspace
        [0.244, 0.116, 0.048, -0.037, -0.093, 0],  # the arm's end configuration hits the pedestal
        [0.55, 0.20, 0.03, 0.0, 0.0, 0.0],        # v = 0
    ])  # fmt: skip
    for model in (physics, reference):
        out = model.predict(poses, params, actions).numpy()
        assert model.last_failed.tolist() == [True, True, True, True]
        np.testing.assert_array_equal(out, np.broadcast_to(poses, out.shape))


def test_physics_predict_validates_shapes(physics):
    with pytest.raises(ValueError, match=r"actions must have shape \(K, 6\)"):
        physics.predict(np.eye(4)[None], np.zeros((1, 9)), np.zeros((2, 5)))
    with pytest.raises(ValueError, match=r"params must have shape \(1, 9\)"):
        physics.predict(np.eye(4)[None], np.zeros((1, 8)), np.zeros((2, 6)))
    with pytest.raises(ValueError, match=r"poses must have shape \(N, 4, 4\)"):
        physics.predict(np.eye(4), np.zeros((1, 9)), np.zeros((2, 6)))
    with pytest.raises(ValueError, match=r"poses must have shape \(K, N, 4, 4\)"):
        physics.predict_batch(np.eye(4)[None], np.zeros((1, 9)), np.zeros((1, 6)))
    with pytest.raises(ValueError, match=r"one row per scene \(2\)"):
        physics.predict_batch(
            np.eye(4)[None, None].repeat(2, 0), np.zeros((1, 9)), np.zeros((1, 6))
        )
    with pytest.raises(ValueError, match=r"kinds must be 0, 1 or 2"):
        physics.predict(np.eye(4)[None], np.zeros((1, 9)), np.zeros((1, 6)), kinds=[3])
