"""Synthetic single-view tabletop scenes for tests and benchmarks (Appendix A.1, B.2).

Objects are the primitive types of Table A.1 written as (deformable) superquadrics:

- box ``B``: ``size = (w, d, h) / 2``, ``shape = (0.2, 0.2)`` (the most box-like allowed);
- ellipsoid ``E``: ``shape = (1, 1)``;
- cylinder ``CY``: ``shape = (0.2, 1)``;
- cone ``C``: a cylinder tapered with ``k = -1`` (2.3.12): radius ``r`` at the bottom, 0 at the top;
- truncated cone ``TC``: bottom radius ``R``, top radius ``r``: ``a1 = a2 = (R + r) / 2``,
  ``k = (r - R) / (R + r)``.

They rest on the table plane ``z = 0`` (upright, or a cylinder lying on its side), do not overlap,
and are seen by one pinhole camera (:class:`sqmanip.geometry.PinholeCamera`) looking down at 40-60
degrees. Points are the exact first hits of the pixel rays (:func:`sqmanip.geometry.raycast_depth`), i.e. only
the visible surfaces, including the table (a thin flat box whose top face is ``z = 0``), with the
noise of A.1: ``x -> x + m v``, ``m ~ N(0, sigma)``, ``v`` uniform on ``S^2``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
import torch

from sqmanip.geometry import PinholeCamera, Superquadric, pack, raycast_depth

KINDS_ALL = ("box", "ellipsoid", "cylinder", "cone", "truncated_cone")
TABLE_HALF = 0.4
"""Half side of the square table (m)."""
TABLE_THICK = 0.02


@dataclasses.dataclass(frozen=True)
class SyntheticScene:
    points: np.ndarray
    """(N, 3) float32 world-frame visible points (table included)."""
    object_ids: np.ndarray
    """(N,) int64, index into ``objects``; -1 for table points."""
    objects: list[list[Superquadric]]
    """Ground-truth parts of each object."""
    viewpoint: np.ndarray
    """(3,) camera origin in the world frame."""
    camera: PinholeCamera
    kinds: tuple[str, ...] = ()
    """Primitive type of each object."""


def _pose(yaw: float, position: Sequence[float], lying: bool = False) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    R = Rz
    if lying:  # object z axis along world x before the yaw: rotate +90 deg about y
        Ry = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
        R = Rz @ Ry
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = position
    return T


def sample_primitive(
    kind: str, rng: np.random.Generator, allow_lying: bool = True
) -> tuple[Superquadric, float]:
    """A random primitive of ``kind`` (ranges of Table A.1) at the origin, upright.

    Returns the part (pose = identity except its height above the table) and its footprint
    radius (m) for placement. Ranges are Table A.1's, with the smallest boxes at 3 cm instead of
    2 cm (a 2 cm-thin slab seen from 50 degrees is nearly a single plane, which A.1 excludes).
    """
    lying = False
    if kind == "box":
        w, d, h = rng.uniform(0.03, 0.3, 3)
        sq = Superquadric((w / 2, d / 2, h / 2), (0.2, 0.2))
    elif kind == "ellipsoid":
        a, b, c = rng.uniform(0.03, 0.07, 3)
        sq = Superquadric((a, b, c), (1.0, 1.0))
    elif kind == "cylinder":
        r, h = rng.uniform(0.01, 0.075), rng.uniform(0.03, 0.3)
        r = max(r, 0.015)
        sq = Superquadric((r, r, h / 2), (0.2, 1.0))
        lying = allow_lying and h > 2.5 * r and rng.uniform() < 0.3
    elif kind == "cone":
        r, h = rng.uniform(0.02, 0.07), rng.uniform(0.03, 0.15)
        sq = Superquadric((r, r, h / 2), (0.2, 1.0), taper=-1.0)
    elif kind in ("truncated_cone", "tc"):
        R = rng.uniform(0.03, 0.1)
        r = rng.uniform(0.02, 0.8 * R)
        h = rng.uniform(0.02, 0.3)
        h = max(h, 0.03)
        sq = Superquadric(((R + r) / 2, (R + r) / 2, h / 2), (0.2, 1.0), taper=(r - R) / (R + r))
    else:
        raise ValueError(f"kind must be one of {KINDS_ALL}, got {kind!r}")
    a1, a2, a3 = sq.size
    scale = 1.0 + abs(sq.taper)
    if lying:
        footprint = math.hypot(a3, a1)
        height = a1
    else:
        footprint = math.hypot(a1, a2) * scale
        height = a3
    pose = _pose(0.0, (0.0, 0.0, height), lying)
    return sq.with_pose(pose), footprint


def _table() -> Superquadric:
    pose = np.eye(4)
    pose[2, 3] = -TABLE_THICK / 2
    return Superquadric((TABLE_HALF, TABLE_HALF, TABLE_THICK / 2), (0.2, 0.2), pose=pose)


def _camera(
    rng: np.random.Generator, target: np.ndarray, distance: float, scale: float
) -> PinholeCamera:
    elev = math.radians(rng.uniform(40.0, 60.0))
    azim = rng.uniform(-math.pi, math.pi)
    d = np.array([math.cos(elev) * math.cos(azim), math.cos(elev) * math.sin(azim), math.sin(elev)])
    eye = target + distance * d
    return PinholeCamera.look_at(eye, target).scaled(scale)


def _noise(points: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """A.1: ``x + m v`` with ``m ~ N(0, sigma)`` and ``v`` uniform on the unit sphere."""
    if sigma <= 0:
        return points
    v = rng.normal(size=points.shape)
    v /= np.linalg.norm(v, axis=1, keepdims=True).clip(1e-12)
    m = rng.normal(0.0, sigma, size=(len(points), 1))
    return points + m * v


def _object_window(objects: Sequence[Superquadric], camera: PinholeCamera) -> PinholeCamera | None:
    """The camera cropped to the pixels where ``objects`` can appear (None if none can).

    Rendering only that window casts the same rays as the full image there, at a fraction of
    the cost: the corners of each part's bounding box (grown by the taper) are projected.
    """
    inv = np.linalg.inv(camera.pose)
    us, vs = [], []
    for sq in objects:
        a = np.array(sq.size) * np.array([1 + abs(sq.taper), 1 + abs(sq.taper), 1.0]) * 1.05
        corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T * a
        w = corners @ sq.pose[:3, :3].T + sq.pose[:3, 3]
        c = w @ inv[:3, :3].T + inv[:3, 3]
        if (c[:, 2] <= 1e-3).any():
            return camera
        us.append(camera.fx * c[:, 0] / c[:, 2] + camera.cx)
        vs.append(camera.fy * c[:, 1] / c[:, 2] + camera.cy)
    u, v = np.concatenate(us), np.concatenate(vs)
    u0, u1 = max(0, int(np.floor(u.min())) - 1), min(camera.width, int(np.ceil(u.max())) + 2)
    v0, v1 = max(0, int(np.floor(v.min())) - 1), min(camera.height, int(np.ceil(v.max())) + 2)
    if u1 <= u0 or v1 <= v0:
        return None
    return dataclasses.replace(
        camera, cx=camera.cx - u0, cy=camera.cy - v0, width=u1 - u0, height=v1 - v0
    )


def _table_hits(camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """Ray distances ``(H, W)`` to the table top ``z = 0`` (inf off the table) and the rays."""
    origin, dirs = camera.rays(torch.float64)
    o, d = origin.numpy(), dirs.numpy()
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / d[..., 2]
    hit = o + np.nan_to_num(t, nan=0.0, posinf=0.0, neginf=0.0)[..., None] * d
    ok = (t > 0) & (np.abs(hit[..., 0]) <= TABLE_HALF) & (np.abs(hit[..., 1]) <= TABLE_HALF)
    return np.where(ok, t, np.inf), d


def _render(
    objects: list[Superquadric],
    camera: PinholeCamera,
    rng: np.random.Generator,
    noise: float,
    n_points: int | None,
    include_table: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Visible points and ids (-1 = table): exact object hits in the objects' image window
    (:func:`raycast_depth`), the table top intersected analytically where no object is nearer."""
    depth = np.full((camera.height, camera.width), np.inf)
    ids = np.full((camera.height, camera.width), -1, dtype=np.int64)
    window = _object_window(objects, camera) if objects else None
    if window is not None:
        t = pack(objects, dtype=torch.float32)
        d_obj, i_obj = raycast_depth(t.params, t.poses, window, t.kinds)
        v0 = round(camera.cy - window.cy)
        u0 = round(camera.cx - window.cx)
        depth[v0 : v0 + window.height, u0 : u0 + window.width] = d_obj.numpy()
        ids[v0 : v0 + window.height, u0 : u0 + window.width] = i_obj.numpy()
    if include_table:
        t_table, _ = _table_hits(camera)
        table = t_table < depth
        depth = np.where(table, t_table, depth)
        ids = np.where(table, -1, ids)
    rows, cols = np.nonzero(np.isfinite(depth))
    origin, dirs = camera.rays(torch.float64)
    pts = origin.numpy() + depth[rows, cols, None] * dirs.numpy()[rows, cols]
    out_ids = ids[rows, cols]
    if n_points is not None and len(pts) > n_points:
        keep = np.sort(rng.choice(len(pts), n_points, replace=False))
        pts, out_ids = pts[keep], out_ids[keep]
    pts = _noise(pts, noise, rng)
    return pts.astype(np.float32), out_ids


