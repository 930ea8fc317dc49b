"""Superquadric implicit functions, surfaces, normals and radial distance (Ch. 2.2, 3.3.2).

Shapes are described by a packed parameter tensor ``params`` of shape ``(..., 9)`` laid out as
``PARAM_NAMES`` (``a1 a2 a3 e1 e2 k b alpha a4``) and an integer ``kind`` (``KINDS``). Functions
evaluate points ``x`` of shape ``(..., N, 3)`` given in the shape's own (object) frame against
params of shape ``(..., 9)`` (one shape per leading batch entry) and return ``(..., N)``.

Convention:
- the deformed shape is ``f o D^{-1}`` with ``D = D_b o D_t`` (2.3.22); k = b = 0 is plain;
- shape exponents are clamped to ``[0.2, 1.7]``; ``f`` saturates at ``e^MAX_LOG`` (~5.5e34) far away
  (computed in the log domain, so no power overflows, even in float32);
- :func:`implicit_homogeneous` is ``f^{e1}`` (the ``S^{e1}`` of C.2): ``< 1`` inside, ``> 1`` outside,
  and for superellipsoids it grows like distance squared, so thresholds behave alike for all shapes;
- the radial distance at the exact origin of a superellipsoid is taken along +z (``= a3``).
"""

from __future__ import annotations

import torch

from .deform import cofactor, deform_inverse, deform_jacobian
from .numerics import abs_pow, clamp_shape, finite_max, signed_pow, tiny

PARAM_NAMES = ("a1", "a2", "a3", "e1", "e2", "k", "b", "alpha", "a4")
N_PARAMS = len(PARAM_NAMES)
SUPERELLIPSOID, SUPERPARABOLOID, SUPERTOROID = 0, 1, 2
KINDS = ("superellipsoid", "superparaboloid", "supertoroid")


def check_points(x: torch.Tensor, name: str = "points") -> None:
    if x.ndim < 2 or x.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., N, 3), got {tuple(x.shape)}")


def check_params(params: torch.Tensor) -> None:
    if params.shape[-1] != N_PARAMS:
        raise ValueError(f"params must have shape (..., {N_PARAMS}), got {tuple(params.shape)}")


def unpack(params: torch.Tensor) -> list[torch.Tensor]:
    """Split ``(..., 9)`` params into nine ``(..., 1)`` tensors (broadcast against ``(..., N)``)."""
    check_params(params)
    parts = list(params.unsqueeze(-2).unbind(-1))
    parts[3], parts[4] = clamp_shape(parts[3]), clamp_shape(parts[4])
    return parts


def is_deformed(params: torch.Tensor) -> bool:
    return bool((params[..., 5].abs() > 0).any() or (params[..., 6].abs() > 0).any())


