"""Rule-based grasp candidates from a superquadric's size and shape (B.5, C.3).

The MPC (B.5) and the shelf search (C.3) evaluate graspability thousands of times, so instead of
sampling antipodal pairs they place a handful of grasps by rule, in each part's own frame:

- the object axis closest to the support normal is "vertical", the other two "horizontal";
- **top-down**: approach straight down that vertical axis, the TCP ``grasp_depth`` below the top;
  the fingers close across one horizontal axis at ``per_direction`` positions spread along the other
  (for a round cross-section, ``e2 >= 0.6``, the closing axis turns about the vertical instead);
- **side** (four directions): approach along ``+-`` each horizontal axis, the TCP ``grasp_depth``
  past the near face, closing across the other horizontal axis, at ``per_direction`` heights;
- the two fingers sit on antipodal points (B.5): the contacts are where the closing line through
  the TCP enters and leaves the (deformed) part (``geometry.raycast``), the TCP is re-centred
  between them, pairs failing the relaxed antipodal test (3.4.7) are dropped (an off-centre chord
  of a round section is not a grasp), and so are widths over ``max_width`` (7 cm, B.5; 7.5 cm, C.3);
- optionally (C.3) side grasps are pitched ``tilt`` down about their closing axis, and only those
  facing a given horizontal direction (e.g. into the shelf) are kept.

At most ``max_candidates`` (30) per object. Collision and reachability are the caller's
(:class:`~sqmanip.grasping.planner.GraspPlanner` or the MPC's batched check).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from sqmanip.errors import ValidationError
from sqmanip.geometry import SUPERPARABOLOID, SUPERTOROID, Superquadric
from sqmanip.geometry.raycast import bound_radius, line_intersections
from sqmanip.geometry.superquadric import normal

from .types import Candidates, RuleOptions


def part_box(part: Superquadric) -> tuple[np.ndarray, np.ndarray]:
    """Centre and half extents ``(3,), (3,)`` of the undeformed part in its own frame."""
    a1, a2, a3 = part.size
    if part.kind_index == SUPERPARABOLOID:  # from the tip z = -a3 up to the cap z = 0 (2.2.8)
        return np.array([0.0, 0.0, -a3 / 2]), np.array([a1, a2, a3 / 2])
    if part.kind_index == SUPERTOROID:
        g = 1.0 + part.a4
        return np.zeros(3), np.array([a1 * g, a2 * g, a3])
    return np.zeros(3), np.array([a1, a2, a3], dtype=np.float64)


def _frame(y: np.ndarray, z: np.ndarray) -> np.ndarray:
    x = np.cross(y, z)
    return np.stack([x, y, z], -1)


def _spread(center: float, half: float, spread: float, n: int) -> np.ndarray:
    if n <= 1:
        return np.array([center])
    return center + np.linspace(-spread * half, spread * half, n)


def _part_candidates(
    part: Superquadric, up: np.ndarray, opt: RuleOptions
) -> tuple[list[np.ndarray], list[np.ndarray], list[bool]]:
    """Local TCP positions and rotations (object frame) before contacts; flags side grasps."""
    c, b = part_box(part)
    R_o = part.pose[:3, :3]
    up_l = R_o.T @ up
    iv = int(np.argmax(np.abs(up_l)))
    sv = 1.0 if up_l[iv] >= 0 else -1.0
    i1, i2 = [i for i in range(3) if i != iv]
    e = np.eye(3)
    shrink = 1.0 - min(abs(part.taper), 0.99)  # tapering can make a section this much thinner
    n = opt.per_direction
    positions: list[np.ndarray] = []
    rotations: list[np.ndarray] = []
    side: list[bool] = []
    round_xy = iv == 2 and part.shape[1] >= opt.round_threshold and part.kind_index != SUPERTOROID

    def fits(axis: int) -> bool:
        return 2 * b[axis] * shrink <= opt.max_width

    if opt.top_down:
        z = -sv * e[iv]
        tcp = c.copy()
        tcp[iv] = c[iv] + sv * (b[iv] - min(opt.grasp_depth, b[iv]))
        if round_xy:
            for k in range(n):
                phi = math.pi * k / n
                y = math.cos(phi) * e[i1] + math.sin(phi) * e[i2]
                positions.append(tcp.copy())
                rotations.append(_frame(y, z))
                side.append(False)
        else:
            options = [(ax, free) for ax, free in ((i1, i2), (i2, i1)) if fits(ax)]
            for j, (ax, free) in enumerate(options):
                count = n // len(options) + (1 if j < n % len(options) else 0)
                for s in _spread(c[free], b[free], opt.spread, count):
                    p = tcp.copy()
                    p[free] = s
                    positions.append(p)
                    rotations.append(_frame(e[ax], z))
                    side.append(False)
    if opt.side:
        for ha, hb in ((i1, i2), (i2, i1)):
            if not fits(hb) and not round_xy:
                continue
            for sign in (1.0, -1.0):
                z = sign * e[ha]
                R = _frame(e[hb], z)
                if opt.tilt != 0.0:
                    x_up = float(R[:, 0] @ up_l)
                    theta = -opt.tilt * (1.0 if x_up >= 0 else -1.0)
                    ct, st = math.cos(theta), math.sin(theta)
                    x, zz = R[:, 0].copy(), R[:, 2].copy()
                    R = np.stack([ct * x - st * zz, R[:, 1], st * x + ct * zz], -1)
                for h in _spread(c[iv], b[iv], opt.spread, n):
                    p = c.copy()
                    p[ha] = c[ha] - sign * (b[ha] - min(opt.grasp_depth, b[ha]))
                    p[iv] = h
                    positions.append(p)
                    rotations.append(R)
                    side.append(True)
    return positions, rotations, side


def rule_based_candidates(
    parts: Sequence[Superquadric],
    *,
    up: Sequence[float] | np.ndarray = (0.0, 0.0, 1.0),
    options: RuleOptions | None = None,
    dtype: torch.dtype = torch.float64,
) -> Candidates:
    """Rule-based candidates for one object made of ``parts`` (B.5 / C.3), world frame.

    ``up`` is the support normal ``z_t`` (vertical / top-down are relative to it). Returns at most
    ``options.max_candidates`` poses with their antipodal contacts and widths (all within
    ``options.max_width``).
    """
    opt = options or RuleOptions()
    up_v = np.asarray(up, dtype=np.float64)
    if up_v.shape != (3,) or not np.isfinite(up_v).all() or np.linalg.norm(up_v) < 1e-9:
        raise ValidationError(f"up must be a finite non-zero (3,) vector, got {up!r}")
    up_v = up_v / np.linalg.norm(up_v)
    if len(parts) == 0:
        raise ValidationError("parts must hold at least one Superquadric, got 0")
    poses, widths, contacts = [], [], []
    for part in parts:
        if not isinstance(part, Superquadric):
            raise ValidationError(f"parts must hold Superquadric values, got {type(part).__name__}")
        pos, rot, side = _part_candidates(part, up_v, opt)
        if not pos:
            continue
        P = torch.as_tensor(np.stack(pos), dtype=dtype)
        R = torch.as_tensor(np.stack(rot), dtype=dtype)
        params = torch.as_tensor(part.params(), dtype=dtype)
        y = R[:, :, 1]
        reach = 2.0 * float(bound_radius(params, part.kind_index)) + 0.01
        origins = P - reach * y
        hits = line_intersections(origins, y, params, None, part.kind_index, t_min=0.0)
        if hits.t.shape[-1] == 0:
            continue
        t_in = torch.where(hits.valid, hits.t, torch.full_like(hits.t, math.inf)).amin(-1)
        t_out = torch.where(hits.valid, hits.t, torch.full_like(hits.t, -math.inf)).amax(-1)
        ok = hits.valid.sum(-1) >= 2
        width = t_out - t_in
        ok &= (width <= opt.max_width) & (width > 0)
        c_in = origins + t_in.unsqueeze(-1) * y
        c_out = origins + t_out.unsqueeze(-1) * y
        finite = ok.unsqueeze(-1)
        n_in = normal(torch.where(finite, c_in, P).unsqueeze(0), params, part.kind_index)[0]
        n_out = normal(torch.where(finite, c_out, P).unsqueeze(0), params, part.kind_index)[0]
        ok &= (n_in * n_out).sum(-1) < -opt.antipodal_threshold
        tcp = 0.5 * (c_in + c_out)
        R_o = torch.as_tensor(part.pose[:3, :3], dtype=dtype)
        t_o = torch.as_tensor(part.pose[:3, 3], dtype=dtype)
        T = torch.zeros(len(pos), 4, 4, dtype=dtype)
        T[:, :3, :3] = R_o @ R
        T[:, :3, 3] = tcp @ R_o.T + t_o
        T[:, 3, 3] = 1.0
        if opt.facing is not None:
            f = np.asarray(opt.facing, dtype=np.float64)
            f = f - (f @ up_v) * up_v
            fn = np.linalg.norm(f)
            if fn > 1e-9:
                f_t = torch.as_tensor(f / fn, dtype=dtype)
                up_t = torch.as_tensor(up_v, dtype=dtype)
                z = T[:, :3, 2]
                zh = z - (z @ up_t).unsqueeze(-1) * up_t
                cos = (zh @ f_t) / torch.linalg.vector_norm(zh, dim=-1).clamp_min(1e-12)
                is_side = torch.as_tensor(side)
                ok &= ~is_side | (cos >= math.cos(opt.facing_angle))
        world_contacts = torch.stack([c_in, c_out], 1) @ R_o.T + t_o
        poses.append(T[ok])
        widths.append(width[ok])
        contacts.append(world_contacts[ok])
    if not poses:
        return Candidates.empty(dtype)
    out = Candidates(torch.cat(poses), torch.cat(widths), torch.cat(contacts))
    if len(out) > opt.max_candidates:
        keep = torch.as_tensor(
            np.unique(np.round(np.linspace(0, len(out) - 1, opt.max_candidates)).astype(np.int64))
        )
        out = Candidates(out.poses[keep], out.widths[keep], out.contacts[keep])
    return out
