"""Physics baseline (4.7.4): superquadrics re-simulated in PyBullet under the same predict API."""

from __future__ import annotations

import numpy as np
import pytest
from sqmanip.dynamics.physics import PhysicsDynamics


@pytest.fixture(scope="module")
def physics():
    with PhysicsDynamics() as model:
        yield model


def test_pushed_superquadric_moves_along_the_push_and_unreachable_push_is_flagged(physics):
    poses = np.eye(4)[None].repeat(2, 0)
    poses[0, :3, 3] = (0.45, 0.0, 0.03)
    poses[1, :3, 3] = (0.45, 0.18, 0.03)
    params = np.array([[0.03, 0.03, 0.03, 0.2, 0.2, 0, 0, 0, 0],
                       [0.025, 0.025, 0.03, 0.2, 1.0, 0, 0, 0, 0]])  # fmt: skip
    actions = np.array([
        [0.37, 0.0, 0.03, 0.10, 0.0, 0.0],   # pushes object 0 by ~4 cm along +x
        [0.45, 0.10, 0.03, 0.0, 0.0, 0.0],   # |v| = 0: refused by the simulator
    ])  # fmt: skip
    actions[1, 3] = 1e-6
    out = physics.predict(poses, params, actions).numpy()
    assert out.shape == (2, 2, 4, 4)
    moved = out[0, 0, :3, 3] - poses[0, :3, 3]
    assert 0.02 < moved[0] < 0.07 and abs(moved[1]) < 0.01
    assert np.linalg.norm(out[0, 1, :3, 3] - poses[1, :3, 3]) < 0.005  # untouched object
    assert physics.last_failed.tolist() == [False, True]
    np.testing.assert_array_equal(out[1], poses)


def test_physics_predict_validates_shapes(physics):
    with pytest.raises(ValueError, match=r"actions must have shape \(K, 6\)"):
        physics.predict(np.eye(4)[None], np.zeros((1, 9)), np.zeros((2, 5)))
    with pytest.raises(ValueError, match=r"params must have shape \(1, 9\)"):
        physics.predict(np.eye(4)[None], np.zeros((1, 8)), np.zeros((2, 6)))
