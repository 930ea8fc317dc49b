"""The open parallel gripper as a point cloud on its surfaces, for implicit-function collision checks.

B.5 and C.3 check a grasp pose ``T_gr`` by sampling ``n_gr`` points on the gripper mesh in its
maximum-open state and evaluating every obstacle's implicit function at ``T_gr x_gr,j`` (3.7.15,
B.5.12). Here the gripper is the boxes of :class:`GripperSpec` (two fingers, the palm) and, when
asked, a cylinder for links 7 and 6 above the flange (C.3). Points lie on an even grid on each
surface (deterministic; spacing chosen so the total is about ``n_points``).

The C.3 "afterimage" of the gripper approaching ``d`` metres along its ``z`` axis is the union of
the gripper moved back by ``s in [0, d]``: every box / the cylinder simply lengthens by ``d``
towards ``-z`` (the fingers' sweep lies inside the palm's, so only the palm and wrist grow).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch

from sqmanip.errors import ValidationError

from .types import GripperSpec

Box = tuple[np.ndarray, np.ndarray]
"""``(lo, hi)`` corners of an axis-aligned box in the gripper frame, each (3,)."""


def gripper_boxes(
    spec: GripperSpec,
    opening: float | None = None,
    approach_distance: float = 0.0,
    margin: float = 0.0,
) -> list[Box]:
    """Axis-aligned boxes of the open gripper in its own frame: left finger, right finger, palm.

    ``opening`` is the distance between the finger pads (default ``spec.max_opening``);
    ``margin`` inflates every box by that much on every side but the finger pads (a safety
    margin for shape error: the finger backs, sides and tips and the hand grow by ``margin``).
    """
    w = spec.max_opening if opening is None else float(opening)
    if not (0.0 <= w <= spec.max_opening):
        raise ValidationError(f"opening must be in [0, {spec.max_opening}], got {opening!r}")
    if not (math.isfinite(margin) and margin >= 0):
        raise ValidationError(f"margin must be finite and >= 0, got {margin!r}")
    fx, ft = spec.finger_width / 2, spec.finger_thickness
    z0, z1 = spec.palm_bottom, spec.tip_offset
    left = (np.array([-fx, w / 2, z0]), np.array([fx, w / 2 + ft, z1]))
    right = (np.array([-fx, -w / 2 - ft, z0]), np.array([fx, -w / 2, z1]))
    px, py, pz = spec.palm_size
    palm = (
        np.array([-px / 2, -py / 2, z0 - pz - approach_distance]),
        np.array([px / 2, py / 2, z0]),
    )
    out = [(lo - margin, hi + margin) for lo, hi in (left, right, palm)]
    # the pads keep their place: inflating them inwards would reject every grasp within
    # ``2 margin`` of the stroke, while recognition tends to *over*-estimate widths (amodal
    # completion of the hidden side), and the pads only ever meet the target at the contacts
    out[0][0][1], out[1][1][1] = w / 2, -w / 2
    return out


def _box_area(lo: np.ndarray, hi: np.ndarray) -> float:
    d = hi - lo
    return float(2 * (d[0] * d[1] + d[1] * d[2] + d[0] * d[2]))


def _grid(lo: float, hi: float, h: float) -> np.ndarray:
    """Cell centres of an even grid covering ``[lo, hi]`` with spacing about ``h``."""
    n = max(1, math.ceil((hi - lo) / h - 1e-9))
    return lo + (np.arange(n) + 0.5) * (hi - lo) / n


def box_surface_points(lo: np.ndarray, hi: np.ndarray, spacing: float) -> np.ndarray:
    """Points on the six faces of the box ``[lo, hi]``, about ``spacing`` apart, ``(P, 3)``.

    Grids include the face borders' neighbourhood (cell centres), plus the 8 corners and the
    12 edges (sampled with the same spacing) so thin obstacles at an edge are not missed.
    """
    out = []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        gu, gv = _grid(lo[u], hi[u], spacing), _grid(lo[v], hi[v], spacing)
        uu, vv = np.meshgrid(gu, gv, indexing="ij")
        for side in (lo[axis], hi[axis]):
            p = np.empty((uu.size, 3))
            p[:, axis], p[:, u], p[:, v] = side, uu.ravel(), vv.ravel()
            out.append(p)
    # edges: along each axis, at the four (lo/hi, lo/hi) combinations of the other two
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        n = max(2, math.ceil((hi[axis] - lo[axis]) / spacing) + 1)
        g = np.linspace(lo[axis], hi[axis], n)
        for cu in (lo[u], hi[u]):
            for cv in (lo[v], hi[v]):
                p = np.empty((n, 3))
                p[:, axis], p[:, u], p[:, v] = g, cu, cv
                out.append(p)
    return np.concatenate(out)


def cylinder_surface_points(radius: float, z0: float, z1: float, spacing: float) -> np.ndarray:
    """Points on a ``z``-axis cylinder of ``radius`` from ``z0`` to ``z1`` (side and both caps)."""
    n_theta = max(8, math.ceil(2 * math.pi * radius / spacing))
    theta = 2 * math.pi * np.arange(n_theta) / n_theta
    zs = np.linspace(z0, z1, max(2, math.ceil((z1 - z0) / spacing) + 1))
    tt, zz = np.meshgrid(theta, zs, indexing="ij")
    side = np.stack([radius * np.cos(tt).ravel(), radius * np.sin(tt).ravel(), zz.ravel()], -1)
    caps = []
    for r in np.arange(spacing, radius, spacing):
        n = max(6, math.ceil(2 * math.pi * r / spacing))
        th = 2 * math.pi * np.arange(n) / n
        ring = np.stack([r * np.cos(th), r * np.sin(th)], -1)
        for z in (z0, z1):
            caps.append(np.concatenate([ring, np.full((n, 1), z)], -1))
    caps.append(np.array([[0.0, 0.0, z0], [0.0, 0.0, z1]]))
    return np.concatenate([side, *caps])


@lru_cache(maxsize=64)
def _gripper_points_cached(
    spec: GripperSpec,
    n_points: int,
    include_wrist: bool,
    approach_distance: float,
    opening: float | None,
    margin: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    boxes = gripper_boxes(spec, opening, approach_distance, margin)
    area = sum(_box_area(lo, hi) for lo, hi in boxes)
    flange = -spec.flange_offset - approach_distance
    wrist = None
    if include_wrist and spec.wrist_length > 0:
        r = spec.wrist_radius
        z0 = flange - spec.wrist_length
        wrist = (r, z0, flange)
        area += 2 * math.pi * r * (flange - z0) + 2 * math.pi * r * r

    def build(spacing: float) -> tuple[np.ndarray, np.ndarray]:
        parts = [box_surface_points(lo, hi, spacing) for lo, hi in boxes]
        if wrist is not None:
            parts.append(cylinder_surface_points(*wrist, spacing))
        sides = [
            np.full(len(q), s, dtype=np.int8)
            for q, s in zip(parts, (1, -1, 0, 0)[: len(parts)], strict=True)
        ]
        return np.concatenate(parts), np.concatenate(sides)

    # faces + edges + caps make the count exceed area / h^2; a few secant steps fix the spacing
    spacing = math.sqrt(area / n_points)
    pts, sides = build(spacing)
    for _ in range(4):
        spacing *= math.sqrt(len(pts) / n_points)
        pts, sides = build(spacing)
    pts.setflags(write=False)
    sides.setflags(write=False)
    return pts, sides


def gripper_points(
    spec: GripperSpec,
    n_points: int = 512,
    *,
    include_wrist: bool = False,
    approach_distance: float = 0.0,
    opening: float | None = None,
    margin: float = 0.0,
) -> np.ndarray:
    """Points on the open gripper's surfaces in the gripper frame, ``(P, 3)`` with ``P ~ n_points``.

    ``include_wrist`` adds the link 7/6 cylinder; ``approach_distance > 0`` returns the swept
    afterimage of an approach along ``+z`` from ``approach_distance`` behind the pose (C.3);
    ``margin`` inflates the boxes (:func:`gripper_boxes`). Cached per arguments (read-only).
    """
    return gripper_points_and_sides(
        spec,
        n_points,
        include_wrist=include_wrist,
        approach_distance=approach_distance,
        opening=opening,
        margin=margin,
    )[0]


def gripper_points_and_sides(
    spec: GripperSpec,
    n_points: int = 512,
    *,
    include_wrist: bool = False,
    approach_distance: float = 0.0,
    opening: float | None = None,
    margin: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`gripper_points` ``(P, 3)`` and the side of each point ``(P,)`` int8: ``+1`` left
    finger (``+y``), ``-1`` right finger, ``0`` palm / wrist; moving the ``+-1`` points by
    ``+-dy`` along ``y`` re-opens the hand (:func:`open_gripper_points`)."""
    if n_points < 16 or n_points > 100_000:
        raise ValidationError(f"n_points must be in [16, 100000], got {n_points}")
    if not (math.isfinite(approach_distance) and approach_distance >= 0):
        raise ValidationError(f"approach_distance must be >= 0, got {approach_distance!r}")
    return _gripper_points_cached(
        spec, int(n_points), bool(include_wrist), float(approach_distance), opening, float(margin)
    )


