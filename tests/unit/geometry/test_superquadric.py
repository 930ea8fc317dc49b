"""Superquadric implicit functions, parametric surfaces, normals and radial distance
(Ch. 2.2, 2.3.3, 3.3.4), plain and deformed, over the thesis' parameter ranges."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from sq_strategies import SIZE, E, deformed_params, seeds
from sqmanip.geometry import (
    SUPERELLIPSOID,
    SUPERPARABOLOID,
    SUPERTOROID,
    implicit,
    implicit_homogeneous,
    normal,
    radial_distance,
    superellipsoid_implicit,
    superellipsoid_parametric_normal,
    superellipsoid_surface,
    superparaboloid_surface,
    supertoroid_surface,
)
from sqmanip.geometry.deform import TAPER_MIN, deform, taper

HYP = settings(max_examples=20, deadline=None)
MARGIN = 0.15  # parameter margin from multiples of pi/2, where surface tangents degenerate


def _angles(g: torch.Generator, n: int, lo: float, hi: float, avoid_quarter: bool) -> torch.Tensor:
    t = lo + (hi - lo) * torch.rand(n, generator=g, dtype=torch.float64)
    if avoid_quarter:  # move samples out of [q pi/2 - MARGIN, q pi/2 + MARGIN]
        q = torch.round(t / (math.pi / 2)) * (math.pi / 2)
        d = t - q
        t = torch.where(d.abs() < MARGIN, q + torch.sign(d + 1e-300) * MARGIN, t)
    return t


def _se_parameters(seed: int, n: int = 64, avoid_quarter: bool = True):
    g = torch.Generator().manual_seed(seed)
    eta = _angles(g, n, -math.pi / 2 + MARGIN, math.pi / 2 - MARGIN, avoid_quarter)
    omega = _angles(g, n, -math.pi, math.pi, avoid_quarter)
    return eta, omega


def _se_surface(params: torch.Tensor, eta, omega) -> torch.Tensor:
    a1, a2, a3, e1, e2 = params[:5].tolist()
    return superellipsoid_surface(eta, omega, a1, a2, a3, e1, e2)


def _d(params: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    _, _, a3, _, _, k, b, alpha, _ = params.tolist()
    return deform(x, k, a3, b, alpha)


def _unfolded(params: torch.Tensor, x: torch.Tensor, margin: float = 0.05) -> torch.Tensor:
    """Points where D is one-to-one (see test_deform._unfolded)."""
    _, _, a3, _, _, k, b, alpha, _ = params.tolist()
    xt = taper(x, k, a3)
    r = xt[..., 0] * math.cos(alpha) + xt[..., 1] * math.sin(alpha)
    t = k * x[..., 2] / a3 + 1
    bent_angle_ok = (x[..., 2] * b).abs() < math.pi - margin
    return (r * b < 1 - margin) & (t > TAPER_MIN + margin) & bent_angle_ok


def _assert_orthogonal_to_tangents(n: torch.Tensor, surf, u, v, h: float = 1e-6, bound=1e-6):
    assume(n.shape[0] > 0)  # strongly bent shapes may wrap so far that no sample is unfolded
    tu = (surf(u + h, v) - surf(u - h, v)) / (2 * h)
    tv = (surf(u, v + h) - surf(u, v - h)) / (2 * h)
    for t in (tu, tv):
        cos = (n * t).sum(-1) / (n.norm(dim=-1) * t.norm(dim=-1))
        assert cos.abs().max() < bound, cos.abs().max()


class TestSuperellipsoid:
    def test_implicit_matches_equation_2_2_1(self):
        g = torch.Generator().manual_seed(0)
        x = torch.randn(200, 3, generator=g, dtype=torch.float64) * 0.3
        a1, a2, a3, e1, e2 = 0.2, 0.3, 0.15, 0.6, 1.4
        f = ((x[:, 0] / a1).abs() ** (2 / e2) + (x[:, 1] / a2).abs() ** (2 / e2)) ** (e2 / e1) + (
            x[:, 2] / a3
        ).abs() ** (2 / e1)
        torch.testing.assert_close(superellipsoid_implicit(x, a1, a2, a3, e1, e2), f)

    @HYP
    @given(params=deformed_params(), seed=seeds())
    def test_deformed_surface_points_satisfy_f_equals_1(self, params, seed):
        eta, omega = _se_parameters(seed, avoid_quarter=False)
        x = _se_surface(params, eta, omega)
        X = _d(params, x)[_unfolded(params, x)]
        torch.testing.assert_close(implicit(X, params), torch.ones(X.shape[0], dtype=torch.float64))
        torch.testing.assert_close(
            implicit_homogeneous(X, params), torch.ones(X.shape[0], dtype=torch.float64)
        )
        torch.testing.assert_close(
            radial_distance(X, params), torch.zeros(X.shape[0], dtype=torch.float64)
        )

    def test_surface_points_satisfy_f_equals_1_in_float32(self):
        params = torch.tensor([0.1, 0.2, 0.15, 0.2, 1.7, 0.5, 2.0, 0.4, 0.0])
        eta, omega = _se_parameters(1, avoid_quarter=False)
        x = _se_surface(params.double(), eta, omega)
        X = _d(params.double(), x)[_unfolded(params.double(), x)].float()
        f = implicit(X, params)
        assert f.dtype == torch.float32
        torch.testing.assert_close(f, torch.ones_like(f), rtol=1e-3, atol=1e-3)

    @HYP
    @given(params=deformed_params(), seed=seeds())
    def test_normals_are_orthogonal_to_tangents_and_point_outward(self, params, seed):
        eta, omega = _se_parameters(seed)

        def surf(u, v):
            return _d(params, _se_surface(params, u, v))

        keep = _unfolded(params, _se_surface(params, eta, omega))
        eta, omega = eta[keep], omega[keep]
        X = surf(eta, omega)
        n = normal(X, params)
        torch.testing.assert_close(n.norm(dim=-1), torch.ones(X.shape[0], dtype=torch.float64))
        _assert_orthogonal_to_tangents(n, surf, eta, omega)
        h = 1e-5 * float(params[:3].min())
        assert (implicit(X + h * n, params) > 1).all()
        assert (implicit(X - h * n, params) < 1).all()

    @HYP
    @given(params=deformed_params(deformed=False), seed=seeds())
    def test_parametric_normal_2_2_3_matches_implicit_normal(self, params, seed):
        eta, omega = _se_parameters(seed)
        a1, a2, a3, e1, e2 = params[:5].tolist()
        n_param = superellipsoid_parametric_normal(eta, omega, a1, a2, a3, e1, e2)
        n_param = n_param / n_param.norm(dim=-1, keepdim=True)
        torch.testing.assert_close(normal(_se_surface(params, eta, omega), params), n_param)

    def test_normal_is_parallel_to_autograd_gradient(self, dtype, tol):
        params = torch.tensor([0.2, 0.1, 0.3, 0.5, 1.2, -0.4, 1.0, 2.0, 0.0], dtype=dtype)
        x = (torch.rand(50, 3, generator=torch.Generator().manual_seed(3), dtype=dtype) - 0.5) * 0.4
        x.requires_grad_(True)
        (grad,) = torch.autograd.grad(implicit(x, params).sum(), x)
        expected = grad / grad.norm(dim=-1, keepdim=True)
        torch.testing.assert_close(normal(x.detach(), params), expected, **tol(dtype, 10))

    @HYP
    @given(radius=SIZE, seed=seeds())
    def test_radial_distance_is_true_distance_for_spheres(self, radius, seed):
        g = torch.Generator().manual_seed(seed)
        x = (
            torch.randn(100, 3, generator=g, dtype=torch.float64)
            * radius
            * torch.rand(100, 1, generator=g)
            * 3
        )
        params = torch.tensor([radius, radius, radius, 1.0, 1.0, 0, 0, 0, 0], dtype=torch.float64)
        torch.testing.assert_close(radial_distance(x, params), (x.norm(dim=-1) - radius).abs())

    @HYP
    @given(params=deformed_params(deformed=False), seed=seeds(), scale=st.floats(0.05, 20.0))
    def test_radial_distance_is_distance_along_the_ray_to_the_surface(self, params, seed, scale):
        eta, omega = _se_parameters(seed, avoid_quarter=False)
        xs = _se_surface(params, eta, omega)
        expected = abs(scale - 1) * xs.norm(dim=-1)
        torch.testing.assert_close(radial_distance(scale * xs, params), expected)

    @HYP
    @given(params=deformed_params(), seed=seeds())
    def test_deformed_radial_distance_is_equation_3_3_4(self, params, seed):
        g = torch.Generator().manual_seed(seed)
        x0 = (torch.rand(64, 3, generator=g, dtype=torch.float64) - 0.5) * params[:3] * 4
        e1 = float(params[3])
        expected = x0.norm(dim=-1) * (1 - implicit(x0, params) ** (-e1 / 2)).abs()
        torch.testing.assert_close(radial_distance(x0, params), expected)

    @HYP
    @given(params=deformed_params(deformed=False), seed=seeds(), s=st.floats(0.01, 100.0))
    def test_homogeneous_implicit_scales_like_distance_squared(self, params, seed, s):
        x = torch.randn(32, 3, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
        f1 = implicit_homogeneous(x, params)
        torch.testing.assert_close(implicit_homogeneous(s * x, params), s * s * f1)
        torch.testing.assert_close(f1, implicit(x, params) ** params[3])

    def test_inside_is_below_one_and_outside_above(self, dtype):
        params = torch.tensor([0.1, 0.2, 0.3, 0.3, 1.5, 0.2, 1.0, 0.0, 0.0], dtype=dtype)
        x = torch.tensor(
            [[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.0, 0.5], [0.3, 0.0, 0.0]], dtype=dtype
        )
        f = implicit(x, params)
        assert f[0] < 1 and f[1] < 1 and f[2] > 1 and f[3] > 1


class TestSuperparaboloid:
    @HYP
    @given(params=deformed_params(), seed=seeds())
    def test_parametric_points_satisfy_f_equals_1(self, params, seed):
        g = torch.Generator().manual_seed(seed)
        theta = _angles(g, 64, -math.pi, math.pi, avoid_quarter=False)
        u = torch.rand(64, generator=g, dtype=torch.float64)
        x = superparaboloid_surface(theta, u, *params[:5].tolist())
        one = torch.ones(64, dtype=torch.float64)
        torch.testing.assert_close(implicit(x, params * _plain_mask(), SUPERPARABOLOID), one)
        X = _d(params, x)[_unfolded(params, x)]
        torch.testing.assert_close(implicit(X, params, SUPERPARABOLOID), one[: X.shape[0]])

    def test_cap_closes_the_solid_at_z_0(self):
        params = torch.tensor([0.1, 0.1, 0.2, 1.0, 1.0, 0, 0, 0, 0], dtype=torch.float64)
        x = torch.tensor(
            [[0.0, 0.0, -0.1], [0.05, 0.0, 0.0], [0.0, 0.0, 0.05], [0.0, 0.0, -0.25]],
            dtype=torch.float64,
        )
        f = implicit(x, params, SUPERPARABOLOID)
        assert f[0] < 1 and f[2] > 1 and f[3] > 1
        torch.testing.assert_close(f[1], torch.tensor(1.0, dtype=torch.float64))

    @HYP
    @given(params=deformed_params(), seed=seeds())
    def test_normals_are_orthogonal_to_tangents_and_point_outward(self, params, seed):
        g = torch.Generator().manual_seed(seed)
        theta = _angles(g, 64, -math.pi, math.pi, avoid_quarter=True)
        u = 0.1 + 0.8 * torch.rand(64, generator=g, dtype=torch.float64)
        keep = _unfolded(params, superparaboloid_surface(theta, u, *params[:5].tolist()))
        theta, u = theta[keep], u[keep]

        def surf(t, v):
            return _d(params, superparaboloid_surface(t, v, *params[:5].tolist()))

        X = surf(theta, u)
        n = normal(X, params, SUPERPARABOLOID)
        _assert_orthogonal_to_tangents(n, surf, theta, u)
        h = 1e-5 * float(params[:3].min())
        assert (implicit(X + h * n, params, SUPERPARABOLOID) > 1).all()
        assert (implicit(X - h * n, params, SUPERPARABOLOID) < 1).all()


class TestSupertoroid:
    @HYP
    @given(params=deformed_params(), seed=seeds(), a4=st.floats(1.2, 3.0))
    def test_parametric_points_satisfy_f_equals_1(self, params, seed, a4):
        params = params.clone()
        params[8] = a4
        params[[0, 1]] /= a4  # keep the whole ring within the size range
        g = torch.Generator().manual_seed(seed)
        theta = _angles(g, 64, -math.pi, math.pi, avoid_quarter=False)
        phi = _angles(g, 64, -math.pi, math.pi, avoid_quarter=False)
        a1, a2, a3, e1, e2 = params[:5].tolist()
        x = supertoroid_surface(theta, phi, a1, a2, a3, e1, e2, a4)
        one = torch.ones(64, dtype=torch.float64)
        torch.testing.assert_close(implicit(x, params * _plain_mask(), SUPERTOROID), one)
        X = _d(params, x)[_unfolded(params, x)]
        torch.testing.assert_close(implicit(X, params, SUPERTOROID), one[: X.shape[0]])

    @HYP
    @given(e1=E, e2=E, seed=seeds())
    def test_normals_are_orthogonal_to_tangents_and_point_outward(self, e1, e2, seed):
        params = torch.tensor([0.05, 0.04, 0.06, e1, e2, 0.3, 2.0, 0.5, 2.0], dtype=torch.float64)
        g = torch.Generator().manual_seed(seed)
        theta = _angles(g, 64, -math.pi, math.pi, avoid_quarter=True)
        phi = _angles(g, 64, -math.pi, math.pi, avoid_quarter=True)

        def surf(t, p):
            return _d(params, supertoroid_surface(t, p, 0.05, 0.04, 0.06, e1, e2, 2.0))

        X = surf(theta, phi)
        n = normal(X, params, SUPERTOROID)
        _assert_orthogonal_to_tangents(n, surf, theta, phi)
        h = 1e-6
        assert (implicit(X + h * n, params, SUPERTOROID) > 1).all()
        assert (implicit(X - h * n, params, SUPERTOROID) < 1).all()

    def test_hole_is_outside(self):
        params = torch.tensor([0.05, 0.05, 0.05, 1.0, 1.0, 0, 0, 0, 2.0], dtype=torch.float64)
        x = torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, -0.1, 0.0]], dtype=torch.float64)
        f = implicit(x, params, SUPERTOROID)
        assert f[0] > 1 and f[1] < 1 and f[2] < 1


def _plain_mask() -> torch.Tensor:
    """Multiplier that zeroes k and b in packed params (the undeformed shape)."""
    m = torch.ones(9, dtype=torch.float64)
    m[5] = m[6] = 0
    return m


# --- robustness, batching, gradients, errors ------------------------------------------------------

SPECIAL_POINTS = [
    (0.0, 0.0, 0.0),
    (1e-30, 0.0, 0.0),
    (0.1, 0.0, 0.0),
    (0.0, 0.1, 0.0),
    (0.0, 0.0, 0.1),
    (0.0, 0.0, -0.1),
    (1e6, 0.0, 0.0),
    (0.0, 0.0, 1e6),
    (0.0, 0.0, -1e6),
    (-1e6, 1e6, 1e6),
]
BOUNDS = [
    # a1, a2, a3, e1, e2, k, b, alpha, a4
    (0.1, 0.2, 0.3, 0.2, 0.2, 0.0, 0.0, 0.0, 1.5),
    (0.1, 0.2, 0.3, 1.7, 1.7, 0.0, 0.0, 0.0, 1.5),
    (0.1, 0.2, 0.3, 0.2, 1.7, 0.9, 0.0, 0.0, 1.5),
    (0.1, 0.2, 0.3, 1.7, 0.2, -0.9, 3.75, math.pi, 1.5),
    (0.03, 0.03, 0.03, 0.2, 0.2, 0.9, 25.0, -math.pi, 1.5),
    (0.53, 0.53, 0.53, 1.7, 1.7, -0.9, 0.019, 0.3, 1.5),
]


@pytest.mark.parametrize("kind", [SUPERELLIPSOID, SUPERPARABOLOID, SUPERTOROID])
@pytest.mark.parametrize("bound", BOUNDS, ids=[f"bound{i}" for i in range(len(BOUNDS))])
def test_no_nan_or_inf_on_axes_origin_far_and_parameter_bounds(kind, bound, dtype):
    x = torch.tensor(SPECIAL_POINTS, dtype=dtype).requires_grad_(True)
    params = torch.tensor(bound, dtype=dtype).requires_grad_(True)
    fns = [implicit, implicit_homogeneous]
    if kind == SUPERELLIPSOID:
        fns.append(lambda x, p, kind: radial_distance(x, p))
    for fn in fns:
        out = fn(x, params, kind=kind)
        assert torch.isfinite(out).all()
        gx, gp = torch.autograd.grad(out.sum(), (x, params))
        assert torch.isfinite(gx).all() and torch.isfinite(gp).all()
    n = normal(x, params, kind)
    assert torch.isfinite(n).all()
    # Unit length, except at the origin and on a supertoroid's axis where the direction is undefined.
    assert ((n[2:].norm(dim=-1) - 1).abs() < 1e-3).all()
    assert ((n[:2].norm(dim=-1) - 1).abs() < 1e-3).all() or (n[:2] == 0).any()


@pytest.mark.parametrize("batch", [(), (1,), (3, 1, 2, 1)])
@pytest.mark.parametrize("kind", [SUPERELLIPSOID, SUPERPARABOLOID, SUPERTOROID])
def test_batch_shapes(batch, kind, dtype):
    x = torch.rand(*batch, 5, 3, dtype=dtype)
    params = torch.tensor([0.1, 0.2, 0.3, 0.5, 1.0, 0.2, 1.0, 0.3, 1.5], dtype=dtype).expand(
        *batch, 9
    )
    for fn in (implicit, implicit_homogeneous, normal):
        out = fn(x, params, kind)
        assert out.dtype == dtype
        assert out.shape == ((*batch, 5, 3) if fn is normal else (*batch, 5))
    assert radial_distance(x, params).shape == (*batch, 5)
    if batch:  # every batch entry is evaluated against its own params
        flat = implicit(x.reshape(-1, 5, 3)[:1], params.reshape(-1, 9)[:1], kind)
        torch.testing.assert_close(implicit(x, params, kind).reshape(-1, 5)[:1], flat)


def test_points_broadcast_against_a_batch_of_shapes(dtype):
    x = torch.rand(7, 3, dtype=dtype)
    params = torch.tensor(
        [[0.1, 0.2, 0.3, 0.5, 1.0, 0, 0, 0, 0], [0.3, 0.2, 0.1, 1.0, 0.5, 0.1, 1.0, 0, 0]],
        dtype=dtype,
    )
    for fn in (implicit, implicit_homogeneous, radial_distance):
        out = fn(x, params)
        assert out.shape == (2, 7)
        torch.testing.assert_close(out[1], fn(x, params[1]))


def test_gradcheck_implicit_and_radial_distance_wrt_points_and_params():
    g = torch.Generator().manual_seed(7)
    x = ((torch.rand(6, 3, generator=g, dtype=torch.float64) - 0.5) * 0.5).requires_grad_(True)
    params = torch.tensor(
        [0.2, 0.15, 0.25, 0.7, 1.3, 0.3, 1.5, 0.4, 0.0], dtype=torch.float64, requires_grad=True
    )
    assert torch.autograd.gradcheck(implicit, (x, params))
    assert torch.autograd.gradcheck(implicit_homogeneous, (x, params))
    assert torch.autograd.gradcheck(radial_distance, (x, params))
    assert torch.autograd.gradcheck(lambda x, p: implicit(x, p, SUPERTOROID), (x, params + _a4()))


def _a4() -> torch.Tensor:
    out = torch.zeros(9, dtype=torch.float64)
    out[8] = 1.5
    return out


@pytest.mark.parametrize(
    "x_shape,p_shape,match",
    [
        ((5, 2), (9,), "points"),
        ((3,), (9,), "points"),
        ((5, 3), (8,), "params"),
        ((5, 4), (9,), "points"),
    ],
)
def test_bad_shapes_raise(x_shape, p_shape, match):
    x, p = torch.zeros(x_shape), torch.ones(p_shape)
    for fn in (implicit, implicit_homogeneous, radial_distance, normal):
        with pytest.raises(ValueError, match=match):
            fn(x, p)


def test_unknown_kind_raises():
    with pytest.raises(ValueError, match="kind"):
        implicit(torch.zeros(2, 3), torch.ones(9), kind=3)
