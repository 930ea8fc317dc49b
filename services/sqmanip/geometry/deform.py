"""Global tapering and bending deformations of superquadrics (Ch. 2.3).

All functions take points ``x`` of shape ``(..., 3)`` and deformation parameters
broadcastable to ``(...)``; they return ``(..., 3)`` points or ``(..., 3, 3)`` Jacobians.

Convention:
- ``b`` is the bending curvature (1/m, ``b >= 0``); ``b -> 0`` is the identity. The formulas are
  rewritten so nothing divides by ``b`` directly (stable for ``b = 0`` exactly).
- ``t_k(z)`` is clamped to ``>= TAPER_MIN``; inside ``|z| <= a3`` with ``|k| <= 0.9`` it is >= 0.1,
  so the clamp only changes points far outside the shape (and keeps them outside).
- ``r = x cos(alpha) + y sin(alpha)``: (2.3.16) with ``cos(alpha - atan2(y, x)) sqrt(x^2 + y^2)`` expanded.
"""

from __future__ import annotations

import torch

TAPER_MIN = 0.05


def _t(v, like: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(v, dtype=like.dtype, device=like.device)


def _split(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    if x.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., 3), got {tuple(x.shape)}")
    return x[..., 0], x[..., 1], x[..., 2]


def taper_factor(z: torch.Tensor, k: torch.Tensor, a3: torch.Tensor) -> torch.Tensor:
    """Linear tapering function ``t_k(z) = k z / a3 + 1`` (2.3.12), clamped to ``>= TAPER_MIN``."""
    return (_t(k, z) * z / _t(a3, z) + 1.0).clamp_min(TAPER_MIN)


def taper(x: torch.Tensor, k, a3) -> torch.Tensor:
    """Tapering ``D_t`` (2.3.11): ``(x, y, z) -> (t_k(z) x, t_k(z) y, z)``."""
    px, py, pz = _split(x)
    t = taper_factor(pz, k, a3)
    return torch.stack([t * px, t * py, pz.expand_as(t * px)], dim=-1)


def taper_inverse(X: torch.Tensor, k, a3) -> torch.Tensor:
    """Inverse tapering ``D_t^{-1}`` (2.3.13)."""
    px, py, pz = _split(X)
    t = taper_factor(pz, k, a3)
    return torch.stack([px / t, py / t, pz.expand_as(px / t)], dim=-1)


def taper_jacobian(x: torch.Tensor, k, a3) -> torch.Tensor:
    """Jacobian ``dD_t/dx`` (2.3.14), shape ``(..., 3, 3)``."""
    px, py, pz = _split(x)
    t = taper_factor(pz, k, a3)
    # d t_k / dz = k / a3, and 0 where the clamp of taper_factor is active.
    raw = _t(k, x) * pz / _t(a3, x) + 1.0
    dt = torch.where(raw > TAPER_MIN, _t(k, x) / _t(a3, x), torch.zeros_like(raw))
    dt = torch.broadcast_to(dt, t.shape)
    zero, one = torch.zeros_like(t), torch.ones_like(t)
    rows = [
        torch.stack([t, zero, dt * px], -1),
        torch.stack([zero, t, dt * py], -1),
        torch.stack([zero, zero, one], -1),
    ]
    return torch.stack(rows, dim=-2)


def _bend_terms(x, b, alpha):
    px, py, pz = _split(x)
    alpha = _t(alpha, x)
    ca, sa = torch.cos(alpha), torch.sin(alpha)
    r = px * ca + py * sa
    b = _t(b, x).clamp_min(0.0)
    bsafe = b.clamp_min(1e-12)
    gamma = pz * b
    # (1/b - r) (1 - cos g) = (1 - r b) * 2 sin^2(g / 2) / b ; (1/b - r) sin g = (1 - r b) sin(g) / b
    one_m_rb = 1.0 - r * b
    sin_over_b = torch.where(b > 1e-12, torch.sin(gamma) / bsafe, pz)
    vers_over_b = torch.where(b > 1e-12, 2.0 * torch.sin(gamma / 2) ** 2 / bsafe, 0.5 * pz * gamma)
    return px, py, pz, ca, sa, r, b, gamma, one_m_rb, sin_over_b, vers_over_b


def bend(x: torch.Tensor, b, alpha) -> torch.Tensor:
    """Circular bending ``D_b`` of the z axis in direction ``alpha`` (2.3.15-2.3.16)."""
    px, py, _, ca, sa, _, _, _, one_m_rb, sin_over_b, vers_over_b = _bend_terms(x, b, alpha)
    shift = one_m_rb * vers_over_b  # R - r
    return torch.stack([px + shift * ca, py + shift * sa, one_m_rb * sin_over_b], dim=-1)


def bend_inverse(X: torch.Tensor, b, alpha) -> torch.Tensor:
    """Inverse bending ``D_b^{-1}`` (2.3.17-2.3.18), rewritten to be stable as ``b -> 0``."""
    px, py, pz = _split(X)
    alpha = _t(alpha, X)
    ca, sa = torch.cos(alpha), torch.sin(alpha)
    b = _t(b, X).clamp_min(0.0)
    R = px * ca + py * sa  # R'
    c = 1.0 - b * R  # b (1/b - R')
    # Clamped so the gradient stays finite at the centre of the bending circle (c = Z = 0).
    root = torch.sqrt((c * c + (b * pz) ** 2).clamp_min(1e-30))
    # r' = 1/b - sqrt(Z^2 + (1/b - R')^2) = (R'(2 - bR') - b Z^2) / (1 + root)
    r = (R * (2.0 - b * R) - b * pz * pz) / (1.0 + root)
    gamma = torch.atan2(b * pz, c)
    bsafe = b.clamp_min(1e-12)
    z = torch.where(b > 1e-12, gamma / bsafe, pz / c.clamp_min(1e-12))
    shift = R - r
    return torch.stack([px - shift * ca, py - shift * sa, z], dim=-1)


def bend_jacobian(x: torch.Tensor, b, alpha) -> torch.Tensor:
    """Jacobian ``dD_b/dx`` (2.3.19) with ``r_x = cos(alpha)``, ``r_y = sin(alpha)`` (2.3.20)."""
    _, _, _, ca, sa, _, b, gamma, one_m_rb, _, _ = _bend_terms(x, b, alpha)
    cg, sg = torch.cos(gamma), torch.sin(gamma)
    ca, sa = torch.broadcast_to(ca, cg.shape), torch.broadcast_to(sa, cg.shape)
    rows = [
        torch.stack([1 + ca * (cg - 1) * ca, sa * (cg - 1) * ca, one_m_rb * sg * ca], -1),
        torch.stack([ca * (cg - 1) * sa, 1 + sa * (cg - 1) * sa, one_m_rb * sg * sa], -1),
        torch.stack([-ca * sg, -sa * sg, one_m_rb * cg], -1),
    ]
    return torch.stack(rows, dim=-2)


def deform(x: torch.Tensor, k, a3, b, alpha) -> torch.Tensor:
    """Combined deformation ``D = D_b o D_t`` (Ch. 2.3.3)."""
    return bend(taper(x, k, a3), b, alpha)


def deform_inverse(X: torch.Tensor, k, a3, b, alpha) -> torch.Tensor:
    """``D^{-1} = D_t^{-1} o D_b^{-1}``."""
    return taper_inverse(bend_inverse(X, b, alpha), k, a3)


def deform_jacobian(x: torch.Tensor, k, a3, b, alpha) -> torch.Tensor:
    """``dD/dx = dD_b/dx(D_t(x)) dD_t/dx(x)`` (2.3.22), shape ``(..., 3, 3)``."""
    return bend_jacobian(taper(x, k, a3), b, alpha) @ taper_jacobian(x, k, a3)


def cofactor(J: torch.Tensor) -> torch.Tensor:
    """``det(J) J^{-T}`` computed from column cross products (no inversion), ``(..., 3, 3)``."""
    c1, c2, c3 = J[..., :, 0], J[..., :, 1], J[..., :, 2]
    return torch.stack(
        [torch.linalg.cross(c2, c3), torch.linalg.cross(c3, c1), torch.linalg.cross(c1, c2)], dim=-1
    )


def deform_normal(x: torch.Tensor, n: torch.Tensor, k, a3, b, alpha) -> torch.Tensor:
    """Normal of the deformed surface at ``D(x)`` from the normal ``n`` at ``x`` (2.3.21)."""
    J = deform_jacobian(x, k, a3, b, alpha)
    return (cofactor(J) @ n.unsqueeze(-1)).squeeze(-1)