def open_gripper_points(
    poses: torch.Tensor,
    points: np.ndarray,
    sides: np.ndarray,
    openings: torch.Tensor,
    built_opening: float,
) -> torch.Tensor:
    """World points ``(K, P, 3)`` of the gripper at ``poses (K, 4, 4)`` opened to ``openings (K,)``.

    ``points``/``sides`` come from :func:`gripper_points_and_sides` built at ``built_opening``;
    each finger moves by ``(opening_k - built_opening) / 2`` along its side of the closing axis,
    so the collision model holds the hand exactly as wide as it will be opened for execution.
    """
    world = transform_gripper_points(poses, points)
    s = torch.as_tensor(np.asarray(sides, dtype=np.float64), dtype=world.dtype)
    dy = 0.5 * (openings.to(world.dtype) - float(built_opening))  # (K,)
    shift = dy.view(-1, 1, 1) * s.view(1, -1, 1) * poses[:, :3, 1].to(world.dtype).unsqueeze(1)
    return world + shift


def transform_gripper_points(
    poses: torch.Tensor | np.ndarray, points: torch.Tensor | np.ndarray
) -> torch.Tensor:
    """Gripper-frame ``points (P, 3)`` placed at each of ``poses (K, 4, 4)``: world ``(K, P, 3)``."""
    poses_t = torch.as_tensor(poses)
    if torch.is_tensor(points):
        pts = points.to(dtype=poses_t.dtype, device=poses_t.device)
    else:  # copy: the cached arrays are read-only, which torch does not support
        pts = torch.tensor(np.asarray(points), dtype=poses_t.dtype, device=poses_t.device)
    if poses_t.ndim != 3 or poses_t.shape[-2:] != (4, 4):
        raise ValidationError(f"poses must have shape (K, 4, 4), got {tuple(poses_t.shape)}")
    if pts.ndim != 2 or pts.shape[-1] != 3:
        raise ValidationError(f"points must have shape (P, 3), got {tuple(pts.shape)}")
    K, P = poses_t.shape[0], pts.shape[0]
    R, t = poses_t[:, :3, :3], poses_t[:, :3, 3]
    # one (3K x 3) @ (3 x P) product instead of K tiny batched ones
    rotated = (R.reshape(K * 3, 3) @ pts.T).reshape(K, 3, P).transpose(1, 2)
    return rotated + t.unsqueeze(1)
