"""The pushing action sampler of Ch. 4.5 (Fig. 4.7), shared by data generation and MPC.

For a chosen object ``i`` the candidates are:

- 8 push directions ``theta_k = yaw_i + 2 pi k / 8`` towards the object's centre, where
  ``yaw_i`` is the heading of ``C_i`` (B.1.1); measuring them from the object's heading (not the
  world x axis) makes the candidate set itself SE(2)-equivariant: transforming the scene
  transforms the candidates, so the data distribution has no preferred direction;
- 5 tool heights ``h_m = H (m + 1) / 6`` (``H = 0.192`` m, the workspace height, divided equally),
  keeping those below the object's top (if none is, the mid-height of the object is used);
- 4 start points on the line through the centre along the push: the tool tip starts
  ``r(theta) + tip_radius + 2 clearance + o_j`` before the centre, ``r`` the object's extent
  towards the pusher and ``o_j`` in ``start_offsets``.

So at most ``8 x 5 x 4 = 160`` candidates per object. Every action is ``(p, v)`` with ``v`` of
length ``push_length`` along the direction. Candidates whose start or end leave the workspace or
whose start point lies inside (or within ``clearance`` of) any object are dropped.

``min_travel`` (off in data generation, on in the MPC) also drops pushes whose tip meets the
object on its pushing line less than that before the push ends. The start distance is the
object's extent towards the pusher (its support function). Along an elongated object's diagonal
that is much more than where the line enters the object. There, a 34 x 13 cm box pushed at 45
degrees is touched for 1.6 cm, or not at all, and barely moves. SQPD-Net, trained on smaller
objects, predicts 6-7 cm for such pushes.

The functions take objects as ``(poses (N, 4, 4), params (N, 9))`` arrays (ground truth in data
generation) or as :class:`~sqmanip.geometry.types.Superquadric` lists (recognized shapes in MPC).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from sqmanip.geometry.superquadric import N_PARAMS, superellipsoid_surface
from sqmanip.geometry.transforms import decompose_pose
from sqmanip.geometry.types import Superquadric

__all__ = [
    "PushCandidates",
    "as_object_arrays",
    "as_workspace_bounds",
    "push_candidates",
    "sample_push_actions",
]

WORKSPACE_HEIGHT = 0.192
"""Ch. 4.5: the workspace is 0.512 x 0.512 x 0.192 m."""


@dataclasses.dataclass(frozen=True)
class PushCandidates:
    """All valid candidate pushes of a scene; one row per candidate."""

    actions: np.ndarray
    """``(K, 6)`` rows ``(p, v)`` in the world frame (m)."""
    target: np.ndarray
    """``(K,)`` index of the pushed object."""
    direction: np.ndarray
    """``(K,)`` direction index in ``0..directions-1``."""
    height: np.ndarray
    """``(K,)`` height index in ``0..heights-1`` (``-1``: the mid-height fallback)."""
    start: np.ndarray
    """``(K,)`` start-point index in ``0..len(start_offsets)-1``."""

    def __len__(self) -> int:
        return int(self.actions.shape[0])


def as_object_arrays(
    objects: Sequence[Superquadric] | tuple[Any, Any],
) -> tuple[np.ndarray, np.ndarray]:
    """``(poses (N, 4, 4), params (N, 9))`` float64 from either accepted object form."""
    if (
        isinstance(objects, tuple)
        and len(objects) == 2
        and not isinstance(objects[0], Superquadric)
    ):
        poses = np.asarray(objects[0], dtype=np.float64)
        params = np.asarray(objects[1], dtype=np.float64)
    else:
        items = list(objects)
        if items and not all(isinstance(o, Superquadric) for o in items):
            raise ValueError("objects must be a (poses, params) tuple or a list of Superquadric")
        poses = np.stack([o.pose for o in items]) if items else np.zeros((0, 4, 4))
        params = np.stack([o.params() for o in items]) if items else np.zeros((0, N_PARAMS))
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"poses must have shape (N, 4, 4), got {poses.shape}")
    if params.shape != (poses.shape[0], N_PARAMS):
        raise ValueError(
            f"params must have shape ({poses.shape[0]}, {N_PARAMS}), got {params.shape}"
        )
    if not (np.isfinite(poses).all() and np.isfinite(params).all()):
        raise ValueError("poses and params must be finite")
    return poses, params


def as_workspace_bounds(workspace: Any) -> np.ndarray:
    """``(2, 3)`` lower/upper corners from an array or an object with ``min`` / ``max``."""
    if (
        hasattr(workspace, "min")
        and hasattr(workspace, "max")
        and not isinstance(workspace, np.ndarray)
    ):
        b = np.array([workspace.min, workspace.max], dtype=np.float64)
    else:
        b = np.asarray(workspace, dtype=np.float64)
    if b.shape != (2, 3) or not np.isfinite(b).all() or np.any(b[1] <= b[0]):
        raise ValueError(f"workspace must be (2, 3) finite bounds with max > min, got {b.tolist()}")
    return b


def _surface_points(params: np.ndarray, n_eta: int = 17, n_omega: int = 48) -> np.ndarray:
    """``(N, S, 3)`` object-frame points covering each object's surface.

    Superellipsoid parametrisation (2.2.2) of the sizes and exponents; deformations and other
    kinds are bounded by the same ``a1..a3`` box closely enough for choosing start points.
    """
    t = torch.as_tensor(params, dtype=torch.float64)
    eta = torch.linspace(-math.pi / 2, math.pi / 2, n_eta, dtype=torch.float64)
    omega = torch.linspace(-math.pi, math.pi, n_omega + 1, dtype=torch.float64)[:-1]
    eta, omega = torch.meshgrid(eta, omega, indexing="ij")
    e = t[:, 3:5].clamp(0.1, 2.0)
    a = t[:, :3]
    pts = superellipsoid_surface(
        eta.reshape(1, -1),
        omega.reshape(1, -1),
        a[:, 0:1],
        a[:, 1:2],
        a[:, 2:3],
        e[:, 0:1],
        e[:, 1:2],
    )
    return pts.numpy()


def push_candidates(
    objects: Sequence[Superquadric] | tuple[Any, Any],
    workspace: Any,
    *,
    targets: Sequence[int] | None = None,
    directions: int = 8,
    heights: int = 5,
    start_offsets: Sequence[float] = (0.0, 0.01, 0.02, 0.03),
    push_length: float = 0.10,
    tip_radius: float = 0.01,
    clearance: float = 0.005,
    workspace_height: float = WORKSPACE_HEIGHT,
    min_travel: float | None = None,
) -> PushCandidates:
    """Every valid candidate push of the 4.5 sampler for the objects ``targets`` (default all).

    ``objects``: ``(poses (N, 4, 4), params (N, 9))`` or ``Superquadric`` list; ``workspace``:
    ``(2, 3)`` bounds or an object with ``min`` / ``max`` (e.g. ``perception.types.Workspace``).
    Heights are measured from the workspace floor ``workspace[0, 2]``. Deterministic (no RNG).
    ``min_travel`` (m): keep only pushes that move the tip at least this far once it reaches the
    object on the pushing line (module docstring); None keeps every push.
    """
    poses, params = as_object_arrays(objects)
    bounds = as_workspace_bounds(workspace)
    if directions < 1 or heights < 1 or len(start_offsets) < 1:
        raise ValueError(
            f"directions, heights and start_offsets must be non-empty, got {directions}, "
            f"{heights}, {len(start_offsets)}"
        )
    if push_length <= 0:
        raise ValueError(f"push_length must be positive, got {push_length}")
    n = poses.shape[0]
    targets = list(range(n)) if targets is None else [int(t) for t in targets]
    for t in targets:
        if not 0 <= t < n:
            raise ValueError(f"targets must index the {n} objects, got {t}")
    empty = PushCandidates(np.zeros((0, 6)), *(np.zeros(0, dtype=np.int64) for _ in range(4)))
    if n == 0 or not targets:
        return empty
    # World-frame surface points for extents and tops.
    local = _surface_points(params)  # (N, S, 3)
    world = np.einsum("nij,nsj->nsi", poses[:, :3, :3], local) + poses[:, None, :3, 3]
    C, _ = decompose_pose(torch.as_tensor(poses))
    yaw = torch.atan2(C[:, 1, 0], C[:, 0, 0]).numpy()
    floor = bounds[0, 2]
    level = floor + workspace_height * np.arange(1, heights + 1) / (heights + 1)  # (H,)
    offsets = np.asarray(start_offsets, dtype=np.float64)
    rows, info = [], []
    for i in targets:
        center = poses[i, :2, 3]
        top, bottom = world[i, :, 2].max(), world[i, :, 2].min()
        ok_h = np.nonzero((level < top) & (level > bottom))[0]
        h_vals = level[ok_h] if ok_h.size else np.array([(top + bottom) / 2])
        h_idx = ok_h if ok_h.size else np.array([-1])
        theta = yaw[i] + 2 * math.pi * np.arange(directions) / directions  # (D,)
        d = np.stack([np.cos(theta), np.sin(theta)], -1)  # (D, 2)
        rel = world[i, :, :2] - center  # (S, 2)
        extent = (rel @ -d.T).max(0)  # (D,): reach of the object towards the pusher side
        back = extent[:, None] + tip_radius + 2 * clearance + offsets[None, :]  # (D, J)
        start_xy = center - back[..., None] * d[:, None, :]  # (D, J, 2)
        D, J, Hn = directions, offsets.size, h_vals.size
        touches = np.ones((D, J), dtype=bool)
        if min_travel is not None:
            reach = _reach_along(params[i], poses[i, :3, :3], -d)  # (D,)
            travel = push_length - (back - tip_radius - reach[:, None])
            touches = travel >= min_travel
        p = np.concatenate(
            [
                np.broadcast_to(start_xy[:, :, None, :], (D, J, Hn, 2)),
                np.broadcast_to(h_vals[None, None, :, None], (D, J, Hn, 1)),
            ],
            -1,
        ).reshape(-1, 3)
        v = np.concatenate(
            [
                np.broadcast_to(d[:, None, None, :] * push_length, (D, J, Hn, 2)),
                np.zeros((D, J, Hn, 1)),
            ],
            -1,
        ).reshape(-1, 3)
        idx = np.stack(
            np.broadcast_arrays(
                np.arange(D)[:, None, None], h_idx[None, None, :], np.arange(J)[None, :, None]
            ),
            -1,
        ).reshape(-1, 3)
        keep_i = np.broadcast_to(touches[:, :, None], (D, J, Hn)).reshape(-1)
        rows.append(np.concatenate([p, v], -1)[keep_i])
        info.append(np.concatenate([np.full((p.shape[0], 1), i), idx], -1)[keep_i])
    actions = np.concatenate(rows)
    meta = np.concatenate(info)
    keep = _inside(actions[:, :3], bounds) & _inside(actions[:, :3] + actions[:, 3:], bounds)
    keep &= _clear(actions[:, :3], poses, params, tip_radius + clearance)
    actions, meta = actions[keep], meta[keep]
    return PushCandidates(
        actions, meta[:, 0].astype(np.int64), meta[:, 1].astype(np.int64),
        meta[:, 2].astype(np.int64), meta[:, 3].astype(np.int64),
    )  # fmt: skip


def _reach_along(params: np.ndarray, R: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``(D,)`` distance from the object's centre to its surface along the horizontal world
    directions ``d (D, 2)``: the superellipsoid's inside-outside function is homogeneous about
    its centre, ``F(s u) = s^(2/e1) F(u)``, so the surface lies at ``s = F(u)^(-e1/2)``
    (deformations ignored, as for the surface points)."""
    a = np.maximum(params[:3], 1e-6)
    e1, e2 = np.clip(params[3:5], 0.1, 2.0)
    u = np.concatenate([d, np.zeros((len(d), 1))], -1) @ R  # object frame (R^T d per row)
    q = np.abs(u) / a
    F = (q[:, 0] ** (2 / e2) + q[:, 1] ** (2 / e2)) ** (e2 / e1) + q[:, 2] ** (2 / e1)
    return np.maximum(F, 1e-300) ** (-e1 / 2)


