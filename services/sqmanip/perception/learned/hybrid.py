"""Hybrid recognition: the network's prediction refined by the optimisation fitter.

DSQNet (3.3) completes the hidden side of a partially seen part from what it learned about
shapes, but its surface fits the observed points only to a few millimetres (Table 3.2: error
2.5e-3 to 1.3e-2 against the fitter's 1.8e-5 to 9.1e-4). The optimisation fitter (DSQOpt, 3.5.1,
plus the amodal terms of :mod:`sqmanip.perception.fit`) is the opposite. The hybrid keeps the
best of both:

- the fitter starts from the network's pose, sizes, exponents and taper (one initialisation,
  no search over orientations), in the segment's local plane frame;
- its data term sees the observed points **and** pseudo-observations on the hidden side: points
  of the network's surface farther than ``hybrid_seen_radius`` from every observed point and
  facing away from the camera (where the view says nothing). There are ``hybrid_hidden_weight`` times as many of them as observed
  points, so the seen side is fitted tightly and the unseen side stays close to the network;
- the amodal terms (free space seen by the camera, support plane) still apply, so a hidden-side
  guess that contradicts the view is pushed out of the seen free space.

The fitter has no bending (see :mod:`~sqmanip.perception.fit`), so it starts from the
network's part unbent; the result keeps, per part, whichever of the refined and the network's
(bent) part lies closer to the observed and hidden-side points (exact radial distance 3.3.4).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from scipy.spatial import cKDTree

from sqmanip.geometry import Superquadric
from sqmanip.geometry.sampling import sample_surface

from ..config import PerceptionSettings
from ..fit import (
    _K,
    E_LO,
    E_SPAN,
    K_MAX,
    FitResult,
    _Batch,
    _Data,
    _frame,
    _free_space_samples,
    _optimise,
    _Problem,
    check_equal_sizes,
    rests_on_support,
    seen_around,
    world_part,
)
from ..preprocess import PlaneFit
from ..threads import torch_threads

__all__ = ["hidden_side_points", "refine_parts"]


def hidden_side_points(
    part: Superquadric,
    observed: np.ndarray,
    radius: float,
    viewpoint: np.ndarray | None = None,
    n_surface: int = 512,
    seed: int = 0,
) -> np.ndarray:
    """World points ``(H, 3)`` of ``part``'s surface that the view says nothing about: farther
    than ``radius`` (m) from every point of ``observed (P, 3)`` and, with a ``viewpoint``, facing
    away from it (outward normal along the viewing ray). Unobserved surface that faces the camera
    is not "unknown": the camera would have seen it, so the free-space term handles it instead.
    """
    if radius <= 0:
        raise ValueError(f"radius must be positive, got {radius}")
    pts, nrm = sample_surface(part.params()[None], n_surface, generator=seed)
    R, t = part.pose[:3, :3], part.pose[:3, 3]
    world = np.asarray(pts[0], dtype=np.float64) @ R.T + t
    d, _ = cKDTree(np.asarray(observed, dtype=np.float64)).query(world)
    keep = d > radius
    if viewpoint is not None:
        normals = np.asarray(nrm[0], dtype=np.float64) @ R.T
        ray = world - np.asarray(viewpoint, dtype=np.float64)
        keep &= (normals * ray).sum(1) > 0
    return world[keep]


def refine_parts(
    segments: Sequence[np.ndarray],
    network_parts: Sequence[Superquadric],
    *,
    plane: PlaneFit | None = None,
    viewpoint: np.ndarray | None = None,
    table_points: np.ndarray | None = None,
    settings: PerceptionSettings | None = None,
    amodal: bool = True,
    deformable: bool = True,
    seed: int = 0,
) -> list[FitResult]:
    """Refine ``network_parts[i]`` on ``segments[i]`` (``(P, 3)`` world points, equal ``P``).

    Returns one :class:`~sqmanip.perception.fit.FitResult` per segment (``residual``: mean
    squared radial distance of the observed points to the refined part, m^2). All segments are
    one batch; deterministic for ``seed``.
    """
    s = settings or PerceptionSettings()
    if len(segments) != len(network_parts):
        raise ValueError(
            f"segments and network_parts must have the same length, got {len(segments)} and "
            f"{len(network_parts)}"
        )
    if not segments:
        return []
    check_equal_sizes(segments)
    with torch_threads(s.torch_threads):
        return _refine(segments, network_parts, plane, viewpoint, table_points, s, amodal,
                       deformable, seed)  # fmt: skip


def _residual(part: Superquadric, pts: np.ndarray) -> float:
    from sqmanip.geometry import radial_distance

    T = np.linalg.inv(part.pose)
    local = torch.as_tensor(pts @ T[:3, :3].T + T[:3, 3], dtype=torch.float64)
    d = radial_distance(local, torch.as_tensor(part.params(), dtype=torch.float64))
    return float((d**2).mean())


def _refine(segments, net_parts, plane, viewpoint, table_points, s, amodal, deformable, seed):
    rng = np.random.default_rng(seed)
    use_plane = amodal and plane is not None
    lo, hi = s.size_bounds
    P = len(segments[0])
    n_hidden = max(0, int(round(s.hybrid_hidden_weight * P)))
    out: list[FitResult | None] = [None] * len(segments)
    # (segment index, frame, R0, t0, a0, e0, k0, X, F, contact, network part, X in the world)
    rows = []
    for i, (seg, net) in enumerate(zip(segments, net_parts, strict=True)):
        pts = np.asarray(seg, dtype=np.float64)
        frame = _frame(pts, plane if use_plane else None)
        X = frame.to_local(pts)
        if n_hidden:
            hid = hidden_side_points(net, pts, s.hybrid_seen_radius, viewpoint, seed=seed + i)
            if len(hid):
                pick = rng.choice(len(hid), n_hidden, replace=len(hid) < n_hidden)
                X = np.concatenate([X, frame.to_local(hid[pick])])
            else:  # the whole predicted surface was seen: weight the observed points only
                X = np.concatenate([X, X[rng.choice(P, n_hidden, replace=n_hidden > P)]])
        seen = frame.to_local(seen_around(segments, i, table_points))
        contact = use_plane and rests_on_support(frame.to_local(pts), seen, s.support_contact)
        F = np.zeros((0, 3))
        if amodal and viewpoint is not None:
            eye = frame.to_local(np.asarray(viewpoint, dtype=np.float64))
            table = frame.to_local(table_points) if table_points is not None else None
            F = _free_space_samples(frame.to_local(pts), eye, table if use_plane else None, s, rng)
        R0 = frame.R.T @ net.pose[:3, :3]
        t0 = frame.to_local(net.pose[:3, 3][None])[0]
        rows.append((i, frame, R0, t0, np.asarray(net.size), np.asarray(net.shape),
                     net.taper if deformable else 0.0, X, F, contact, net,
                     X @ frame.R.T + frame.origin))  # fmt: skip
    if rows:
        _optimise_rows(rows, segments, out, s, lo, hi, amodal, deformable, use_plane, seed)
    return [r for r in out if r is not None]


def _optimise_rows(rows, segments, out, s, lo, hi, amodal, deformable, use_plane, seed):
    B = len(rows)
    fmax = max(len(r[8]) for r in rows)
    Fpad, Fw = np.zeros((B, fmax, 3)), np.zeros((B, fmax))
    for b, r in enumerate(rows):
        Fpad[b, : len(r[8])] = r[8]
        Fw[b, : len(r[8])] = 1.0
    data = _Data(
        np.stack([r[7] for r in rows]),
        Fpad,
        Fw,
        np.array([r[9] for r in rows], dtype=bool),
        use_plane,
    )
    e0 = np.clip(np.stack([r[5] for r in rows]), E_LO + 1e-3, E_LO + E_SPAN - 1e-3)
    batch = _Batch(
        np.stack([r[2] for r in rows]),
        np.stack([r[3] for r in rows]),
        np.stack([r[4] for r in rows]),
        e0,
        lo,
        hi,
        deformable,
    )
    k0 = np.clip(np.array([r[6] for r in rows]) / K_MAX, -0.999, 0.999)
    batch.u[:, _K] = np.arctanh(k0)[:, None]
    data = data.subset(s.refine_points, s.refine_free_points, np.random.default_rng([seed, 1]))
    problem = _Problem(batch, data, s, amodal)
    lr = s.hybrid_learning_rate
    _optimise(problem, s.hybrid_iterations, lr, lr * (1.0 - s.lr_decay))
    loss, _ = problem(batch.u)
    params, _, _ = batch.unpack()
    R, t = batch.pose()
    for b, r in enumerate(rows):
        i, frame = r[0], r[1]
        part = world_part(params[b], R[b], t[b], frame)
        # keep whichever of the refined and the network's part is closer to the observed plus
        # hidden-side points (exact radial distance, bending included): a bent network part
        # (the fitter has no bending) survives unless the unbent refinement fits better
        refined = _residual(part, r[11]) if np.isfinite(params[b]).all() else math.inf
        if not refined <= _residual(r[10], r[11]):
            part = r[10]
        pts = np.asarray(segments[i], dtype=np.float64)
        out[i] = FitResult(part, _residual(part, pts), float(loss[b]))
