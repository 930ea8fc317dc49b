"""Watertight triangle meshes of plain and deformed superquadrics (Ch. 2.2, 2.3).

Why not the angle parametrisation (2.2.2)? ``cos^e`` with ``e = 0.2`` squeezes a whole flat face
into a few degrees of ``eta``, and its poles give degenerate triangles. Instead every kind is
meshed from a *domain* whose points are mapped onto the exact surface in closed form:

- superellipsoid: the surface of the cube ``[-1, 1]^3`` (``R`` cells per edge, vertices on shared
  edges merged) mapped by the radial projection ``q -> q f(q)^{-e1/2}`` (``f`` is homogeneous of
  degree ``2 / e1``), then scaled by ``(a1, a2, a3)``: no poles, no degenerate triangles, and for
  box-like shapes the projection is nearly the identity, so cells stay evenly sized;
- superparaboloid (2.2.8): a polar grid (rings over the radial level ``u`` in [0, 1], angles from
  the square perimeter projected radially onto the superellipse) for the wall and for the cap
  ``z = 0``, sharing the rim ring and closed by one vertex at each pole (a fan, not a degenerate
  quad);
- supertoroid (2.2.10): a periodic grid over two square perimeters (tube and ring), each projected
  radially onto its superellipse: torus topology.

The canonical surface point is then deformed by ``D = D_b o D_t`` (2.3.22). All maps preserve
orientation, so the fixed winding of each topology gives outward normals for every shape.

Vertices are exact surface points (``f_D = 1`` up to rounding); so are points interpolated in the
domain and mapped (used by :mod:`.sampling`).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import numpy as np
import torch
import trimesh

from .deform import deform
from .numerics import abs_pow, as_tensor, clamp_shape
from .superquadric import (
    KINDS,
    SUPERELLIPSOID,
    SUPERPARABOLOID,
    SUPERTOROID,
    check_params,
)
from .types import Superquadric

DEFAULT_RESOLUTION = 24


# --- domains ---------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Domain:
    """Topology of one kind at one resolution.

    ``vertices (V, D)`` are domain coordinates of the mesh vertices, ``faces (F, 3)`` index them,
    and ``face_coords (F, 3, D)`` are the (unwrapped) domain coordinates of each face's corners, so
    that convex combinations inside a face stay inside it (periodic seams are unwrapped).
    """

    kind: int
    vertices: np.ndarray
    faces: np.ndarray
    face_coords: np.ndarray


def _cube_domain(res: int) -> Domain:
    n = res + 1
    index = -np.ones((n, n, n), dtype=np.int64)
    grid = np.stack(np.meshgrid(*(np.arange(n),) * 3, indexing="ij"), -1).reshape(-1, 3)
    on_surface = ((grid == 0) | (grid == res)).any(-1)
    lattice = grid[on_surface]
    index[tuple(lattice.T)] = np.arange(len(lattice))
    faces = []
    a, b = np.meshgrid(np.arange(res), np.arange(res), indexing="ij")
    a, b = a.ravel(), b.ravel()
    for axis in range(3):
        # (u, v) chosen so that e_u x e_v = +e_axis; swapped on the negative face.
        u, v = (axis + 1) % 3, (axis + 2) % 3
        for side, (uu, vv) in ((res, (u, v)), (0, (v, u))):
            corners = []
            for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                ijk = np.empty((len(a), 3), dtype=np.int64)
                ijk[:, axis] = side
                ijk[:, uu] = a + du
                ijk[:, vv] = b + dv
                corners.append(index[tuple(ijk.T)])
            p00, p10, p11, p01 = corners
            faces.append(np.stack([p00, p10, p11], -1))
            faces.append(np.stack([p00, p11, p01], -1))
    faces = np.concatenate(faces)
    verts = 2.0 * lattice / res - 1.0
    return Domain(SUPERELLIPSOID, verts, faces, verts[faces])


def _perimeter_count(res: int) -> int:
    return 8 * max(1, res // 2)


def _torus_domain(res: int) -> Domain:
    p = _perimeter_count(res)
    s = 8.0 * np.arange(p) / p
    i, j = np.meshgrid(np.arange(p), np.arange(p), indexing="ij")
    i, j = i.ravel(), j.ravel()
    vid = lambda ii, jj: (ii % p) * p + (jj % p)  # noqa: E731
    q00, q10, q11, q01 = vid(i, j), vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1)
    faces = np.concatenate([np.stack([q00, q11, q10], -1), np.stack([q00, q01, q11], -1)])
    # unwrapped corner coordinates
    ci = np.concatenate([np.stack([i, i + 1, i + 1], -1), np.stack([i, i, i + 1], -1)])
    cj = np.concatenate([np.stack([j, j + 1, j], -1), np.stack([j, j + 1, j + 1], -1)])
    face_coords = np.stack([8.0 * ci / p, 8.0 * cj / p], -1)
    verts = np.stack(np.meshgrid(s, s, indexing="ij"), -1).reshape(-1, 2)
    return Domain(SUPERTOROID, verts, faces, face_coords)


def _paraboloid_domain(res: int) -> Domain:
    p = _perimeter_count(res)
    levels = max(2, res)
    u = np.arange(1, levels + 1) / levels  # rings 1..levels, u = 1 is the shared rim
    # vertices: [wall pole, cap pole, wall rings (levels), cap rings (levels - 1; rim shared)]
    verts = [np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])]
    s = 8.0 * np.arange(p) / p
    for uk in u:
        verts.append(np.stack([s, np.full(p, uk), np.zeros(p)], -1))
    for uk in u[:-1]:
        verts.append(np.stack([s, np.full(p, uk), np.ones(p)], -1))
    verts = np.concatenate(verts)

    def ring_id(level: int, cap: bool, j: np.ndarray) -> np.ndarray:
        # level in 1..levels; the rim (level == levels) is the wall ring for both surfaces
        if cap and level < levels:
            return 2 + levels * p + (level - 1) * p + (j % p)
        return 2 + (level - 1) * p + (j % p)

    faces, coords = [], []
    j = np.arange(p)
    for cap in (False, True):
        pole = 1 if cap else 0
        flag = 1.0 if cap else 0.0
        # The wall is seen from below (outward = -z at the pole), the cap from above.
        fan = np.stack([np.full(p, pole), ring_id(1, cap, j + 1), ring_id(1, cap, j)], -1)
        fan_c = np.stack(
            [
                np.stack([(j + 0.5) * 8.0 / p, np.zeros(p), np.full(p, flag)], -1),
                np.stack([(j + 1) * 8.0 / p, np.full(p, u[0]), np.full(p, flag)], -1),
                np.stack([j * 8.0 / p, np.full(p, u[0]), np.full(p, flag)], -1),
            ],
            1,
        )
        if cap:
            fan = fan[:, [0, 2, 1]]
            fan_c = fan_c[:, [0, 2, 1]]
        faces.append(fan)
        coords.append(fan_c)
        for lv in range(1, levels):
            a0, a1 = ring_id(lv, cap, j), ring_id(lv, cap, j + 1)
            b0, b1 = ring_id(lv + 1, cap, j), ring_id(lv + 1, cap, j + 1)
            s0, s1 = j * 8.0 / p, (j + 1) * 8.0 / p
            ua, ub = np.full(p, u[lv - 1]), np.full(p, u[lv])
            fl = np.full(p, flag)
            tri1 = np.stack([a0, a1, b1], -1)
            tri2 = np.stack([a0, b1, b0], -1)
            c1 = np.stack(
                [
                    np.stack([s0, ua, fl], -1),
                    np.stack([s1, ua, fl], -1),
                    np.stack([s1, ub, fl], -1),
                ],
                1,
            )
            c2 = np.stack(
                [
                    np.stack([s0, ua, fl], -1),
                    np.stack([s1, ub, fl], -1),
                    np.stack([s0, ub, fl], -1),
                ],
                1,
            )
            if cap:
                tri1, tri2 = tri1[:, [0, 2, 1]], tri2[:, [0, 2, 1]]
                c1, c2 = c1[:, [0, 2, 1]], c2[:, [0, 2, 1]]
            faces += [tri1, tri2]
            coords += [c1, c2]
    return Domain(SUPERPARABOLOID, verts, np.concatenate(faces), np.concatenate(coords))


@functools.lru_cache(maxsize=64)
def domain(kind: int, resolution: int = DEFAULT_RESOLUTION) -> Domain:
    """Cached mesh topology and domain coordinates for ``kind`` at ``resolution`` (cells per edge)."""
    if kind not in range(len(KINDS)):
        raise ValueError(f"kind must be one of {list(range(len(KINDS)))}, got {kind!r}")
    if resolution < 2:
        raise ValueError(f"resolution must be >= 2, got {resolution}")
    if kind == SUPERELLIPSOID:
        return _cube_domain(resolution)
    if kind == SUPERTOROID:
        return _torus_domain(resolution)
    return _paraboloid_domain(resolution)


# --- domain -> surface -------------------------------------------------------------------------------


def _square(s: torch.Tensor) -> torch.Tensor:
    """Point on the boundary of ``[-1, 1]^2`` at perimeter parameter ``s`` (period 8, CCW from (1, 0))."""
    s = torch.remainder(s, 8.0)
    one = torch.ones_like(s)
    x = torch.where(
        s < 1,
        one,
        torch.where(s < 3, 2 - s, torch.where(s < 5, -one, torch.where(s < 7, s - 6, one))),
    )
    y = torch.where(
        s < 1,
        s,
        torch.where(s < 3, one, torch.where(s < 5, 4 - s, torch.where(s < 7, -one, s - 8))),
    )
    return torch.stack([x, y], -1)


def _project_superellipse(v: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
    """Radially project ``v (..., 2)`` onto ``|x|^{2/e} + |y|^{2/e} = 1``."""
    m = v.abs().amax(-1, keepdim=True).clamp_min(1e-30)
    u = v / m
    n = (abs_pow(u[..., 0:1], 2 / e) + abs_pow(u[..., 1:2], 2 / e)).pow(e / 2)
    return u / n


def domain_to_surface(coords: torch.Tensor, params: torch.Tensor, kind: int) -> torch.Tensor:
    """Map domain coordinates ``(..., N, D)`` to object-frame surface points ``(..., N, 3)``.

    ``params (..., 9)`` broadcast against the leading dims; the canonical point is deformed by
    ``D = D_b o D_t`` (2.3.22), so ``implicit(result, params, kind) == 1`` up to rounding.
    """
    check_params(params)
    p = params.unsqueeze(-2)  # (..., 1, 9)
    a1, a2, a3 = p[..., 0:1], p[..., 1:2], p[..., 2:3]
    e1, e2 = clamp_shape(p[..., 3:4]), clamp_shape(p[..., 4:5])
    k, b, alpha, a4 = p[..., 5], p[..., 6], p[..., 7], p[..., 8]
    if kind == SUPERELLIPSOID:
        q = coords / coords.abs().amax(-1, keepdim=True).clamp_min(1e-30)  # on the cube
        inner = abs_pow(q[..., 0:1], 2 / e2) + abs_pow(q[..., 1:2], 2 / e2)
        f = inner.pow(e2 / e1) + abs_pow(q[..., 2:3], 2 / e1)  # in [1, 2^{e2/e1} + 1]
        x = q / f.pow(e1 / 2)
        canon = torch.cat([a1 * x[..., 0:1], a2 * x[..., 1:2], a3 * x[..., 2:3]], -1)
    elif kind == SUPERTOROID:
        tube = _project_superellipse(_square(coords[..., 0]), e1)
        ring = _project_superellipse(_square(coords[..., 1]), e2)
        rad = a4.unsqueeze(-1) + tube[..., 0:1]
        canon = torch.cat(
            [a1 * rad * ring[..., 0:1], a2 * rad * ring[..., 1:2], a3 * tube[..., 1:2]], -1
        )
    elif kind == SUPERPARABOLOID:
        ring = _project_superellipse(_square(coords[..., 0]), e2)
        u = coords[..., 1:2].clamp(0.0, 1.0)
        cap = coords[..., 2:3]
        wall_z = a3 * (abs_pow(u, 2 / e1) - 1.0)
        z = torch.where(cap > 0.5, torch.zeros_like(wall_z), wall_z)
        canon = torch.cat([a1 * u * ring[..., 0:1], a2 * u * ring[..., 1:2], z], -1)
    else:
        raise ValueError(f"kind must be one of {list(range(len(KINDS)))}, got {kind!r}")
    return deform(canon, k, p[..., 2], b, alpha)


def mesh_vertices(params: torch.Tensor, kind: int, resolution: int) -> torch.Tensor:
    """Object-frame vertices ``(..., V, 3)`` of :func:`domain` ``(kind, resolution)``."""
    dom = domain(kind, resolution)
    coords = torch.as_tensor(dom.vertices, dtype=params.dtype, device=params.device)
    return domain_to_surface(coords, params, kind)


def triangle_areas(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Areas ``(..., F)`` of triangles ``faces (F, 3)`` over ``vertices (..., V, 3)``."""
    tri = vertices[..., faces, :]
    cross = torch.linalg.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :])
    return 0.5 * torch.linalg.vector_norm(cross, dim=-1)