def undeform(x: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
    """Map object-frame points ``(..., N, 3)`` to the undeformed canonical frame: ``D^{-1}(x)``."""
    if not is_deformed(params):  # D is exactly the identity for k = b = 0; skip its cost
        return x
    _, _, a3, _, _, k, b, alpha, _ = unpack(params)
    return deform_inverse(x, k, a3, b, alpha)


# --- canonical (undeformed) implicit functions -------------------------------------------------


MAX_LOG = 80.0
"""``log`` of the value at which implicit functions saturate (``e^80 ~ 5.5e34``, finite in float32)."""


def _superellipsoid_parts(x, a1, a2, a3, e1, e2):
    """Return ``(r, g)`` with ``f(x) = r^{2/e1} g`` and ``g`` in ``[1, 2^{e2/e1} + 1]`` (scale trick).

    ``r`` is clamped to ``>= tiny``; where it is (the origin), ``g`` is meaningless but finite.
    """
    q = torch.stack([(x[..., 0] / a1).abs(), (x[..., 1] / a2).abs(), (x[..., 2] / a3).abs()], -1)
    r = q.amax(-1).clamp_min(tiny(x.dtype))
    u = q / r.unsqueeze(-1)
    inner = (abs_pow(u[..., 0], 2 / e2) + abs_pow(u[..., 1], 2 / e2)).clamp_min(tiny(x.dtype))
    g = inner.pow(e2 / e1) + abs_pow(u[..., 2], 2 / e1)
    return r, g.clamp_min(tiny(x.dtype))


def _xy_parts(x, a1, a2, e2):
    """``(s, p)`` with ``|x/a1|^{2/e2} + |y/a2|^{2/e2} = s^{2/e2} p``, ``p`` in ``[1, 2]``.

    Scaling by ``s = max(|x/a1|, |y/a2|)`` keeps the powers from overflowing far away.
    """
    q1, q2 = (x[..., 0] / a1).abs(), (x[..., 1] / a2).abs()
    s = torch.maximum(q1, q2).clamp_min(tiny(x.dtype))
    p = (abs_pow(q1 / s, 2 / e2) + abs_pow(q2 / s, 2 / e2)).clamp_min(tiny(x.dtype))
    return s, p


def superellipsoid_implicit(x, a1, a2, a3, e1, e2, max_log: float = MAX_LOG) -> torch.Tensor:
    """Superellipsoid inside-outside function ``f`` (2.2.1), saturating at ``e^max_log``."""
    r, g = _superellipsoid_parts(x, a1, a2, a3, e1, e2)
    logf = (2 / e1) * torch.log(r) + torch.log(g)
    return torch.exp(logf.clamp_max(max_log)).clamp_max(finite_max(x.dtype))


def superparaboloid_implicit(x, a1, a2, a3, e1, e2, max_log: float = MAX_LOG) -> torch.Tensor:
    """Superparaboloid ``f`` (2.2.7) closed by the cap ``z = 0`` of its parametrisation (2.2.8).

    ``f = max(P^{e2/e1} - z/a3, 1 + z/a3) >= 1/2`` with ``P = |x/a1|^{2/e2} + |y/a2|^{2/e2}``:
    the solid is the paraboloid bowl from the tip ``z = -a3`` up to the flat cap at ``z = 0``.
    """
    s, p = _xy_parts(x, a1, a2, e2)
    log_term = (2 / e1) * torch.log(s) + (e2 / e1) * torch.log(p)
    term = torch.exp(log_term.clamp_max(max_log))
    f = torch.maximum(term - x[..., 2] / a3, 1.0 + x[..., 2] / a3)
    return f.clamp(-finite_max(x.dtype), finite_max(x.dtype))


def supertoroid_implicit(x, a1, a2, a3, e1, e2, a4, max_log: float = MAX_LOG) -> torch.Tensor:
    """Supertoroid ``f`` (2.2.9); ``a4`` sets the hole, ``a1, a2`` the tube thickness.

    Evaluated as ``m^{2/e1} (|ring/m|^{2/e1} + |z/(a3 m)|^{2/e1})`` with
    ``m = max(|ring|, |z/a3|)`` so it saturates instead of overflowing far away.
    """
    s, p = _xy_parts(x, a1, a2, e2)
    ring = s * p.pow(e2 / 2) - a4
    zz = (x[..., 2] / a3).abs()
    m = torch.maximum(ring.abs(), zz).clamp_min(tiny(x.dtype))
    g = (abs_pow(ring / m, 2 / e1) + abs_pow(zz / m, 2 / e1)).clamp_min(tiny(x.dtype))
    logf = (2 / e1) * torch.log(m) + torch.log(g)
    return torch.exp(logf.clamp_max(max_log)).clamp_max(finite_max(x.dtype))


def _canonical(x, parts, kind: int, max_log: float = MAX_LOG) -> torch.Tensor:
    a1, a2, a3, e1, e2, _, _, _, a4 = parts
    if kind == SUPERELLIPSOID:
        return superellipsoid_implicit(x, a1, a2, a3, e1, e2, max_log)
    if kind == SUPERPARABOLOID:
        return superparaboloid_implicit(x, a1, a2, a3, e1, e2, max_log)
    if kind == SUPERTOROID:
        return supertoroid_implicit(x, a1, a2, a3, e1, e2, a4, max_log)
    raise ValueError(
        f"unknown superquadric kind {kind!r}; expected one of {list(range(len(KINDS)))}"
    )


# --- deformed implicit function, radial distance, normals ----------------------------------------


def implicit(x: torch.Tensor, params: torch.Tensor, kind: int = SUPERELLIPSOID) -> torch.Tensor:
    """Deformed implicit function ``f_D(x) = f(D^{-1}(x))`` (Ch. 2.3.3): ``(..., N, 3) -> (..., N)``."""
    check_points(x)
    parts = unpack(params)
    return _canonical(undeform(x, params), parts, kind)


def implicit_homogeneous(
    x: torch.Tensor, params: torch.Tensor, kind: int = SUPERELLIPSOID
) -> torch.Tensor:
    """``f_D^{e1}`` (the ``S^{e1}`` of C.2.5): ``< 1`` inside, ``> 1`` outside, ``(..., N)``."""
    check_points(x)
    parts = unpack(params)
    xc = undeform(x, params)
    if kind == SUPERELLIPSOID:
        r, g = _superellipsoid_parts(xc, *parts[:5])
        return (r * r * g.pow(parts[3])).clamp_max(finite_max(x.dtype))
    f = _canonical(xc, parts, kind)  # >= 1/2 for superparaboloids, >= 0 for supertoroids
    logf = parts[3] * torch.log(f.clamp_min(tiny(x.dtype)))
    return torch.exp(logf.clamp_max(MAX_LOG))


def radial_distance(x: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
    """Radial distance of a (deformed) superellipsoid (2.2.6, 3.3.4): ``(..., N, 3) -> (..., N)``.

    ``delta = ||x0|| |1 - f^{-e1/2}(D^{-1} x0)|``, where ``x0`` is the object-frame point.
    """
    check_points(x)
    parts = unpack(params)
    xc = undeform(x, params)
    r, g = _superellipsoid_parts(xc, *parts[:5])
    norm = torch.linalg.vector_norm(x, dim=-1)
    # ||x0|| f^{-e1/2}(xc) with f^{e1/2} = r g^{e1/2}. Where r was not clamped, g >= 1 and the
    # quotient is finite; where it was (xc at the origin, to the dtype's resolution) the ray
    # direction is undefined and +z is used. The denominator is replaced *before* dividing so
    # neither the value nor the gradient of the unused branch can be inf/NaN.
    at_origin = r <= tiny(x.dtype)
    den = torch.where(at_origin, torch.ones_like(r), r * g.pow(parts[3] / 2))
    surface = torch.where(at_origin, parts[2], norm / den)
    return (norm - surface).abs()


def superellipsoid_gradient_direction(xc, a1, a2, a3, e1, e2) -> torch.Tensor:
    """Direction of ``grad f`` of a plain superellipsoid at canonical points, ``(..., N, 3)``.

    Evaluated at the rescaled point ``u = x / r`` (same direction since ``f`` is homogeneous).
    """
    q = torch.stack([xc[..., 0] / a1, xc[..., 1] / a2, xc[..., 2] / a3], -1)
    r = q.abs().amax(-1, keepdim=True).clamp_min(tiny(xc.dtype))
    u = q / r
    inner = (abs_pow(u[..., 0], 2 / e2) + abs_pow(u[..., 1], 2 / e2)).clamp_min(tiny(xc.dtype))
    common = inner.pow(e2 / e1 - 1)
    gx = common * signed_pow(u[..., 0], 2 / e2 - 1) / a1
    gy = common * signed_pow(u[..., 1], 2 / e2 - 1) / a2
    gz = signed_pow(u[..., 2], 2 / e1 - 1) / a3
    return torch.stack([gx, gy, gz], -1)


def _canonical_gradient(xc, parts, kind):
    if kind == SUPERELLIPSOID:
        return superellipsoid_gradient_direction(xc, *parts[:5])
    # Autograd in float64 with a saturation far above float32's range, so the direction stays
    # defined far away; normalised before casting back so it cannot overflow.
    with torch.enable_grad():
        xg = xc.detach().to(torch.float64).requires_grad_(True)
        f = _canonical(xg, [p.detach().to(torch.float64) for p in parts], kind, max_log=700.0)
        (grad,) = torch.autograd.grad(f.sum(), xg)
    grad = grad / torch.linalg.vector_norm(grad, dim=-1, keepdim=True).clamp_min(1e-300)
    return grad.to(xc.dtype)


def normal(x: torch.Tensor, params: torch.Tensor, kind: int = SUPERELLIPSOID) -> torch.Tensor:
    """Outward unit normal of the deformed surface through ``x`` (2.2.3, 2.3.21), ``(..., N, 3)``.

    ``N(X) = det(dD/dx) (dD/dx)^{-T} n(x)`` with ``x = D^{-1}(X)`` and ``n = grad f``.
    """
    check_points(x)
    parts = unpack(params)
    _, _, a3, _, _, k, b, alpha, _ = parts
    xc = undeform(x, params)
    n = _canonical_gradient(xc, parts, kind)
    N = (cofactor(deform_jacobian(xc, k, a3, b, alpha)) @ n.unsqueeze(-1)).squeeze(-1)
    return N / torch.linalg.vector_norm(N, dim=-1, keepdim=True).clamp_min(tiny(x.dtype))


# --- parametric surfaces -------------------------------------------------------------------------


def superellipsoid_surface(eta, omega, a1, a2, a3, e1, e2) -> torch.Tensor:
    """Parametric superellipsoid (2.2.2), ``eta`` in [-pi/2, pi/2], ``omega`` in [-pi, pi]."""
    ce, se = signed_pow(torch.cos(eta), e1), signed_pow(torch.sin(eta), e1)
    cw, sw = signed_pow(torch.cos(omega), e2), signed_pow(torch.sin(omega), e2)
    return torch.stack([a1 * ce * cw, a2 * ce * sw, a3 * se], -1)


def superellipsoid_parametric_normal(eta, omega, a1, a2, a3, e1, e2) -> torch.Tensor:
    """Unnormalised outward normal direction (2.2.3) at parameters ``(eta, omega)``."""
    ce, se = signed_pow(torch.cos(eta), 2 - e1), signed_pow(torch.sin(eta), 2 - e1)
    cw, sw = signed_pow(torch.cos(omega), 2 - e2), signed_pow(torch.sin(omega), 2 - e2)
    return torch.stack([ce * cw / a1, ce * sw / a2, se / a3], -1)


def superparaboloid_surface(theta, u, a1, a2, a3, e1, e2) -> torch.Tensor:
    """Parametric superparaboloid (2.2.8), ``theta`` in [-pi, pi], ``u`` in [0, 1]."""
    ct, st = signed_pow(torch.cos(theta), e2), signed_pow(torch.sin(theta), e2)
    return torch.stack([a1 * u * ct, a2 * u * st, a3 * (abs_pow(u, 2 / e1) - 1)], -1)


def supertoroid_surface(theta, phi, a1, a2, a3, e1, e2, a4) -> torch.Tensor:
    """Parametric supertoroid (2.2.10), ``theta, phi`` in [-pi, pi]."""
    ring = a4 + signed_pow(torch.cos(theta), e1)
    cp, sp = signed_pow(torch.cos(phi), e2), signed_pow(torch.sin(phi), e2)
    return torch.stack([a1 * ring * cp, a2 * ring * sp, a3 * signed_pow(torch.sin(theta), e1)], -1)
