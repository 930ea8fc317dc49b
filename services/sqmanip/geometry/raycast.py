"""Intersections of lines with posed (deformed) superquadrics (3.4.1).

A line ``x(t) = o + t d`` meets the posed shape where ``g(t) = f_D(T^{-1} x(t)) - 1 = 0`` (3.4.1), which
has no closed form. We solve ``h(t) = f_D^{e1}(T^{-1} x(t)) - 1 = 0`` (the homogeneous form
:func:`implicit_homogeneous`, which grows like distance squared for superellipsoids, so Newton
steps stay well scaled even for ``e = 0.2``):

1. the search interval is the chord of a closed-form bound of the shape, as in 3.4.1 where the
   initial guesses are the intersections with a sphere. For unbent shapes the bound is the
   oriented box ``|x| <= (a1 (1 + |k|), a2 (1 + |k|), a3)`` (``(1 + a4)`` on x, y for toroids),
   which lies inside the sphere of radius ``|a|``; for bent shapes it is the sphere of radius
   ``sqrt(1 + b r_max) * |a~|`` (bending maps ``|x|^2`` to at most ``(1 + b |r|) |x|^2``);
2. ``n_scan`` uniform samples of ``h`` on the chord; every sign change brackets one root
   (tangent double roots, where ``h`` touches 0 without crossing, are not reported);
3. each bracket is refined by Newton-Raphson on ``h`` (derivative by autograd), safeguarded by
   bisection whenever a Newton step leaves the bracket, so boxy and deformed shapes converge.

Roots with ``t > t_min`` are returned sorted, padded to the largest count with ``valid = False``.
``t`` is in units of ``|d|`` (directions are not normalised).
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from .numerics import as_tensor
from .superquadric import (
    SUPERELLIPSOID,
    SUPERTOROID,
    check_params,
    implicit_homogeneous,
)
from .transforms import se3_inverse

BOUND_MARGIN = 1.01


class LineHits(NamedTuple):
    """Sorted roots ``t (..., L, K)`` of each line, ``valid (..., L, K)`` marks real ones."""

    t: torch.Tensor
    valid: torch.Tensor


def bound_box(params: torch.Tensor, kind: int) -> torch.Tensor:
    """Half extents ``(..., 3)`` of the object-frame box containing the *tapered* shape."""
    a = params[..., :3].abs()
    k = params[..., 5].abs().unsqueeze(-1)
    grow = torch.cat([1 + k, 1 + k, torch.ones_like(k)], -1)
    if kind == SUPERTOROID:
        a4 = params[..., 8].abs().unsqueeze(-1)
        grow = grow * torch.cat([1 + a4, 1 + a4, torch.ones_like(a4)], -1)
    # 1 % margin: a box-like shape touches its box (f = 1 at face centres), and the scan's end
    # samples must lie strictly outside so the last crossing is bracketed in float32 too.
    return a * grow * BOUND_MARGIN


def bound_radius(params: torch.Tensor, kind: int) -> torch.Tensor:
    """Radius ``(...)`` of an origin-centred sphere containing the deformed shape (see module doc)."""
    box = bound_box(params, kind)
    r = torch.linalg.vector_norm(box, dim=-1)
    r_max = torch.linalg.vector_norm(box[..., :2], dim=-1)
    b = params[..., 6].abs()
    return r * torch.sqrt(1 + b * r_max)


def _chord_sphere(o, d, radius):
    """``t`` interval where ``|o + t d| <= radius``; ``hit`` False when the line misses."""
    dd = (d * d).sum(-1).clamp_min(1e-30)
    od = (o * d).sum(-1)
    oo = (o * o).sum(-1)
    disc = od * od - dd * (oo - radius * radius)
    root = disc.clamp_min(0).sqrt()
    return (-od - root) / dd, (-od + root) / dd, disc > 0


def _chord_box(o, d, half):
    """Slab test: ``t`` interval inside the box ``|x| <= half``."""
    big = 1e30
    inv = 1.0 / torch.where(d.abs() < 1e-30, torch.full_like(d, 1e-30), d)
    t1, t2 = (-half - o) * inv, (half - o) * inv
    lo = torch.minimum(t1, t2)
    hi = torch.maximum(t1, t2)
    parallel = d.abs() < 1e-30
    inside = (o.abs() <= half).expand_as(parallel)
    lo = torch.where(parallel, torch.where(inside, -big, big), lo)
    hi = torch.where(parallel, torch.where(inside, big, -big), hi)
    t0, t1_ = lo.amax(-1), hi.amin(-1)
    return t0, t1_, t1_ > t0


def search_interval(o_local, d_local, params, kind):
    """Closed-form bound chord ``(t0, t1, hit)`` for object-frame lines, shapes ``(..., L)``."""
    p = params.unsqueeze(-2)
    s0, s1, shit = _chord_sphere(o_local, d_local, bound_radius(p, kind))
    b0, b1, bhit = _chord_box(o_local, d_local, bound_box(p, kind))
    bent = (p[..., 6].abs() > 0).expand_as(s0)
    t0 = torch.where(bent, s0, b0)
    t1 = torch.where(bent, s1, b1)
    hit = torch.where(bent, shit, bhit)
    return t0, t1, hit


def _h(t, o, d, params, kind):
    x = o + t.unsqueeze(-1) * d
    return implicit_homogeneous(x.unsqueeze(-2), params, kind).squeeze(-1) - 1.0


def _refine(lo, hi, hlo, o, d, params, kind, iters):
    """Safeguarded Newton on flat brackets ``lo, hi (P,)`` with ``h(lo)`` sign ``hlo``."""
    t = 0.5 * (lo + hi)
    tol = 1e-10 if t.dtype == torch.float64 else 1e-6
    for _ in range(iters):
        with torch.enable_grad():
            tg = t.detach().requires_grad_(True)
            h = _h(tg, o, d, params, kind)
            (dh,) = torch.autograd.grad(h.sum(), tg)
        h = h.detach()
        same = (h > 0) == (hlo > 0)
        lo = torch.where(same, t, lo)
        hi = torch.where(same, hi, t)
        step = t - h / torch.where(dh.abs() > 1e-30, dh, torch.full_like(dh, 1e-30))
        ok = torch.isfinite(step) & (step > lo) & (step < hi)
        t_new = torch.where(ok, step, 0.5 * (lo + hi))
        done = ((t_new - t).abs() <= tol * (1.0 + t.abs())) | (h.abs() <= tol * tol)
        t = t_new
        if bool(done.all()):
            break
    return t.detach()


def line_intersections(
    origins,
    directions,
    params,
    poses=None,
    kind: int = SUPERELLIPSOID,
    *,
    n_scan: int = 64,
    iters: int | None = None,
    t_min: float | None = None,
    first_only: bool = False,
) -> LineHits:
    """All roots ``t > t_min`` of ``f_D(T^{-1}(o + t d)) = 1`` (3.4.1), sorted ascending.

    ``origins, directions (..., L, 3)`` (world frame), ``params (..., 9)``, ``poses (..., 4, 4)``
    (object to world; ``None`` = identity); leading dims broadcast. Returns :class:`LineHits` with
    ``t, valid (..., L, K)``, ``K`` the largest root count found (1 with ``first_only``). ``t_min``
    defaults to ``1e-4`` times the bound radius (drops the root at a line's own start point).
    ``n_scan`` must resolve the thinnest part of the shape along the chord.
    """
    o = as_tensor(origins)
    d = as_tensor(directions, dtype=o.dtype)
    params = as_tensor(params, dtype=o.dtype)
    check_params(params)
    if o.ndim < 2 or o.shape[-1] != 3:
        raise ValueError(f"origins must have shape (..., L, 3), got {tuple(o.shape)}")
    if d.shape[-1] != 3 or d.ndim < 2:
        raise ValueError(f"directions must have shape (..., L, 3), got {tuple(d.shape)}")
    if poses is not None:
        poses = as_tensor(poses, dtype=o.dtype)
        if poses.shape[-2:] != (4, 4):
            raise ValueError(f"poses must have shape (..., 4, 4), got {tuple(poses.shape)}")
        inv = se3_inverse(poses)
        R, tr = inv[..., :3, :3].unsqueeze(-3), inv[..., :3, 3].unsqueeze(-2)
        o = (R @ o.unsqueeze(-1)).squeeze(-1) + tr
        d = (R @ d.unsqueeze(-1)).squeeze(-1)
    lead = torch.broadcast_shapes(o.shape[:-2], d.shape[:-2], params.shape[:-1])
    L = torch.broadcast_shapes(o.shape[-2:-1], d.shape[-2:-1])[0]
    o = o.expand(*lead, L, 3)
    d = d.expand(*lead, L, 3)
    params = params.expand(*lead, 9)
    if iters is None:
        iters = 30 if o.dtype == torch.float64 else 20
    if L == 0 or o.numel() == 0:
        empty = torch.zeros(*lead, L, 0, dtype=o.dtype)
        return LineHits(empty, empty.bool())

    t0, t1, hit = search_interval(o, d, params, kind)
    radius = bound_radius(params, kind).unsqueeze(-1).expand_as(t0)
    tmin = 1e-4 * radius if t_min is None else torch.full_like(t0, t_min)
    t0 = torch.maximum(t0, tmin)
    hit = hit & (t1 > t0)
    # flatten lines; only lines whose bound chord is non-empty are scanned
    P = o.reshape(-1, 3)
    D = d.reshape(-1, 3)
    prm = params.unsqueeze(-2).expand(*lead, L, 9).reshape(-1, 9)
    idx = hit.reshape(-1).nonzero().squeeze(-1)
    n_lines = P.shape[0]
    out_t = torch.zeros(n_lines, 0, dtype=o.dtype)
    if idx.numel() > 0:
        Ps, Ds, prs = P[idx], D[idx], prm[idx]
        a, b = t0.reshape(-1)[idx], t1.reshape(-1)[idx]
        s = torch.linspace(0, 1, n_scan, dtype=o.dtype)
        ts = a.unsqueeze(-1) + (b - a).unsqueeze(-1) * s  # (H, n)
        x = Ps.unsqueeze(-2) + ts.unsqueeze(-1) * Ds.unsqueeze(-2)
        h = implicit_homogeneous(x, prs, kind) - 1.0
        pos = h > 0
        cross = pos[:, 1:] != pos[:, :-1]  # (H, n - 1)
        if first_only:
            first = torch.cumsum(cross.int(), -1) == 1
            cross = cross & first
        line_i, seg_j = cross.nonzero(as_tuple=True)
        if line_i.numel() > 0:
            lo, hi = ts[line_i, seg_j], ts[line_i, seg_j + 1]
            root = _refine(
                lo, hi, h[line_i, seg_j], Ps[line_i], Ds[line_i], prs[line_i], kind, iters
            )
            counts = cross.sum(-1)
            k = int(counts.max())
            rank = torch.cumsum(cross.int(), -1)[line_i, seg_j] - 1  # roots come in t order
            out_t = torch.zeros(n_lines, k, dtype=o.dtype)
            valid = torch.zeros(n_lines, k, dtype=torch.bool)
            out_t[idx[line_i], rank] = root
            valid[idx[line_i], rank] = True
            return LineHits(out_t.reshape(*lead, L, k), valid.reshape(*lead, L, k))
    k = 1 if first_only else 0
    empty = torch.zeros(*lead, L, k, dtype=o.dtype)
    return LineHits(empty, empty.bool())


def world_line_intersections(
    origins,
    directions,
    params,
    poses,
    kinds=SUPERELLIPSOID,
    **kwargs,
) -> LineHits:
    """Roots for ``L`` lines against each of ``M`` posed shapes of mixed kinds: ``(M, L, K)``.

    ``origins, directions (L, 3)``, ``params (M, 9)``, ``poses (M, 4, 4)``, ``kinds`` an int or
    ``(M,)``. Keyword arguments go to :func:`line_intersections`.
    """
    params = as_tensor(params)
    poses = as_tensor(poses, dtype=params.dtype)
    o = as_tensor(origins, dtype=params.dtype)
    d = as_tensor(directions, dtype=params.dtype)
    M, L = params.shape[0], o.shape[0]
    kinds_t = torch.full((M,), int(kinds)) if isinstance(kinds, int) else torch.as_tensor(kinds)
    results = []
    for kind in torch.unique(kinds_t).tolist():
        sel = (kinds_t == kind).nonzero().squeeze(-1)
        hits = line_intersections(o, d, params[sel], poses[sel], int(kind), **kwargs)
        results.append((sel, hits))
    k = max([h.t.shape[-1] for _, h in results], default=0)
    t = torch.zeros(M, L, k, dtype=params.dtype)
    valid = torch.zeros(M, L, k, dtype=torch.bool)
    for sel, h in results:
        t[sel, :, : h.t.shape[-1]] = h.t
        valid[sel, :, : h.t.shape[-1]] = h.valid
    return LineHits(t, valid)


def first_hits(origins, directions, params, poses, kinds=SUPERELLIPSOID, **kwargs):
    """Nearest root over ``M`` shapes for each of ``L`` lines: ``t (L,)`` (inf on a miss), ``ids (L,)`` (-1)."""
    hits = world_line_intersections(
        origins, directions, params, poses, kinds, first_only=True, **kwargs
    )
    if hits.t.shape[0] == 0 or hits.t.shape[-1] == 0:  # no shapes: every line misses
        L = hits.t.shape[1]
        return (
            torch.full((L,), float("inf"), dtype=hits.t.dtype),
            torch.full((L,), -1, dtype=torch.long),
        )
    t = torch.where(hits.valid, hits.t, torch.full_like(hits.t, float("inf")))[..., 0]  # (M, L)
    best, ids = t.min(0)
    ids = torch.where(torch.isfinite(best), ids, torch.full_like(ids, -1))
    return best, ids


def farthest_intersection(hits: LineHits) -> tuple[torch.Tensor, torch.Tensor]:
    """The grasp planner's choice (3.4.1): largest valid ``t (..., L)`` and whether any exists."""
    t = torch.where(hits.valid, hits.t, torch.full_like(hits.t, -float("inf")))
    if t.shape[-1] == 0:
        shape = t.shape[:-1]
        return torch.zeros(shape, dtype=t.dtype), torch.zeros(shape, dtype=torch.bool)
    far = t.amax(-1)
    ok = hits.valid.any(-1)
    return torch.where(ok, far, torch.zeros_like(far)), ok
