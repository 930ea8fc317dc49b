"""Approximately uniform surface sampling of plain and deformed superquadrics (Ch. 2.2, 2.3, 3.4.1).

Uniform *angles* in the parametrisation (2.2.2) bunch points at the poles and, for box-like shapes,
on the edges. Here sampling is uniform in *area*, then thinned to even spacing:

1. the (deformed) surface is meshed from the closed-form domain of :mod:`.mesh` (cube surface for
   superellipsoids, polar/periodic grids for the others);
2. ``oversample * n`` candidates: a triangle drawn with probability proportional to its deformed
   area, a uniform barycentric point inside it *in the domain*, mapped exactly onto the surface
   (so ``f_D = 1`` holds to rounding, not to the chord error of the mesh);
3. farthest-point sampling (FPS) keeps ``n`` of them: equal spacing (blue noise) instead of the
   clumps of i.i.d. sampling.

``method="area"`` stops after step 2 (i.i.d. uniform in area, fast for large ``n``); ``"fps"`` always
thins; ``"auto"`` thins when ``n <= FPS_MAX``. Normals are :func:`superquadric.normal` (2.3.21).
Everything is deterministic given ``generator`` (a ``torch.Generator`` or an int seed).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
import torch

from .mesh import domain, domain_to_surface, mesh_vertices, surface_area, triangle_areas
from .numerics import as_tensor
from .superquadric import SUPERELLIPSOID, check_params, normal
from .types import Superquadric

FPS_MAX = 4096
"""``method="auto"`` uses farthest-point thinning up to this many points per shape."""

Method = Literal["auto", "area", "fps"]


def _generator(generator: torch.Generator | int | None) -> torch.Generator:
    if isinstance(generator, torch.Generator):
        return generator
    g = torch.Generator()
    g.manual_seed(0 if generator is None else int(generator))
    return g


def _resolution_for(n: int) -> int:
    # ~ at least as many triangles as candidates / 8, between 16 and 48 cells per cube edge
    return int(min(48, max(16, np.ceil(np.sqrt(max(n, 1) / 12.0)))))


def farthest_point_sampling(
    points: torch.Tensor, n: int, generator: torch.Generator | int | None = None
) -> torch.Tensor:
    """Indices ``(..., n)`` of ``n`` farthest-point-sampled rows of ``points (..., M, 3)``.

    Starts at a random point (from ``generator``), then repeatedly adds the point farthest from the
    ones chosen; the result has near-equal nearest-neighbour spacing. ``O(n M)`` per batch entry.
    """
    if points.ndim < 2 or points.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., M, 3), got {tuple(points.shape)}")
    m = points.shape[-2]
    if n > m:
        raise ValueError(f"n must be <= the number of points {m}, got {n}")
    lead = points.shape[:-2]
    flat = points.reshape(-1, m, 3)
    b = flat.shape[0]
    out = torch.zeros(b, n, dtype=torch.long, device=points.device)
    if n == 0 or b == 0:
        return out.reshape(*lead, n)
    g = _generator(generator)
    idx = torch.randint(m, (b,), generator=g).to(points.device)
    dist = torch.full((b, m), float("inf"), dtype=points.dtype, device=points.device)
    rows = torch.arange(b, device=points.device)
    for i in range(n):
        out[:, i] = idx
        d = ((flat - flat[rows, idx].unsqueeze(1)) ** 2).sum(-1)
        dist = torch.minimum(dist, d)
        idx = dist.argmax(-1)
    return out.reshape(*lead, n)


def sample_surface(
    params,
    n: int,
    *,
    kind: int = SUPERELLIPSOID,
    generator: torch.Generator | int | None = None,
    method: Method = "auto",
    oversample: int = 4,
) -> tuple[torch.Tensor, torch.Tensor] | tuple[np.ndarray, np.ndarray]:
    """``n`` approximately equally spaced points on (deformed) superquadrics, with outward normals.

    ``params (..., 9)`` (torch, or numpy / list: then numpy is returned) in the object frame.
    Returns ``points (..., n, 3)`` with ``f_D(points) = 1`` (to rounding) and unit outward
    ``normals (..., n, 3)`` (2.3.21), same dtype as ``params`` (float32 unless float64 given).
    """
    as_numpy = not isinstance(params, torch.Tensor)
    params = as_tensor(params)
    check_params(params)
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    if method not in ("auto", "area", "fps"):
        raise ValueError(f"method must be 'auto', 'area' or 'fps', got {method!r}")
    lead = params.shape[:-1]
    if n == 0 or params.numel() == 0:
        z = torch.zeros(*lead, n, 3, dtype=params.dtype, device=params.device)
        return (z.numpy(), z.clone().numpy()) if as_numpy else (z, z.clone())
    g = _generator(generator)
    thin = method == "fps" or (method == "auto" and n <= FPS_MAX)
    m = n * max(1, oversample) if thin else n
    flat = params.reshape(-1, params.shape[-1])
    b = flat.shape[0]

    res = _resolution_for(m)
    dom = domain(kind, res)
    faces = torch.as_tensor(dom.faces, device=params.device)
    areas = triangle_areas(mesh_vertices(flat, kind, res), faces)  # (B, F)
    probs = areas.clamp_min(0) + 1e-30
    tri = torch.multinomial(probs.float(), m, replacement=True, generator=g)  # (B, m)
    # uniform barycentric coordinates (reflection trick)
    r = torch.rand(b, m, 2, generator=g, dtype=params.dtype).to(params.device)
    flip = r.sum(-1, keepdim=True) > 1
    r = torch.where(flip, 1 - r, r)
    w = torch.cat([1 - r.sum(-1, keepdim=True), r], -1)  # (B, m, 3)
    corners = torch.as_tensor(dom.face_coords, dtype=params.dtype, device=params.device)[tri]
    coords = (w.unsqueeze(-1) * corners).sum(-2)  # (B, m, D)
    pts = domain_to_surface(coords, flat, kind)  # (B, m, 3)
    if thin:
        keep = farthest_point_sampling(pts, n, g)
        pts = torch.gather(pts, 1, keep.unsqueeze(-1).expand(-1, -1, 3))
    nrm = normal(pts, flat, kind)
    pts, nrm = pts.reshape(*lead, n, 3), nrm.reshape(*lead, n, 3)
    if as_numpy:
        return pts.numpy(), nrm.numpy()
    return pts, nrm


def sample_surface_angles(params, n_eta: int, n_omega: int, kind: int = SUPERELLIPSOID):
    """Points on a uniform grid of the *angles* of (2.2.2) (superellipsoids only).

    The naive sampler, kept for comparison: it bunches points at the poles and edges.
    Returns ``(..., n_eta * n_omega, 3)`` deformed object-frame points.
    """
    from .deform import deform
    from .superquadric import superellipsoid_surface, unpack

    if kind != SUPERELLIPSOID:
        raise ValueError(f"angle sampling is implemented for superellipsoids (kind 0), got {kind}")
    params = as_tensor(params)
    eta = torch.linspace(-np.pi / 2, np.pi / 2, n_eta, dtype=params.dtype)
    omega = torch.linspace(-np.pi, np.pi, n_omega + 1, dtype=params.dtype)[:-1]
    eta, omega = (t.reshape(-1) for t in torch.meshgrid(eta, omega, indexing="ij"))
    a1, a2, a3, e1, e2, k, b, alpha, _ = unpack(params)
    x = superellipsoid_surface(eta, omega, a1, a2, a3, e1, e2)
    return deform(x, k, a3, b, alpha)


def _allocate(weights: np.ndarray, n: int) -> np.ndarray:
    """Split ``n`` into integer counts proportional to ``weights`` (largest remainder)."""
    if weights.sum() <= 0:
        weights = np.ones_like(weights)
    share = weights / weights.sum() * n
    counts = np.floor(share).astype(np.int64)
    rest = n - counts.sum()
    if rest > 0:
        counts[np.argsort(-(share - counts), kind="stable")[:rest]] += 1
    return counts


def sample_parts(
    parts: Sequence[Superquadric],
    n: int,
    *,
    generator: torch.Generator | int | None = None,
    method: Method = "auto",
    dtype: torch.dtype = torch.float64,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` surface points over posed parts, split in proportion to their surface areas.

    Returns world-frame ``points (n, 3)``, unit outward ``normals (n, 3)`` and ``part_ids (n,)``
    (index into ``parts``), as numpy. Points of a part inside another part are kept (callers that
    need the visible union filter with :func:`world.occupied`).
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    if len(parts) == 0 or n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    g = _generator(generator)
    areas = np.array(
        [float(surface_area(torch.as_tensor(p.params(), dtype=dtype), p.kind_index)) for p in parts]
    )
    counts = _allocate(areas, n)
    pts, nrms, ids = [], [], []
    for i, (part, c) in enumerate(zip(parts, counts, strict=True)):
        if c == 0:
            continue
        p, nr = sample_surface(
            torch.as_tensor(part.params(), dtype=dtype),
            int(c),
            kind=part.kind_index,
            generator=g,
            method=method,
        )
        R, t = (
            torch.as_tensor(part.pose[:3, :3], dtype=dtype),
            torch.as_tensor(part.pose[:3, 3], dtype=dtype),
        )
        pts.append((p @ R.T + t).numpy())
        nrms.append((nr @ R.T).numpy())
        ids.append(np.full(int(c), i, dtype=np.int64))
    return np.concatenate(pts), np.concatenate(nrms), np.concatenate(ids)
