"""Tapering and bending (Ch. 2.3): forward, inverse, Jacobians, normal transport."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from sq_strategies import ALPHA, B_PRIME, SIZE, K, seeds
from sqmanip.geometry.deform import (
    TAPER_MIN,
    bend,
    bend_inverse,
    bend_jacobian,
    cofactor,
    deform,
    deform_inverse,
    deform_jacobian,
    deform_normal,
    taper,
    taper_inverse,
    taper_jacobian,
)

HYP = settings(max_examples=25, deadline=None)


def _points(seed: int, a: tuple[float, float, float], n: int = 64, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    box = torch.tensor(a, dtype=dtype) * 1.2
    return (torch.rand(n, 3, generator=g, dtype=dtype) * 2 - 1) * box


def _autograd_jacobian(fn, x: torch.Tensor) -> torch.Tensor:
    """Per-point Jacobian ``(..., 3, 3)`` of a pointwise map, by three backward passes."""
    x = x.detach().requires_grad_(True)
    y = fn(x)
    rows = [torch.autograd.grad(y[..., i].sum(), x, retain_graph=True)[0] for i in range(3)]
    return torch.stack(rows, dim=-2)


def _fd_jacobian(fn, x: torch.Tensor, h: float = 1e-6) -> torch.Tensor:
    cols = []
    for j in range(3):
        e = torch.zeros(3, dtype=x.dtype)
        e[j] = h
        cols.append((fn(x + e) - fn(x - e)) / (2 * h))
    return torch.stack(cols, dim=-1)


def _bend_thesis(x: torch.Tensor, b: float, alpha: float) -> torch.Tensor:
    """(2.3.15)-(2.3.16) written literally (with 1/b and atan2), for b well away from 0."""
    px, py, pz = x.unbind(-1)
    gamma = pz * b
    r = torch.cos(alpha - torch.atan2(py, px)) * torch.sqrt(px**2 + py**2)
    R = 1 / b - (1 / b - r) * torch.cos(gamma)
    return torch.stack(
        [
            px + (R - r) * math.cos(alpha),
            py + (R - r) * math.sin(alpha),
            (1 / b - r) * torch.sin(gamma),
        ],
        -1,
    )


def _bend_inverse_thesis(X: torch.Tensor, b: float, alpha: float) -> torch.Tensor:
    """(2.3.17)-(2.3.18) written literally."""
    px, py, pz = X.unbind(-1)
    Rp = torch.cos(alpha - torch.atan2(py, px)) * torch.sqrt(px**2 + py**2)
    rp = 1 / b - torch.sqrt(pz**2 + (1 / b - Rp) ** 2)
    gp = torch.atan2(pz, 1 / b - Rp)
    return torch.stack(
        [px - (Rp - rp) * math.cos(alpha), py - (Rp - rp) * math.sin(alpha), gp / b], -1
    )


def _unfolded(x: torch.Tensor, k, a3, b, alpha, margin: float = 0.05) -> torch.Tensor:
    """Mask of points where D is one-to-one: r b < 1 after tapering (the bending circle's centre
    is not crossed) and the taper clamp is inactive. Within the thesis' ranges b' t_k(z) can
    exceed 1, so some tapered, bent shapes fold over themselves; D^{-1} D = id holds off the fold.
    """
    xt = taper(x, k, a3)
    r = xt[..., 0] * math.cos(alpha) + xt[..., 1] * math.sin(alpha)
    t = k * x[..., 2] / a3 + 1
    return (
        (r * b < 1 - margin) & (t > TAPER_MIN + margin) & ((x[..., 2] * b).abs() < math.pi - margin)
    )


class TestTaper:
    @HYP
    @given(k=K, a3=SIZE, seed=seeds())
    def test_jacobian_matches_autograd_and_finite_differences(self, k, a3, seed):
        x = _points(seed, (0.3, 0.3, a3))
        J = taper_jacobian(x, k, a3)
        torch.testing.assert_close(J, _autograd_jacobian(lambda p: taper(p, k, a3), x))
        torch.testing.assert_close(
            J, _fd_jacobian(lambda p: taper(p, k, a3), x), rtol=1e-6, atol=1e-7
        )

    def test_jacobian_is_consistent_where_taper_factor_is_clamped(self):
        # Regression: the Jacobian used d t/dz = k/a3 even where t_k(z) is clamped to TAPER_MIN.
        x = torch.tensor([[0.3, 0.2, -2.0], [0.1, -0.4, 3.0]], dtype=torch.float64)
        for k in (0.9, -0.9):
            J = taper_jacobian(x, k, 1.0)
            torch.testing.assert_close(J, _autograd_jacobian(lambda p, k=k: taper(p, k, 1.0), x))

    @HYP
    @given(k=K, a3=SIZE, seed=seeds())
    def test_inverse_undoes_forward(self, k, a3, seed):
        x = _points(seed, (0.3, 0.3, a3))
        torch.testing.assert_close(taper_inverse(taper(x, k, a3), k, a3), x)

    def test_zero_taper_is_identity(self, dtype):
        x = _points(0, (0.3, 0.3, 0.3), dtype=dtype)
        torch.testing.assert_close(taper(x, 0.0, 0.2), x)
        torch.testing.assert_close(
            taper_jacobian(x, 0.0, 0.2), torch.eye(3, dtype=dtype).expand(64, 3, 3)
        )

    def test_matches_equation_2_3_12(self):
        x = torch.tensor([0.1, -0.2, 0.05], dtype=torch.float64)
        t = 0.5 * 0.05 / 0.1 + 1  # k z / a3 + 1
        torch.testing.assert_close(
            taper(x, 0.5, 0.1), torch.tensor([0.1 * t, -0.2 * t, 0.05], dtype=torch.float64)
        )


class TestBend:
    @HYP
    @given(bp=B_PRIME, alpha=ALPHA, a=SIZE, seed=seeds())
    def test_jacobian_matches_autograd_and_finite_differences(self, bp, alpha, a, seed):
        b = bp / a
        x = _points(seed, (a, a, a))
        J = bend_jacobian(x, b, alpha)
        torch.testing.assert_close(J, _autograd_jacobian(lambda p: bend(p, b, alpha), x))
        torch.testing.assert_close(
            J, _fd_jacobian(lambda p: bend(p, b, alpha), x), rtol=1e-6, atol=1e-7
        )

    @HYP
    @given(bp=B_PRIME, alpha=ALPHA, a=SIZE, seed=seeds())
    def test_forward_and_inverse_match_thesis_formulas(self, bp, alpha, a, seed):
        b = bp / a
        x = _points(seed, (a, a, a))
        x = x[_unfolded(x, 0.0, a, b, alpha)]
        X = bend(x, b, alpha)
        torch.testing.assert_close(X, _bend_thesis(x, b, alpha))
        torch.testing.assert_close(bend_inverse(X, b, alpha), _bend_inverse_thesis(X, b, alpha))
        torch.testing.assert_close(bend_inverse(X, b, alpha), x)

    def test_zero_bend_is_identity_with_finite_gradients(self, dtype):
        x = _points(1, (0.3, 0.3, 0.3), dtype=dtype)
        b = torch.zeros((), dtype=dtype, requires_grad=True)
        X = bend(x, b, 0.4)
        torch.testing.assert_close(X, x)
        torch.testing.assert_close(bend_inverse(x, b, 0.4), x)
        torch.testing.assert_close(
            bend_jacobian(x, b, 0.4), torch.eye(3, dtype=dtype).expand(64, 3, 3)
        )
        (g,) = torch.autograd.grad((X.sum() + bend_inverse(x, b, 0.4).sum()), b)
        assert torch.isfinite(g)

    def test_tiny_bend_is_continuous_with_zero(self):
        x = _points(2, (0.3, 0.3, 0.3))
        for b in (1e-13, 1e-11, 1e-8):
            torch.testing.assert_close(bend(x, b, 1.0), x, rtol=0, atol=1e-7)
            torch.testing.assert_close(bend_inverse(bend(x, b, 1.0), b, 1.0), x)

    def test_direction_alpha_bends_towards_alpha(self):
        # A point on the z axis at height z moves by (R - r) = (1 - cos(zb))/b along (cos a, sin a).
        b, alpha, z = 2.0, 0.7, 0.3
        X = bend(torch.tensor([0.0, 0.0, z], dtype=torch.float64), b, alpha)
        shift = (1 - math.cos(z * b)) / b
        expected = torch.tensor(
            [shift * math.cos(alpha), shift * math.sin(alpha), math.sin(z * b) / b],
            dtype=torch.float64,
        )
        torch.testing.assert_close(X, expected)


class TestCombined:
    @HYP
    @given(k=K, bp=B_PRIME, alpha=ALPHA, a1=SIZE, a2=SIZE, a3=SIZE, seed=seeds())
    def test_jacobian_matches_autograd_and_finite_differences(self, k, bp, alpha, a1, a2, a3, seed):
        b = bp / max(a1, a2)
        x = _points(seed, (a1, a2, a3))

        def fn(p):
            return deform(p, k, a3, b, alpha)

        J = deform_jacobian(x, k, a3, b, alpha)
        torch.testing.assert_close(J, _autograd_jacobian(fn, x))
        torch.testing.assert_close(J, _fd_jacobian(fn, x), rtol=1e-6, atol=1e-7)

    @HYP
    @given(k=K, bp=B_PRIME, alpha=ALPHA, a1=SIZE, a2=SIZE, a3=SIZE, seed=seeds())
    def test_inverse_undoes_forward_off_the_fold(self, k, bp, alpha, a1, a2, a3, seed):
        b = bp / max(a1, a2)
        x = _points(seed, (a1, a2, a3), n=256)
        x = x[_unfolded(x, k, a3, b, alpha)]
        assert x.shape[0] > 0
        X = deform(x, k, a3, b, alpha)
        torch.testing.assert_close(deform_inverse(X, k, a3, b, alpha), x, rtol=1e-8, atol=1e-10)

    def test_inverse_undoes_forward_in_float32(self):
        x = _points(3, (0.2, 0.1, 0.3), dtype=torch.float32)
        X = deform(x, 0.5, 0.3, 1.5, 0.3)
        torch.testing.assert_close(deform_inverse(X, 0.5, 0.3, 1.5, 0.3), x, rtol=1e-4, atol=1e-5)

    def test_deformations_do_not_commute(self):
        x = _points(4, (0.2, 0.2, 0.2))
        Dbt = bend(taper(x, 0.8, 0.2), 2.0, 0.0)
        Dtb = taper(bend(x, 2.0, 0.0), 0.8, 0.2)
        torch.testing.assert_close(deform(x, 0.8, 0.2, 2.0, 0.0), Dbt)
        assert (Dbt - Dtb).abs().max() > 1e-3

    def test_gradcheck_inverse_wrt_points_and_params(self):
        x = _points(5, (0.2, 0.15, 0.25), n=6).requires_grad_(True)
        p = torch.tensor([0.4, 0.25, 2.0, 0.6], dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(
            lambda x, p: deform_inverse(x, p[0], p[1], p[2], p[3]), (x, p)
        )

    @pytest.mark.parametrize("batch", [(), (1,), (3, 1, 2, 1)])
    def test_batch_shapes(self, batch, dtype):
        x = torch.rand(*batch, 3, dtype=dtype)
        k = torch.full(batch, 0.3, dtype=dtype)
        assert deform(x, k, 0.2, 1.0, 0.1).shape == (*batch, 3)
        assert deform_inverse(x, k, 0.2, 1.0, 0.1).shape == (*batch, 3)
        assert deform_jacobian(x, k, 0.2, 1.0, 0.1).shape == (*batch, 3, 3)
        assert deform_normal(x, x, k, 0.2, 1.0, 0.1).shape == (*batch, 3)

    @pytest.mark.parametrize(
        "point",
        [
            (0, 0, 0),
            (1, 0, 0),
            (0, 1, 0),
            (0, 0, 1),
            (0, 0, -1),
            (1e6, 0, 0),
            (0, 0, 1e6),
            (-1e6, 1e6, -1e6),
        ],
    )
    @pytest.mark.parametrize("k,b", [(0.0, 0.0), (0.9, 0.0), (-0.9, 0.0), (0.9, 1.5), (-0.9, 37.5)])
    def test_finite_on_axes_origin_far_and_bounds(self, point, k, b, dtype):
        x = torch.tensor([point], dtype=dtype).requires_grad_(True)
        for fn in (deform, deform_inverse, deform_jacobian):
            out = fn(x, k, 0.02, b, 0.3)
            assert torch.isfinite(out).all(), fn.__name__
            (g,) = torch.autograd.grad(out.sum(), x)
            assert torch.isfinite(g).all(), fn.__name__

    @pytest.mark.parametrize("shape", [(3, 2), (2,), (4, 4)])
    def test_bad_point_shapes_raise(self, shape):
        x = torch.zeros(shape)
        for fn in (taper, taper_inverse, taper_jacobian):
            with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
                fn(x, 0.1, 1.0)
        for fn in (bend, bend_inverse, bend_jacobian):
            with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
                fn(x, 0.1, 1.0)


class TestNormalTransport:
    def test_cofactor_is_det_times_inverse_transpose(self, dtype, tol):
        J = torch.randn(10, 3, 3, dtype=dtype, generator=torch.Generator().manual_seed(0))
        expected = torch.linalg.det(J)[:, None, None] * torch.linalg.inv(J).transpose(-1, -2)
        torch.testing.assert_close(cofactor(J), expected, **tol(dtype, 10))

    @HYP
    @given(k=K, bp=B_PRIME, alpha=ALPHA, a=SIZE, seed=seeds())
    def test_transported_normal_is_orthogonal_to_pushed_tangents(self, k, bp, alpha, a, seed):
        # For any tangent t at x (t . n = 0), J t is tangent at D(x): (cof(J) n) . (J t) = det(J) n . t = 0.
        b = bp / a
        g = torch.Generator().manual_seed(seed)
        x = _points(seed, (a, a, a), n=32)
        n = torch.randn(32, 3, dtype=torch.float64, generator=g)
        t = torch.linalg.cross(n, torch.randn(32, 3, dtype=torch.float64, generator=g))
        N = deform_normal(x, n, k, a, b, alpha)
        Jt = (deform_jacobian(x, k, a, b, alpha) @ t.unsqueeze(-1)).squeeze(-1)
        cos = (N * Jt).sum(-1) / (N.norm(dim=-1) * Jt.norm(dim=-1))
        assert cos.abs().max() < 1e-9