def surface_area(params, kind: int = SUPERELLIPSOID, resolution: int = 32) -> torch.Tensor:
    """Surface area ``(...)`` of (deformed) superquadrics from their meshes (slightly low: chords)."""
    params = as_tensor(params)
    dom = domain(kind, resolution)
    faces = torch.as_tensor(dom.faces, device=params.device)
    return triangle_areas(mesh_vertices(params, kind, resolution), faces).sum(-1)


# --- public meshes --------------------------------------------------------------------------------


def superquadric_mesh(
    params, kind: int = SUPERELLIPSOID, resolution: int = DEFAULT_RESOLUTION
) -> tuple[np.ndarray, np.ndarray]:
    """Watertight, outward-oriented mesh of one (deformed) superquadric in its object frame.

    ``params (9,)`` (array-like); ``resolution`` is the number of cells along a cube edge
    (superellipsoid) or the ring/level count (others). Returns ``vertices (V, 3)`` float64 and
    ``faces (F, 3)`` int64. A superellipsoid has ``6 R^2 + 2`` vertices and ``12 R^2`` faces.
    """
    params = as_tensor(params, dtype=torch.float64)
    if params.shape != (9,):
        raise ValueError(f"params must have shape (9,), got {tuple(params.shape)}")
    verts = mesh_vertices(params, kind, resolution)
    return verts.numpy(), domain(kind, resolution).faces.copy()


def superquadric_trimesh(sq: Superquadric, resolution: int = DEFAULT_RESOLUTION) -> trimesh.Trimesh:
    """World-frame ``trimesh.Trimesh`` of a posed :class:`Superquadric` (watertight)."""
    verts, faces = superquadric_mesh(sq.params(), sq.kind_index, resolution)
    verts = verts @ sq.pose[:3, :3].T + sq.pose[:3, 3]
    return trimesh.Trimesh(verts, faces, process=False)


def union_mesh(
    parts: Sequence[Superquadric], resolution: int = DEFAULT_RESOLUTION
) -> trimesh.Trimesh:
    """Concatenate the meshes of posed parts (world frame) for the viewer and the simulator.

    Not a boolean union: overlapping parts keep their inner surfaces; each component is watertight.
    An empty ``parts`` gives an empty mesh.
    """
    if len(parts) == 0:
        return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), process=False)
    meshes = [superquadric_trimesh(p, resolution) for p in parts]
    verts, faces, offset = [], [], 0
    for m in meshes:
        verts.append(m.vertices)
        faces.append(m.faces + offset)
        offset += len(m.vertices)
    return trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False)
