"""Camera matrix conversions and pinocchio kinematics, without a physics client."""

from __future__ import annotations

import numpy as np
import pytest
from sqmanip.errors import ValidationError
from sqmanip.sim.camera import (
    Intrinsics,
    add_point_noise,
    linearize_depth,
    look_at,
    projection_matrix,
    view_matrix,
)
from sqmanip.sim.config import ROBOT_BASE_POSITION
from sqmanip.sim.kinematics import PandaKinematics


def test_gl_matrices_reproduce_the_opencv_pinhole():
    k = Intrinsics(width=200, height=150, fx=180.0, fy=170.0, cx=95.0, cy=80.0)
    T_wc = look_at((0.3, -0.2, 0.8), (0.5, 0.1, 0.0))
    V = np.asarray(view_matrix(T_wc)).reshape(4, 4).T
    P = np.asarray(projection_matrix(k)).reshape(4, 4).T
    rng = np.random.default_rng(0)
    X = np.concatenate(
        [rng.uniform([0.3, -0.1, 0.0], [0.7, 0.3, 0.2], (20, 3)), np.ones((20, 1))], 1
    )
    clip = (P @ V @ X.T).T
    ndc = clip[:, :3] / clip[:, 3:]
    # GL viewport: x_ndc -1 -> u = -0.5, y_ndc +1 -> v = -0.5 (image rows top first).
    u_gl = (ndc[:, 0] + 1) / 2 * k.width - 0.5
    v_gl = (1 - ndc[:, 1]) / 2 * k.height - 0.5
    xc = (np.linalg.inv(T_wc) @ X.T).T
    u_cv = k.fx * xc[:, 0] / xc[:, 2] + k.cx
    v_cv = k.fy * xc[:, 1] / xc[:, 2] + k.cy
    np.testing.assert_allclose(u_gl, u_cv, atol=1e-9)
    np.testing.assert_allclose(v_gl, v_cv, atol=1e-9)
    # Depth buffer -> metric depth along the optical axis.
    d_buf = (ndc[:, 2] + 1) / 2
    np.testing.assert_allclose(linearize_depth(d_buf, k), xc[:, 2], rtol=1e-9)


def test_intrinsics_reject_bad_values():
    with pytest.raises(ValidationError):
        Intrinsics(width=0)
    with pytest.raises(ValidationError):
        Intrinsics(fx=float("nan"))
    with pytest.raises(ValidationError):
        Intrinsics(near=1.0, far=0.5)


def test_point_noise_follows_the_appendix_a1_model():
    rng = np.random.default_rng(0)
    x = np.zeros((20000, 3))
    d = add_point_noise(x, 0.001, rng)
    m = np.linalg.norm(d, axis=1)
    assert abs(np.std(m) - 0.001 * np.sqrt(1 - 2 / np.pi)) < 5e-5  # |N(0, s)|
    assert np.abs(np.mean(d, axis=0)).max() < 5e-5  # isotropic


@pytest.fixture(scope="module")
def kin():
    base = np.eye(4)
    base[:3, 3] = ROBOT_BASE_POSITION
    return PandaKinematics(base)


def test_ik_converges_inside_joint_limits_and_matches_fk(kin):
    q_ref = np.array([0.3, -0.2, 0.1, -2.0, 0.2, 1.9, 0.5])
    T = kin.fk(q_ref)
    res = kin.ik(T, np.zeros(7) + kin.clamp(np.zeros(7)))
    assert res.success
    assert kin.within_limits(res.q)
    np.testing.assert_allclose(kin.fk(res.q), T, atol=2e-3)


def test_whole_workspace_is_reachable_pointing_down_and_far_poses_are_not(kin):
    home = np.array([0.0, -0.47, 0.0, -2.0, 0.0, 1.54, 0.785])
    for x in (0.194, 0.45, 0.706):
        for y in (-0.256, 0.256):
            for z in (0.005, 0.19):
                T = np.eye(4)
                T[:3, :3] = np.diag([1.0, -1.0, -1.0])
                T[:3, 3] = (x, y, z)
                assert kin.reachable(T, home), (x, y, z)
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = (1.2, 0.0, 0.05)
    assert not kin.reachable(T, home)


def test_link_surface_covers_the_large_faces_the_mesh_vertices_leave_open():
    """The hand's 102 collision-mesh vertices leave 20 cm faces bare; its surface points lie on
    the mesh (inside its bounding box) and no point of a face is farther than about the
    spacing from one of them."""
    from sqmanip.sim.kinematics import link_surface, link_vertices

    verts = link_vertices("panda_hand")
    pts = link_surface("panda_hand", 0.01)
    assert len(pts) > 3 * len(verts)
    assert (pts >= verts.min(0) - 1e-9).all() and (pts <= verts.max(0) + 1e-9).all()
    # the middle of the hand's broad face, between far-apart vertices
    probe = np.array([0.0, 0.0, verts[:, 2].max()])
    assert np.linalg.norm(verts - probe, axis=-1).min() > 0.02
    assert np.linalg.norm(pts - probe, axis=-1).min() < 0.01 * np.sqrt(3)