def make_tabletop_scene(
    n_objects: int,
    seed: int,
    kinds: Sequence[str] = ("box", "cylinder", "ellipsoid", "cone"),
    noise: float = 0.001,
    *,
    n_points: int | None = None,
    camera_scale: float = 0.5,
    distance: float = 0.9,
    spacing: float = 0.03,
) -> SyntheticScene:
    """``n_objects`` primitives (cycling through ``kinds``) on a table, seen from one camera.

    Objects get random sizes (Table A.1), yaws and positions within 0.25 m of the table centre,
    at least ``spacing`` apart (footprint circles). ``n_points`` randomly subsamples the
    rendered cloud (e.g. 40,000 for the latency benchmark). Deterministic for ``seed``.
    """
    if n_objects < 0:
        raise ValueError(f"n_objects must be >= 0, got {n_objects}")
    rng = np.random.default_rng(seed)
    placed: list[tuple[np.ndarray, float]] = []
    objects: list[list[Superquadric]] = []
    names: list[str] = []
    for i in range(n_objects):
        kind = kinds[i % len(kinds)]
        for _ in range(200):
            sq, radius = sample_primitive(kind, rng)
            radius = min(radius, 0.16)
            if radius > 0.16:
                continue
            xy = rng.uniform(-0.22, 0.22, 2)
            if all(np.linalg.norm(xy - c) > radius + r + spacing for c, r in placed):
                break
        else:
            raise ValueError(f"could not place {n_objects} objects without overlap (seed {seed})")
        lying = abs(sq.pose[2, 2]) < 0.5
        pose = _pose(rng.uniform(-math.pi, math.pi), (xy[0], xy[1], sq.pose[2, 3]), lying)
        objects.append([sq.with_pose(pose)])
        names.append(kind)
        placed.append((xy, radius))
    camera = _camera(rng, np.array([0.0, 0.0, 0.03]), distance, camera_scale)
    pts, ids = _render([o[0] for o in objects], camera, rng, noise, n_points, True)
    return SyntheticScene(pts, ids, objects, camera.pose[:3, 3].copy(), camera, tuple(names))


def make_single_view(
    kind: str,
    seed: int,
    noise: float = 0.001,
    *,
    include_table: bool = True,
    camera_scale: float = 0.5,
    distance: float = 0.7,
    allow_lying: bool = True,
) -> SyntheticScene:
    """One primitive of ``kind`` (box, ellipsoid, cylinder, cone, truncated_cone) on the table.

    The camera looks at the object's centre from ``distance`` at 40-60 degrees elevation; the
    cloud holds the object's visible surface and (``include_table``) the table around it.
    """
    rng = np.random.default_rng(seed)
    sq, _ = sample_primitive(kind, rng, allow_lying=allow_lying)
    lying = abs(sq.pose[2, 2]) < 0.5
    xy = rng.uniform(-0.05, 0.05, 2)
    pose = _pose(rng.uniform(-math.pi, math.pi), (xy[0], xy[1], sq.pose[2, 3]), lying)
    sq = sq.with_pose(pose)
    camera = _camera(rng, pose[:3, 3].copy(), distance, camera_scale)
    pts, ids = _render([sq], camera, rng, noise, None, include_table)
    return SyntheticScene(pts, ids, [[sq]], camera.pose[:3, 3].copy(), camera, (kind,))
