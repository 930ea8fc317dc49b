"""Rigid transforms: quaternions (xyzw), SO(3) exp/log, SE(3), SE(2) of (4.3.2), and the pose
decomposition T = C U of Appendix B.1.1."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from sq_strategies import seeds
from sqmanip.geometry import np_api
from sqmanip.geometry.transforms import (
    decompose_pose,
    is_se2,
    matrix_to_quat,
    pose_from_pq,
    pose_to_pq,
    quat_conjugate,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
    rot_z,
    se2_matrix,
    se2_params,
    se2_transform_action,
    se3_compose,
    se3_inverse,
    skew,
    so3_exp,
    so3_log,
    transform_points,
    transform_vectors,
)

HYP = settings(max_examples=25, deadline=None)
BATCHES = [(), (1,), (3, 1, 2, 1)]


def _canon(q: torch.Tensor) -> torch.Tensor:
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[..., 3:] < 0, -q, q)


def _random_poses(seed: int, n: int, dtype=torch.float64) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return pose_from_pq(
        torch.randn(n, 3, generator=g, dtype=dtype), torch.randn(n, 4, generator=g, dtype=dtype)
    )


def _near_pi_rotations(n: int, dtype) -> torch.Tensor:
    """Rotation vectors with angles pi - 10^-k (k = 1..9) and exactly pi, random axes."""
    g = torch.Generator().manual_seed(11)
    axes = torch.nn.functional.normalize(
        torch.randn(n, 3, generator=g, dtype=torch.float64), dim=-1
    )
    angles = torch.tensor(
        [math.pi - 10.0**-k for k in range(1, 10)] + [math.pi], dtype=torch.float64
    )
    return (axes[:, None, :] * angles[None, :, None]).reshape(-1, 3).to(dtype)


class TestQuaternion:
    def test_matches_scipy_xyzw(self, dtype, tol):
        q = torch.randn(200, 4, dtype=dtype, generator=torch.Generator().manual_seed(0))
        expected = torch.as_tensor(Rotation.from_quat(q.double().numpy()).as_matrix(), dtype=dtype)
        torch.testing.assert_close(quat_to_matrix(q), expected, **tol(dtype, 10))

    def test_unnormalised_input_is_normalised(self, dtype, tol):
        q = torch.randn(50, 4, dtype=dtype, generator=torch.Generator().manual_seed(1))
        torch.testing.assert_close(quat_to_matrix(q * 7.5), quat_to_matrix(q), **tol(dtype, 10))
        R = quat_to_matrix(q * 1e-3)
        torch.testing.assert_close(
            R @ R.transpose(-1, -2), torch.eye(3, dtype=dtype).expand_as(R), **tol(dtype, 10)
        )

    def test_zero_quaternion_is_identity(self, dtype):
        torch.testing.assert_close(
            quat_to_matrix(torch.zeros(4, dtype=dtype)), torch.eye(3, dtype=dtype)
        )
        torch.testing.assert_close(
            quat_normalize(torch.zeros(2, 4, dtype=dtype))[:, 3], torch.ones(2, dtype=dtype)
        )

    @HYP
    @given(seed=seeds())
    def test_round_trip_quat_matrix_quat(self, seed):
        q = torch.randn(64, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))
        torch.testing.assert_close(matrix_to_quat(quat_to_matrix(q)), _canon(q))

    def test_round_trip_near_180_degrees(self, dtype, tol):
        R = so3_exp(_near_pi_rotations(20, dtype))
        q = matrix_to_quat(R)
        torch.testing.assert_close(
            q.norm(dim=-1), torch.ones(q.shape[0], dtype=dtype), **tol(dtype)
        )
        torch.testing.assert_close(quat_to_matrix(q), R, **tol(dtype, 10))
        assert (q[:, 3] >= 0).all()

    def test_matrix_to_quat_matches_scipy(self, dtype, tol):
        R = so3_exp(
            torch.randn(100, 3, dtype=dtype, generator=torch.Generator().manual_seed(2)) * 2
        )
        expected = torch.as_tensor(Rotation.from_matrix(R.double().numpy()).as_quat(), dtype=dtype)
        torch.testing.assert_close(matrix_to_quat(R), _canon(expected), **tol(dtype, 10))

    def test_multiply_matches_matrix_product_and_conjugate_inverts(self, dtype, tol):
        g = torch.Generator().manual_seed(3)
        q1, q2 = (
            _canon(torch.randn(30, 4, dtype=dtype, generator=g)),
            _canon(torch.randn(30, 4, dtype=dtype, generator=g)),
        )
        torch.testing.assert_close(
            quat_to_matrix(quat_multiply(q1, q2)),
            quat_to_matrix(q1) @ quat_to_matrix(q2),
            **tol(dtype, 10),
        )
        ident = quat_multiply(q1, quat_conjugate(q1))
        torch.testing.assert_close(
            ident, torch.tensor([0, 0, 0, 1.0], dtype=dtype).expand_as(ident), **tol(dtype, 10)
        )

    @pytest.mark.parametrize("batch", BATCHES)
    def test_batch_shapes(self, batch, dtype):
        q = torch.randn(*batch, 4, dtype=dtype)
        assert quat_to_matrix(q).shape == (*batch, 3, 3)
        assert matrix_to_quat(quat_to_matrix(q)).shape == (*batch, 4)

    def test_gradcheck(self):
        q = torch.randn(5, 4, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(quat_to_matrix, (q,))
        R = so3_exp(torch.randn(5, 3, dtype=torch.float64)).requires_grad_(True)
        assert torch.autograd.gradcheck(matrix_to_quat, (R,))

    @pytest.mark.parametrize("shape", [(3,), (5, 3), (4, 5)])
    def test_bad_shapes_raise(self, shape):
        with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
            quat_to_matrix(torch.zeros(shape))
        with pytest.raises(ValueError, match=r"\(\.\.\., 3, 3\)"):
            matrix_to_quat(torch.zeros(shape))


class TestSO3:
    def test_exp_matches_scipy(self, dtype, tol):
        v = torch.randn(100, 3, dtype=dtype, generator=torch.Generator().manual_seed(4)) * 2
        expected = torch.as_tensor(
            Rotation.from_rotvec(v.double().numpy()).as_matrix(), dtype=dtype
        )
        torch.testing.assert_close(so3_exp(v), expected, **tol(dtype, 10))

    def test_skew_is_cross_product(self, dtype, tol):
        g = torch.Generator().manual_seed(5)
        v, u = (
            torch.randn(10, 3, dtype=dtype, generator=g),
            torch.randn(10, 3, dtype=dtype, generator=g),
        )
        torch.testing.assert_close(
            (skew(v) @ u[..., None])[..., 0], torch.linalg.cross(v, u), **tol(dtype)
        )

    @HYP
    @given(seed=seeds(), scale=st.floats(1e-9, math.pi - 1e-6))
    def test_log_inverts_exp(self, seed, scale):
        axes = torch.nn.functional.normalize(
            torch.randn(16, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(seed)),
            dim=-1,
        )
        v = axes * scale
        torch.testing.assert_close(so3_log(so3_exp(v)), v, rtol=1e-7, atol=1e-9)

    def test_exp_of_log_near_180_degrees(self, dtype, tol):
        R = so3_exp(_near_pi_rotations(20, dtype))
        w = so3_log(R)
        assert (w.norm(dim=-1) <= math.pi + 1e-6).all()
        torch.testing.assert_close(so3_exp(w), R, **tol(dtype, 50))

    def test_identity_and_tiny_angles(self, dtype):
        for angle in (0.0, 1e-12, 1e-6):
            v = torch.tensor([angle, 0.0, 0.0], dtype=dtype, requires_grad=True)
            R = so3_exp(v)
            (g,) = torch.autograd.grad(R.sum() + so3_log(R).sum(), v)
            assert torch.isfinite(g).all()
            torch.testing.assert_close(so3_log(R.detach()), v.detach(), rtol=1e-4, atol=1e-7)

    def test_gradcheck(self):
        v = torch.randn(6, 3, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(so3_exp, (v,))
        R = so3_exp(v.detach()).requires_grad_(True)
        assert torch.autograd.gradcheck(so3_log, (R,))


class TestSE3:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_inverse_composes_to_identity(self, batch, dtype, tol):
        T = _random_poses(0, max(1, math.prod(batch)), dtype).reshape(*batch, 4, 4)
        I4 = torch.eye(4, dtype=dtype).expand(*batch, 4, 4)
        torch.testing.assert_close(se3_compose(se3_inverse(T), T), I4, **tol(dtype, 10))
        torch.testing.assert_close(se3_inverse(se3_inverse(T)), T, **tol(dtype, 10))

    def test_transform_points_matches_homogeneous_product(self, dtype, tol):
        T = _random_poses(1, 4, dtype)
        p = torch.randn(4, 10, 3, dtype=dtype)
        ph = torch.cat([p, torch.ones(4, 10, 1, dtype=dtype)], -1)
        torch.testing.assert_close(
            transform_points(T, p), (ph @ T.transpose(-1, -2))[..., :3], **tol(dtype, 10)
        )
        torch.testing.assert_close(
            transform_vectors(T, p), p @ T[:, :3, :3].transpose(-1, -2), **tol(dtype, 10)
        )
        torch.testing.assert_close(
            transform_points(se3_inverse(T), transform_points(T, p)), p, **tol(dtype, 100)
        )

    @HYP
    @given(seed=seeds())
    def test_pose_pq_round_trip(self, seed):
        g = torch.Generator().manual_seed(seed)
        pos, q = (
            torch.randn(8, 3, dtype=torch.float64, generator=g),
            torch.randn(8, 4, dtype=torch.float64, generator=g),
        )
        T = pose_from_pq(pos, q)
        pos2, q2 = pose_to_pq(T)
        torch.testing.assert_close(pos2, pos)
        torch.testing.assert_close(q2, _canon(q))
        torch.testing.assert_close(pose_from_pq(pos2, q2), T)

    def test_pose_from_pq_broadcasts(self):
        T = pose_from_pq(torch.zeros(5, 3), torch.tensor([0.0, 0.0, 0.0, 1.0]))
        assert T.shape == (5, 4, 4)
        torch.testing.assert_close(T, torch.eye(4).expand(5, 4, 4))

    @pytest.mark.parametrize("shape", [(4,), (3, 3), (2, 4, 3)])
    def test_bad_shapes_raise(self, shape):
        for fn in (
            se3_inverse,
            lambda T: se3_compose(T, T),
            lambda T: transform_points(T, torch.zeros(2, 3)),
        ):
            with pytest.raises(ValueError, match=r"\(\.\.\., 4, 4\)"):
                fn(torch.zeros(shape))
        with pytest.raises(ValueError, match="points"):
            transform_points(torch.eye(4), torch.zeros(3))


class TestSE2:
    def test_matrix_has_form_4_3_2(self, dtype):
        C = se2_matrix(torch.tensor(0.3, dtype=dtype), 1.0, -2.0)
        expected = torch.eye(4, dtype=dtype)
        expected[:3, :3] = torch.as_tensor(Rotation.from_euler("z", 0.3).as_matrix(), dtype=dtype)
        expected[0, 3], expected[1, 3] = 1.0, -2.0
        torch.testing.assert_close(C, expected)
        assert is_se2(C)
        assert not is_se2(
            pose_from_pq(
                torch.zeros(3, dtype=dtype), torch.tensor([0.1, 0.0, 0.0, 1.0], dtype=dtype)
            )
        )
        assert not is_se2(
            se2_matrix(0.0, 0.0, 0.0)
            + torch.tensor([[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0.2], [0, 0, 0, 0]])
        )

    @pytest.mark.parametrize("batch", BATCHES)
    def test_broadcast_and_params_round_trip(self, batch, dtype):
        theta = (torch.rand(batch, dtype=dtype) * 2 - 1) * math.pi
        C = se2_matrix(theta, 0.5, torch.full(batch, -0.25, dtype=dtype))
        assert C.shape == (*batch, 4, 4) and C.dtype == dtype
        th, tx, ty = se2_params(C)
        torch.testing.assert_close(th, theta)
        torch.testing.assert_close(tx, torch.full(batch, 0.5, dtype=dtype))
        torch.testing.assert_close(ty, torch.full(batch, -0.25, dtype=dtype))
        torch.testing.assert_close(rot_z(theta), C[..., :3, :3])

    @HYP
    @given(seed=seeds())
    def test_push_action_transform_is_equivariant(self, seed):
        # Definition 4.1: the push (p, v) maps to (Rot p + t, Rot v). Expressed in the frame C of an
        # object, the action must not change when object and action move together by C_a.
        g = torch.Generator().manual_seed(seed)
        theta, t = (
            torch.rand(2, generator=g, dtype=torch.float64) * 6 - 3,
            torch.randn(2, 2, generator=g, dtype=torch.float64),
        )
        Ca, Cb = se2_matrix(theta[0], t[0, 0], t[0, 1]), se2_matrix(theta[1], t[1, 0], t[1, 1])
        p, v = (
            torch.randn(3, generator=g, dtype=torch.float64),
            torch.randn(3, generator=g, dtype=torch.float64),
        )
        T = _random_poses(seed, 1)[0]
        C, _ = decompose_pose(T)
        Cinv = se3_inverse(C)
        local = se2_transform_action(Cinv, p, v)
        pa, va = se2_transform_action(Ca, p, v)
        C2, _ = decompose_pose(Ca @ T)
        local2 = se2_transform_action(se3_inverse(C2), pa, va)
        torch.testing.assert_close(local2, local)
        # A group action: (Ca Cb) . a = Ca . (Cb . a); the displacement keeps its length and z.
        torch.testing.assert_close(
            se2_transform_action(Ca @ Cb, p, v),
            se2_transform_action(Ca, *se2_transform_action(Cb, p, v)),
        )
        torch.testing.assert_close(va.norm(), v.norm())
        torch.testing.assert_close(torch.stack([pa[2], va[2]]), torch.stack([p[2], v[2]]))

    def test_bad_shapes_raise(self):
        with pytest.raises(ValueError, match=r"\(\.\.\., 4, 4\)"):
            se2_params(torch.zeros(3, 3))
        with pytest.raises(ValueError, match="p must"):
            se2_transform_action(torch.eye(4), torch.zeros(2), torch.zeros(3))
        with pytest.raises(ValueError, match="v must"):
            se2_transform_action(torch.eye(4), torch.zeros(3), torch.zeros(4))


class TestDecomposePose:
    @HYP
    @given(seed=seeds())
    def test_c_has_form_b_1_3_and_t_equals_c_u(self, seed):
        T = _random_poses(seed, 32)
        C, U = decompose_pose(T)
        assert is_se2(C, atol=1e-12).all()
        torch.testing.assert_close(C @ U, T)
        # M2 only moves along z: U's translation is (0, 0, t_z).
        torch.testing.assert_close(
            U[:, :3, 3], torch.stack([torch.zeros(32), torch.zeros(32), T[:, 2, 3]], -1).double()
        )

    @HYP
    @given(
        seed=seeds(), theta=st.floats(-math.pi, math.pi), tx=st.floats(-2, 2), ty=st.floats(-2, 2)
    )
    def test_property_iii_equivariance(self, seed, theta, tx, ty):
        T = _random_poses(seed, 16)
        Ca = se2_matrix(torch.tensor(theta, dtype=torch.float64), tx, ty)
        C, U = decompose_pose(T)
        C2, U2 = decompose_pose(Ca @ T)
        torch.testing.assert_close(C2, Ca @ C)
        torch.testing.assert_close(U2, U)

    def test_tilt_about_object_x_projects_to_the_heading(self, dtype, tol):
        # R = Rot(z, th) Rot(x, beta): the minimal rotation aligning z undoes the tilt exactly.
        th, beta = 0.8, 0.6
        R = rot_z(torch.tensor(th, dtype=dtype)) @ so3_exp(
            torch.tensor([beta, 0.0, 0.0], dtype=dtype)
        )
        T = torch.eye(4, dtype=dtype)
        T[:3, :3], T[:3, 3] = R, torch.tensor([1.0, 2.0, 3.0], dtype=dtype)
        C, U = decompose_pose(T)
        torch.testing.assert_close(
            C, se2_matrix(torch.tensor(th, dtype=dtype), 1.0, 2.0), **tol(dtype, 10)
        )
        torch.testing.assert_close(
            U[:3, :3], so3_exp(torch.tensor([beta, 0.0, 0.0], dtype=dtype)), **tol(dtype, 10)
        )

    @pytest.mark.parametrize("flip", [False, True])
    @pytest.mark.parametrize("tilt", [0.0, 1e-12, 1e-7, 1e-4])
    def test_degenerate_parallel_and_antiparallel_z(self, flip, tilt, dtype, tol):
        base = so3_exp(torch.tensor([math.pi if flip else 0.0, tilt, 0.0], dtype=torch.float64))
        T = torch.eye(4, dtype=torch.float64)
        T[:3, :3], T[:3, 3] = (
            rot_z(torch.tensor(0.7, dtype=torch.float64)) @ base,
            torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64),
        )
        T = T.to(dtype).requires_grad_(True)
        C, U = decompose_pose(T)
        assert torch.isfinite(C).all() and torch.isfinite(U).all()
        (grad,) = torch.autograd.grad(C.sum() + U.sum(), T)
        assert torch.isfinite(grad).all()
        T, C, U = T.detach(), C.detach(), U.detach()
        assert is_se2(C, atol=1e-6)
        torch.testing.assert_close(C @ U, T, **tol(dtype, 10))
        theta, _, _ = se2_params(C)
        assert abs(float(theta) - 0.7) < 1e-3  # heading kept (flip about the object x axis)
        Ca = se2_matrix(torch.tensor(-2.0, dtype=dtype), 0.1, 0.4)
        C2, U2 = decompose_pose(Ca @ T)
        torch.testing.assert_close(C2, Ca @ C, **tol(dtype, 100))
        torch.testing.assert_close(U2, U, **tol(dtype, 100))

    @pytest.mark.parametrize("batch", BATCHES)
    def test_batch_shapes(self, batch, dtype):
        T = _random_poses(3, max(1, math.prod(batch)), dtype).reshape(*batch, 4, 4)
        C, U = decompose_pose(T)
        assert C.shape == U.shape == (*batch, 4, 4) and C.dtype == U.dtype == dtype

    def test_gradcheck(self):
        T = _random_poses(4, 3).requires_grad_(True)
        assert torch.autograd.gradcheck(lambda T: decompose_pose(T)[0], (T,))
        assert torch.autograd.gradcheck(lambda T: decompose_pose(T)[1], (T,))

    def test_bad_shape_raises(self):
        with pytest.raises(ValueError, match=r"\(\.\.\., 4, 4\)"):
            decompose_pose(torch.zeros(3, 4))


class TestNumpyWrappers:
    def test_results_are_numpy_and_keep_precision(self):
        q64 = np.array([0.1, 0.2, 0.3, 0.9])
        R = np_api.quat_to_matrix(q64)
        assert isinstance(R, np.ndarray) and R.dtype == np.float64
        np.testing.assert_allclose(R, Rotation.from_quat(q64).as_matrix(), atol=1e-12)
        assert np_api.quat_to_matrix(q64.astype(np.float32)).dtype == np.float32
        assert np_api.so3_exp([0.0, 0.0, 0.1]).dtype == np.float64  # numpy's default for lists
        assert np_api.so3_exp(np.array([0, 0, 1])).dtype == np.float32  # integer arrays
        # Python scalars are weak: they do not raise the precision of float32 arrays.
        assert np_api.se2_matrix(np.float32([0.1, 0.2]), 0.5, 1.0).dtype == np.float32

    def test_same_values_as_torch(self):
        T = _random_poses(5, 4).numpy()
        C, U = np_api.decompose_pose(T)
        Ct, Ut = decompose_pose(torch.from_numpy(T))
        np.testing.assert_array_equal(C, Ct.numpy())
        np.testing.assert_array_equal(U, Ut.numpy())
        pos, q = np_api.pose_to_pq(T)
        np.testing.assert_allclose(np_api.pose_from_pq(pos, q), T, atol=1e-12)
        params = np.array([0.1, 0.2, 0.3, 0.5, 1.0, 0.2, 1.0, 0.3, 0.0])
        pts = np.random.default_rng(0).normal(size=(10, 3)) * 0.2
        from sqmanip.geometry import implicit

        expected = implicit(torch.from_numpy(pts), torch.from_numpy(params)).numpy()
        np.testing.assert_array_equal(np_api.implicit(pts, params), expected)
        assert np_api.radial_distance(pts, params).shape == (10,)
        assert np_api.normal(pts, params, kind=1).shape == (10, 3)

    def test_bad_shape_raises(self):
        with pytest.raises(ValueError, match=r"\(\.\.\., 4, 4\)"):
            np_api.se3_inverse(np.zeros((3, 3)))
