"""Superquadric fitting by optimisation: robust radial distance plus amodal constraints.

The plain fit (the thesis' DSQOpt, 3.5.1) minimises the squared radial distance (3.3.4, 3.3.5)
of the observed points to a deformable superquadric. On a single view it fits the visible
surface only and leaves the hidden back empty (Table 3.2: IoU 0.14-0.42 on boxes, cones, tori).
The amodal fit adds what one view implies about the unseen side:

- **support**: an object in contact with the removed support plane reaches down to it and does
  not go through it: ``w_s (min_z)^2`` over a fixed grid of surface points (2.2.2, deformed by
  2.3.11) in the plane frame (for segments whose lowest point is within ``support_contact``),
  otherwise only ``w_s relu(-min_z)^2``;
- **free space**: the camera saw through the space in front of every observed point. Points
  ``x - s u`` (``u`` the unit ray from the viewpoint, ``s`` in ``free_space_offsets``) before
  object points, and points along the rays to table points near the object, must be outside:
  ``w_f mean(delta^2 [f < 1])``, with ``delta`` the radial distance (the penetration depth);
- **priors**: initial orientations include upright ones (object z along the plane normal) and
  lying ones, besides the PCA axes and their permutations; tapering has a small ``w_k k^2``.

Data term: pseudo-Huber of the radial distance, ``c^2 (sqrt(1 + (delta/c)^2) - 1)``, robust to
outliers and clustering errors. All (segment, initialisation) problems are one batch in torch:
parameters are kept in range by reparametrisation (sizes by a sigmoid in log space between
``size_bounds``, exponents ``e = 0.2 + 1.5 sigmoid`` in [0.2, 1.7] (Table 3.1), taper
``k = 0.99 tanh``, rotation ``R0 exp([w])``), optimised with Adam; the best initialisations of each
segment are refined further and the lowest total loss wins.

Deformations: tapering ``k`` is fitted (cones need ``k ~ -1``, truncated cones partial taper);
bending stays 0 here (none of the primitive types needs it, and the (identity) bending map would
double the inner loop's cost). ``deformable=False`` fixes ``k = 0`` too.

Cost: both stages run a fixed number of Adam steps over one batch, so the time hardly depends
on the number of segments (tens of small tensor ops per step dominate, not arithmetic).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from sqmanip.geometry import Superquadric, so3_exp, superellipsoid_surface
from sqmanip.geometry.deform import TAPER_MIN

from .config import PerceptionSettings
from .preprocess import PlaneFit

E_LO, E_SPAN = 0.2, 1.5
K_MAX = 0.99
T_SCALE = 0.05
"""Translation step scale (m per unit of the optimised variable)."""


@dataclasses.dataclass(frozen=True)
class FitResult:
    part: Superquadric
    residual: float
    """Mean squared radial distance of the segment's points (m^2)."""
    loss: float
    """Total objective at the optimum (data + amodal terms)."""


@dataclasses.dataclass
class _Frame:
    R: np.ndarray  # (3, 3) columns = local axes in the world
    origin: np.ndarray  # (3,)

    def to_local(self, x: np.ndarray) -> np.ndarray:
        return (x - self.origin) @ self.R


def _frame(points: np.ndarray, plane: PlaneFit | None) -> _Frame:
    """Local frame of a segment: z = plane normal (else world z), origin = centroid projected
    on the plane (else the centroid)."""
    c = points.mean(0)
    if plane is None:
        return _Frame(np.eye(3), c)
    z = plane.normal
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    origin = c - (c @ z + plane.offset) * z
    return _Frame(np.stack([x, y, z], 1), origin)