def _inside(x: np.ndarray, bounds: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    return np.all((x >= bounds[0] - tol) & (x <= bounds[1] + tol), -1)


def _clear(points: np.ndarray, poses: np.ndarray, params: np.ndarray, margin: float) -> np.ndarray:
    """Whether each point ``(K, 3)`` lies outside every object grown by ``margin`` along its
    axes (a conservative box-like growth of the superellipsoid sizes)."""
    if points.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    R, t = poses[:, :3, :3], poses[:, :3, 3]
    local = np.einsum("nji,knj->kni", R, points[:, None, :] - t[None])  # (K, N, 3)
    a = params[None, :, :3] + margin
    e1 = np.clip(params[None, :, 3], 0.1, 2.0)
    e2 = np.clip(params[None, :, 4], 0.1, 2.0)
    q = np.abs(local) / a
    with np.errstate(over="ignore", divide="ignore"):
        xy = (q[..., 0] ** (2 / e2) + q[..., 1] ** (2 / e2)) ** (e2 / e1)
        f = xy + q[..., 2] ** (2 / e1)
    return np.all(~(f < 1.0), -1)


def sample_push_actions(
    objects: Sequence[Superquadric] | tuple[Any, Any],
    workspace: Any,
    rng: np.random.Generator,
    n: int | None = 1,
    *,
    targets: Sequence[int] | None = None,
    **candidate_kw: Any,
) -> np.ndarray:
    """``(K, 6)`` random pushes ``(p, v)`` of the 4.5 sampler, ``K = min(n, #candidates)``.

    As in 4.5, an object is chosen uniformly (among ``targets`` that have candidates), then one
    of its candidates uniformly: candidates are drawn without replacement with weight
    ``1 / (candidates of its object)``. ``n=None`` returns every candidate in random order.
    ``candidate_kw`` go to :func:`push_candidates`. An empty ``(0, 6)`` means no valid push.
    """
    if n is not None and n < 0:
        raise ValueError(f"n must be >= 0 or None, got {n}")
    cand = push_candidates(objects, workspace, targets=targets, **candidate_kw)
    k = len(cand)
    if k == 0 or n == 0:
        return np.zeros((0, 6))
    counts = np.bincount(cand.target)
    w = 1.0 / counts[cand.target]
    m = k if n is None else min(n, k)
    idx = rng.choice(k, size=m, replace=False, p=w / w.sum())
    return cand.actions[idx]