def _rz(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _right_handed(R: np.ndarray) -> np.ndarray:
    R = R.copy()
    R[:, 2] = np.cross(R[:, 0], R[:, 1])
    return R


def _extent_init(
    X: np.ndarray, R: np.ndarray, floor: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """Centre and half sizes of the box spanned by ``X`` along the columns of ``R``."""
    q = X @ R
    lo, hi = q.min(0), q.max(0)
    if floor is not None:  # extend to the plane along the world-vertical direction
        up = R.T @ np.array([0.0, 0.0, 1.0])
        i = int(np.argmax(np.abs(up)))
        if up[i] > 0:
            lo[i] = min(lo[i], floor / up[i])
        else:
            hi[i] = max(hi[i], floor / up[i])
    centre = R @ ((lo + hi) / 2)
    return centre, np.maximum((hi - lo) / 2, 0.005)


def initial_orientations(X: np.ndarray, upright: bool, pca: bool = True) -> list[np.ndarray]:
    """Candidate object-to-local rotations for points ``X (P, 3)`` in the local frame.

    Upright (object z = local z, yaw from the 2-D principal axis and 45 degrees from it), lying
    (object z horizontal along the 2-D principal axis or across it) and the 3-D principal axes
    with each of them as the object z axis (the permutations that matter for a superquadric).
    """
    out: list[np.ndarray] = []
    if upright:
        xy = X[:, :2] - X[:, :2].mean(0)
        _, vec = np.linalg.eigh(xy.T @ xy + 1e-12 * np.eye(2))
        yaw = math.atan2(vec[1, 1], vec[0, 1])
        out += [_rz(yaw), _rz(yaw + math.pi / 4)]
        for y in (yaw, yaw + math.pi / 2):
            z_obj = np.array([math.cos(y), math.sin(y), 0.0])
            x_obj = np.array([0.0, 0.0, 1.0])
            out.append(np.stack([x_obj, np.cross(z_obj, x_obj), z_obj], 1))
    if pca:
        Xc = X - X.mean(0)
        _, vec = np.linalg.eigh(Xc.T @ Xc + 1e-12 * np.eye(3))
        for zi in range(3):
            xi, yi = [i for i in range(3) if i != zi]
            out.append(_right_handed(np.stack([vec[:, xi], vec[:, yi], vec[:, zi]], 1)))
    return out


def _free_space_samples(
    X: np.ndarray,
    eye: np.ndarray,
    table: np.ndarray | None,
    settings: PerceptionSettings,
    rng: np.random.Generator,
) -> np.ndarray:
    """Local points that the camera at local ``eye`` saw through: ``(F, 3)`` (may be empty)."""
    offsets = np.asarray(settings.free_space_offsets)
    n_rays = settings.free_space_rays
    if n_rays == 0 or len(offsets) == 0:
        return np.zeros((0, 3))
    src = X[rng.choice(len(X), min(n_rays, len(X)), replace=False)]
    u = src - eye
    u /= np.linalg.norm(u, axis=1, keepdims=True).clip(1e-9)
    obj = (src[:, None, :] - offsets[None, :, None] * u[:, None, :]).reshape(-1, 3)
    samples = [obj]
    if table is not None and len(table):
        c = X.mean(0)
        radius = np.linalg.norm(X[:, :2] - c[:2], axis=1).max() + 0.02
        height = X[:, 2].max() + 0.02
        near = table[np.linalg.norm(table[:, :2] - c[:2], axis=1) < radius + 0.15]
        if len(near):
            near = near[rng.choice(len(near), min(len(near), 8 * n_rays), replace=False)]
            u = near - eye
            u /= np.linalg.norm(u, axis=1, keepdims=True).clip(1e-9)
            steps = np.array([0.01, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3])
            q = (near[:, None, :] - steps[None, :, None] * u[:, None, :]).reshape(-1, 3)
            inside = (
                (np.linalg.norm(q[:, :2] - c[:2], axis=1) < radius)
                & (q[:, 2] > 0.004)
                & (q[:, 2] < height)
            )
            q = q[inside]
            if len(q) > n_rays * len(offsets):
                q = q[rng.choice(len(q), n_rays * len(offsets), replace=False)]
            samples.append(q)
    return np.concatenate(samples)


def _pseudo_huber(d: torch.Tensor, c: float) -> torch.Tensor:
    return c * c * (torch.sqrt(1 + (d / c) ** 2) - 1)


def tapered_radial_distance(
    x: torch.Tensor, params: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Radial distance (3.3.4) of object-frame points ``x (B, N, 3)`` to tapered superellipsoids
    ``params (B, 9)`` (bending ignored), and the radial scale ``f^{e1/2}(D_t^{-1} x)`` (< 1 inside).

    The same value as :func:`sqmanip.geometry.radial_distance` for ``b = 0`` (a unit test checks
    it), written for the optimiser's inner loop: the generic function also applies the (identity)
    bending and re-validates its inputs on every call, which costs about 1.5x the time here.
    Uses the same scaling trick (``r = max |x_i / a_i|``) so no power overflows far away.
    """
    a1, a2, a3, e1, e2, k = (params[:, i : i + 1] for i in range(6))
    e1, e2 = e1.clamp(0.2, 1.7), e2.clamp(0.2, 1.7)
    z = x[..., 2]
    t = (k * z / a3 + 1.0).clamp_min(TAPER_MIN)
    q = torch.stack(
        [(x[..., 0] / (t * a1)).abs(), (x[..., 1] / (t * a2)).abs(), (z / a3).abs()], -1
    )
    r = q.amax(-1).clamp_min(1e-20)
    u = (q / r.unsqueeze(-1)).clamp_min(1e-20)
    inner = u[..., 0].pow(2 / e2) + u[..., 1].pow(2 / e2)
    g = inner.pow(e2 / e1) + u[..., 2].pow(2 / e1)
    scale = r * g.pow(e1 / 2)
    norm = torch.linalg.vector_norm(x, dim=-1)
    return (norm - norm / scale).abs(), scale


_ETA = torch.linspace(-math.pi / 2, math.pi / 2, 7)
_OMEGA = torch.linspace(-math.pi, math.pi, 9)[:-1]
_GRID = torch.meshgrid(_ETA, _OMEGA, indexing="ij")
_GRID_ETA, _GRID_OMEGA = _GRID[0].reshape(-1), _GRID[1].reshape(-1)


class _Batch:
    """Unconstrained variables of ``B`` problems and the map to superquadric parameters."""

    def __init__(self, R0, t0, a0, e0, lo: float, hi: float, deformable: bool):
        B = R0.shape[0]
        self.R0 = R0
        self.t0 = t0
        self.log_lo, self.log_hi = math.log(lo), math.log(hi)
        frac = (torch.log(a0.clamp(lo * 1.01, hi * 0.99)) - self.log_lo) / (
            self.log_hi - self.log_lo
        )
        self.u_a = torch.logit(frac).clone().requires_grad_(True)
        self.u_e = torch.logit((e0 - E_LO) / E_SPAN).clone().requires_grad_(True)
        self.u_t = torch.zeros(B, 3, requires_grad=True)
        self.w = torch.zeros(B, 3, requires_grad=True)
        self.u_k = torch.zeros(B, 1, requires_grad=deformable)
        self.deformable = deformable

    def variables(self) -> list[torch.Tensor]:
        v = [self.u_a, self.u_e, self.u_t, self.w]
        return [*v, self.u_k] if self.deformable else v

    def select(self, idx: torch.Tensor) -> _Batch:
        new = object.__new__(_Batch)
        new.R0, new.t0 = self.R0[idx], self.t0[idx]
        new.log_lo, new.log_hi, new.deformable = self.log_lo, self.log_hi, self.deformable
        for name in ("u_a", "u_e", "u_t", "w", "u_k"):
            src = getattr(self, name)
            setattr(new, name, src.detach()[idx].clone().requires_grad_(src.requires_grad))
        return new

    def unpack(self):
        a = torch.exp(self.log_lo + (self.log_hi - self.log_lo) * torch.sigmoid(self.u_a))
        e = E_LO + E_SPAN * torch.sigmoid(self.u_e)
        k = K_MAX * torch.tanh(self.u_k)
        zeros = torch.zeros_like(k)
        params = torch.cat([a, e, k, zeros, zeros, zeros], -1)  # (B, 9)
        R = self.R0 @ so3_exp(self.w)
        t = self.t0 + T_SCALE * self.u_t
        return params, R, t


@dataclasses.dataclass
class _Data:
    X: torch.Tensor  # (B, P, 3) local
    F: torch.Tensor  # (B, Fm, 3) local free-space samples
    Fw: torch.Tensor  # (B, Fm) weights (0 = padding)
    contact: torch.Tensor  # (B,) 1 if the segment rests on the plane
    has_plane: bool


def _losses(batch: _Batch, data: _Data, settings: PerceptionSettings, amodal: bool):
    params, R, t = batch.unpack()
    n = data.X.shape[1]
    use_free = amodal and data.F.shape[1] > 0 and settings.free_space_weight > 0
    pts = torch.cat([data.X, data.F], 1) if use_free else data.X  # one pass for both terms
    local = (pts - t.unsqueeze(1)) @ R  # (B, N, 3) object frame
    dist, scale = tapered_radial_distance(local, params)
    delta = dist[:, :n]
    loss = _pseudo_huber(delta, settings.huber_delta).mean(-1)
    if batch.deformable:
        loss = loss + settings.taper_weight * params[:, 5] ** 2
    if not amodal:
        return loss, delta
    if use_free:
        inside = (scale[:, n:].detach() < 1.0).to(dist.dtype) * data.Fw
        free = (inside * dist[:, n:] ** 2).sum(-1) / data.Fw.sum(-1).clamp_min(1.0)
        loss = loss + settings.free_space_weight * free
    if data.has_plane and settings.support_weight > 0:
        a1, a2, a3, e1, e2, k = (params[:, i : i + 1] for i in range(6))
        s = superellipsoid_surface(_GRID_ETA, _GRID_OMEGA, a1, a2, a3, e1, e2)  # (B, G, 3)
        taper = (k.unsqueeze(-1) * s[..., 2:] / a3.unsqueeze(-1) + 1.0).clamp_min(TAPER_MIN)
        s = torch.cat([s[..., :2] * taper, s[..., 2:]], -1)  # D_t (2.3.11)
        z = (s * R[:, 2:3, :]).sum(-1) + t[:, 2:3]  # height above the plane
        zmin = z.amin(-1)
        gap = torch.where(data.contact > 0, zmin, torch.relu(-zmin))
        loss = loss + settings.support_weight * gap**2
    return loss, delta


def _optimise(batch: _Batch, data: _Data, settings, amodal: bool, steps: int, lr: float):
    opt = torch.optim.Adam(batch.variables(), lr=lr, foreach=True)
    for i in range(steps):
        # linear decay by lr_decay: large moves first, then settle (few steps in all)
        opt.param_groups[0]["lr"] = lr * (1.0 - settings.lr_decay * i / max(steps - 1, 1))
        opt.zero_grad(set_to_none=True)
        loss, _ = _losses(batch, data, settings, amodal)
        loss.sum().backward()
        opt.step()
    with torch.no_grad():
        loss, delta = _losses(batch, data, settings, amodal)
    return loss, delta


def fit_segments(
    segments: list[np.ndarray],
    *,
    plane: PlaneFit | None = None,
    viewpoint: np.ndarray | None = None,
    table_points: np.ndarray | None = None,
    settings: PerceptionSettings | None = None,
    amodal: bool = True,
    deformable: bool = True,
    seed: int = 0,
) -> list[FitResult]:
    """Fit one superquadric to each segment (``(P, 3)`` world points, equal ``P``), batched.

    ``plane``, ``viewpoint`` and ``table_points`` (world points of the removed support plane)
    feed the amodal terms (module docstring); ``amodal=False`` is the plain DSQOpt fit.
    Deterministic for ``seed``.
    """
    settings = settings or PerceptionSettings()
    if not segments:
        return []
    sizes = {len(s) for s in segments}
    if len(sizes) != 1:
        raise ValueError(f"segments must all have the same number of points, got {sorted(sizes)}")
    threads = torch.get_num_threads()
    if settings.torch_threads and settings.torch_threads != threads:
        torch.set_num_threads(settings.torch_threads)
    try:
        return _fit(segments, plane, viewpoint, table_points, settings, amodal, deformable, seed)
    finally:
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)


def _fit(segments, plane, viewpoint, table_points, settings, amodal, deformable, seed):
    rng = np.random.default_rng(seed)
    use_plane = amodal and plane is not None
    lo, hi = settings.size_bounds

    R0s, t0s, a0s, Xs, Fs, contacts, owner, frames = [], [], [], [], [], [], [], []
    for si, seg in enumerate(segments):
        pts = np.asarray(seg, dtype=np.float64)
        frame = _frame(pts, plane if use_plane else None)
        frames.append(frame)
        X = frame.to_local(pts)
        contact = bool(use_plane and X[:, 2].min() < settings.support_contact)
        floor = 0.0 if contact else None
        F = np.zeros((0, 3))
        if amodal and viewpoint is not None:
            eye = frame.to_local(np.asarray(viewpoint, dtype=np.float64))
            table = frame.to_local(table_points) if table_points is not None else None
            F = _free_space_samples(X, eye, table if use_plane else None, settings, rng)
        for R0 in initial_orientations(X, upright=use_plane, pca=not contact or settings.pca_inits):
            centre, half = _extent_init(X, R0, floor)
            R0s.append(R0)
            t0s.append(centre)
            a0s.append(half)
            Xs.append(X)
            Fs.append(F)
            contacts.append(float(contact))
            owner.append(si)

    B = len(R0s)
    fmax = max(len(f) for f in Fs)
    Fpad = np.zeros((B, fmax, 3))
    Fw = np.zeros((B, fmax))
    for i, f in enumerate(Fs):
        Fpad[i, : len(f)] = f
        Fw[i, : len(f)] = 1.0
    f32 = torch.float32
    data = _Data(
        torch.as_tensor(np.stack(Xs), dtype=f32),
        torch.as_tensor(Fpad, dtype=f32),
        torch.as_tensor(Fw, dtype=f32),
        torch.as_tensor(contacts, dtype=f32),
        use_plane,
    )
    e0 = torch.tensor(settings.initial_shape, dtype=f32).expand(B, 2)
    batch = _Batch(
        torch.as_tensor(np.stack(R0s), dtype=f32),
        torch.as_tensor(np.stack(t0s), dtype=f32),
        torch.as_tensor(np.stack(a0s), dtype=f32),
        e0,
        lo,
        hi,
        deformable,
    )
    # stage 1: every initialisation on a random subset of the points and free-space samples
    g = torch.Generator().manual_seed(seed)
    n_sel = min(settings.select_points, data.X.shape[1])
    f_sel = min(settings.select_free_points, data.F.shape[1])
    pi = torch.randperm(data.X.shape[1], generator=g)[:n_sel]
    fi = torch.randperm(data.F.shape[1], generator=g)[:f_sel]
    small = _Data(data.X[:, pi], data.F[:, fi], data.Fw[:, fi], data.contact, use_plane)
    loss, _ = _optimise(
        batch, small, settings, amodal, settings.fit_iterations, settings.learning_rate
    )
    owner_t = torch.as_tensor(owner)
    # stage 2: the best initialisations of each segment on all points
    keep = []
    for si in range(len(segments)):
        idx = torch.nonzero(owner_t == si).squeeze(-1)
        order = torch.argsort(loss[idx])[: settings.refine_keep]
        keep.append(idx[order])
    keep_t = torch.cat(keep)
    batch = batch.select(keep_t)
    data = _Data(data.X[keep_t], data.F[keep_t], data.Fw[keep_t], data.contact[keep_t], use_plane)
    owner_t = owner_t[keep_t]
    loss, _ = _optimise(
        batch, data, settings, amodal, settings.refine_iterations, settings.refine_learning_rate
    )
    with torch.no_grad():
        params, R, t = batch.unpack()
        _, delta = _losses(batch, data, settings, False)
    results = []
    for si in range(len(segments)):
        idx = torch.nonzero(owner_t == si).squeeze(-1)
        best = int(idx[torch.argmin(loss[idx])])
        p = params[best].double().numpy()
        frame = frames[si]
        pose = np.eye(4)
        pose[:3, :3] = frame.R @ R[best].double().numpy()
        pose[:3, 3] = frame.R @ t[best].double().numpy() + frame.origin
        # re-orthonormalise (float32 round-off)
        u, _, vt = np.linalg.svd(pose[:3, :3])
        pose[:3, :3] = u @ vt
        part = Superquadric(
            (float(p[0]), float(p[1]), float(p[2])),
            (float(p[3]), float(p[4])),
            pose=pose,
            taper=float(p[5]),
        )
        residual = float((delta[best].double() ** 2).mean())
        results.append(FitResult(part, residual, float(loss[best])))
    return results
