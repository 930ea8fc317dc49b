"""Superquadric fitting by optimisation: robust radial distance plus amodal constraints.

The plain fit (the thesis' DSQOpt, 3.5.1) minimises the squared radial distance (3.3.4, 3.3.5)
of the observed points to a deformable superquadric. On a single view it fits the visible
surface only and leaves the hidden back empty (Table 3.2: IoU 0.14-0.42 on boxes, cones, tori).
The amodal fit adds what one view implies about the unseen side:

- **support**: an object in contact with the removed support plane reaches down to it and does
  not go through it: ``w_s (min_z)^2`` over a fixed grid of surface points (2.2.2, deformed by
  2.3.11) in the plane frame for segments that rest on it (:func:`rests_on_support`: the
  lowest point within ``support_contact``, or nothing seen under the segment), otherwise only
  ``w_s relu(-min_z)^2``;
- **free space**: the camera saw through the space in front of every observed point. Points
  ``x - s u`` (``u`` the unit ray from the viewpoint, ``s`` in ``free_space_offsets``) before
  object points, and points along the rays to the support plane's points and to points seen
  below it (the floor past a table's edge) where they pass the object, must be outside:
  ``w_f mean(delta^2 [f < 1])``, with ``delta`` the radial distance (the penetration depth);
- **priors**: initial orientations include upright ones (object z along the plane normal) and
  lying ones, besides the PCA axes and their permutations; tapering has a small ``w_k k^2``.

Data term: pseudo-Huber of the radial distance, ``c^2 (sqrt(1 + (delta/c)^2) - 1)``, robust to
outliers and clustering errors. All (segment, initialisation) problems are one numpy batch:
parameters are kept in range by reparametrisation (sizes by a sigmoid in log space between
``size_bounds``, exponents ``e = 0.2 + 1.5 sigmoid`` in [0.2, 1.7] (Table 3.1), taper
``k = 0.99 tanh``, rotation ``R0 exp([w])``), optimised with Adam; the best initialisations of each
segment are refined further (cosine learning-rate decay) and the lowest total loss wins.

Deformations: tapering ``k`` is fitted (cones need ``k ~ -1``, truncated cones partial taper);
bending stays 0 here (none of the primitive types needs it, and the (identity) bending map would
double the inner loop's cost). ``deformable=False`` fixes ``k = 0`` too.

Cost: both stages run a fixed number of Adam steps over one batch, so the time hardly depends
on the number of segments: the per-op overhead of the small arrays dominates, not arithmetic.
The inner loop is therefore written for few ops: one optimised variable, Adam written out in
place, the radial distance in log space (no ``pow`` with array exponents), the points
pre-rotated into each initial frame, the support grid as one ``exp`` of precomputed logs, and
the gradient by the chain rule written out. It was torch with autograd; autograd's bookkeeping
took two thirds of each step and torch's per-op dispatch most of the rest (3.3 ms per step for
16 problems of 128 points in torch with autograd, 1.2 ms with the written-out gradient, about
0.6 ms in numpy float64). A unit test checks the gradient against finite differences.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.spatial import ConvexHull, QhullError
from scipy.special import expit, logit

from sqmanip.geometry import Superquadric
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


def world_part(params: np.ndarray, R: np.ndarray, t: np.ndarray, frame: _Frame) -> Superquadric:
    """A fitted row ``(a1 a2 a3 e1 e2 k ...)`` with its pose in the segment frame -> the world
    superquadric (rotation re-orthonormalised against round-off)."""
    p = np.asarray(params, dtype=np.float64)
    pose = np.eye(4)
    pose[:3, :3] = frame.R @ np.asarray(R, dtype=np.float64)
    pose[:3, 3] = frame.R @ np.asarray(t, dtype=np.float64) + frame.origin
    u, _, vt = np.linalg.svd(pose[:3, :3])
    pose[:3, :3] = u @ vt
    return Superquadric(
        (float(p[0]), float(p[1]), float(p[2])),
        (float(p[3]), float(p[4])),
        pose=pose,
        taper=float(p[5]),
    )


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


UNDER_MARGIN = 0.01
"""Seen points count as under a segment only this far (m) inside its footprint (sensor noise and
perspective put a few table points right at a top face's rim)."""
UNDER_MIN_POINTS = 3
"""A segment with fewer seen points than this under it rests on the support (stray points)."""


def rests_on_support(X: np.ndarray, seen: np.ndarray, contact: float) -> bool:
    """Does the segment ``X (P, 3)`` (support-plane frame, z up) stand on the support?

    Yes if its lowest point is within ``contact`` of the plane. Otherwise yes too if nothing was
    seen under it: no point of ``seen (M, 3)`` (the other segments and the support plane's
    points, same frame) lies below its lowest point inside its footprint (the convex hull of its
    points' x, y, eroded by ``UNDER_MARGIN``). Objects do not float: a flat box seen only from
    above (its top face 5 cm up, its sides hidden) must reach down to the table, while a
    bottle's neck (its body seen under it) or a mug's handle (the table seen through it) must not.
    """
    z_min = float(X[:, 2].min())
    if z_min < contact:
        return True
    q = seen[seen[:, 2] < z_min, :2]
    if len(q) < UNDER_MIN_POINTS:
        return True
    try:
        hull = ConvexHull(X[:, :2])
    except QhullError:  # a degenerate (edge-on) footprint has no inside to see anything in
        return True
    d = q @ hull.equations[:, :2].T + hull.equations[:, 2]  # signed distances to the edges
    return int((d <= -UNDER_MARGIN).all(-1).sum()) < UNDER_MIN_POINTS


BAND_Z_MIN = 0.004
"""Free-space samples on rays to the support stay this far (m) above it (plane-fit noise)."""
BELOW_PLANE = 0.05
"""``table`` points this far (m) below the support plane were seen past its edge."""
BAND_STEPS = 8
"""Samples per ray to a point below the plane, across the object's height band."""
BAND_MIN_GAP = 0.005
"""Those samples nearer than this (m) to a segment point are dropped (sensor noise)."""


def _free_space_samples(
    X: np.ndarray,
    eye: np.ndarray,
    table: np.ndarray | None,
    settings: PerceptionSettings,
    rng: np.random.Generator,
) -> np.ndarray:
    """Local points that the camera at local ``eye`` saw through: ``(F, 3)`` (may be empty).

    Three kinds: points just before the segment's own points along their rays; points 1-30 cm
    before ``table`` points on the support plane near the object; and, for ``table`` points
    seen below the plane (the floor past a table's edge), the stretch of their rays through the
    object's height band, nearest the segment first (what bounds an end overhanging the edge).
    """
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
        below = table[:, 2] < -BELOW_PLANE
        table, under = table[~below], table[below]
        near = table[np.linalg.norm(table[:, :2] - c[:2], axis=1) < radius + 0.15]
        if len(near):
            near = near[rng.choice(len(near), min(len(near), 8 * n_rays), replace=False)]
            u = near - eye
            u /= np.linalg.norm(u, axis=1, keepdims=True).clip(1e-9)
            steps = np.array([0.01, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3])
            q = (near[:, None, :] - steps[None, :, None] * u[:, None, :]).reshape(-1, 3)
            inside = (
                (np.linalg.norm(q[:, :2] - c[:2], axis=1) < radius)
                & (q[:, 2] > BAND_Z_MIN)
                & (q[:, 2] < height)
            )
            q = q[inside]
            if len(q) > n_rays * len(offsets):
                q = q[rng.choice(len(q), n_rays * len(offsets), replace=False)]
            samples.append(q)
        if len(under):
            limit = n_rays * len(offsets)
            q = _rays_through_band(under, eye, c[:2], radius, height, 16 * limit, rng)
            samples.append(_nearest_to(q, X, 2 * limit))
    return np.concatenate(samples)


def _nearest_to(q: np.ndarray, X: np.ndarray, n: int) -> np.ndarray:
    """The ``n`` samples ``q`` nearest the segment's points ``X`` (but not within
    ``BAND_MIN_GAP``): free space right next to the seen surface is what bounds the hidden
    extent (a box's end past a table edge); a sample 15 cm away constrains nothing."""
    if len(q) == 0:
        return q
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(X).query(q, k=1)
    order = np.argsort(np.where(dist < BAND_MIN_GAP, np.inf, dist), kind="stable")[:n]
    return q[order[np.isfinite(dist[order]) & (dist[order] >= BAND_MIN_GAP)]]


def _rays_through_band(
    ends: np.ndarray,
    eye: np.ndarray,
    centre: np.ndarray,
    radius: float,
    height: float,
    limit: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Points of the rays ``eye -> ends`` (local frame, ``z`` above the support; ``ends`` below
    it) inside the cylinder ``|xy - centre| < radius``, ``BAND_Z_MIN < z < height``; at most
    ``limit``. Each such ray crosses the band once, and the camera saw through that stretch.
    """
    d = ends - eye
    d = d[d[:, 2] < -1e-9]
    if not len(d):
        return np.zeros((0, 3))
    s_top = np.clip((height - eye[2]) / d[:, 2], 0.0, 1.0)  # ray parameter where z = height
    s_end = np.clip((BAND_Z_MIN - eye[2]) / d[:, 2], 0.0, 1.0)
    # keep rays whose band stretch comes near the object (segment-to-centre distance in xy)
    a = eye[:2] + s_top[:, None] * d[:, :2]
    b = eye[:2] + s_end[:, None] * d[:, :2]
    ab = b - a
    w = np.clip(((centre - a) * ab).sum(1) / (ab * ab).sum(1).clip(1e-12), 0.0, 1.0)
    near = (s_end > s_top) & (np.linalg.norm(a + w[:, None] * ab - centre, axis=1) < radius)
    idx = np.flatnonzero(near)
    if not len(idx):
        return np.zeros((0, 3))
    idx = idx[rng.choice(len(idx), min(len(idx), limit // BAND_STEPS + 1), replace=False)]
    f = (np.arange(BAND_STEPS) + 0.5) / BAND_STEPS
    s = s_top[idx, None] + f[None, :] * (s_end - s_top)[idx, None]  # (R, steps)
    q = (eye + s[..., None] * d[idx, None, :]).reshape(-1, 3)
    q = q[np.linalg.norm(q[:, :2] - centre, axis=1) < radius]
    if len(q) > limit:
        q = q[rng.choice(len(q), limit, replace=False)]
    return q


def tapered_radial_distance(x: np.ndarray, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Radial distance (3.3.4) of object-frame points ``x (B, N, 3)`` to tapered superellipsoids
    ``params (B, 9)`` (bending ignored), and the radial scale ``f^{e1/2}(D_t^{-1} x)`` (< 1 inside).

    The same value as :func:`sqmanip.geometry.radial_distance` for ``b = 0`` (a unit test checks
    it); see :func:`_log_radial` for how it is computed.
    """
    params = np.asarray(params, dtype=np.float64)
    a, e, k = params[:, 0:3], params[:, 3:5], params[:, 5:6]
    dist, log_scale, _ = _log_radial(np.asarray(x, dtype=np.float64), np.log(a), e, k)
    return dist, np.exp(log_scale)


def _logaddexp(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``log(exp(a) + exp(b))``, stable; numpy's own ufunc is ten times slower on small arrays."""
    top = np.maximum(a, b)
    return top + np.log1p(np.exp(-np.abs(a - b)))


def _log_radial(x: np.ndarray, log_a: np.ndarray, e: np.ndarray, k: np.ndarray):
    """Radial distance ``(B, N)``, ``log`` of the radial scale ``(B, N)`` and the vector-Jacobian
    product of the distance, for ``x (B, N, 3)``, half sizes ``exp(log_a) (B, 3)``, exponents
    ``e (B, 2)`` and taper ``k (B, 1)``.

    Written for the optimiser's inner loop, in log space: with ``l_i = log|x_i / (t_i a_i)|``
    (``t = k z / a3 + 1`` the taper (2.3.11) on x and y), ``log f = logaddexp((e2/e1)
    logaddexp(2 l_x / e2, 2 l_y / e2), 2 l_z / e1)`` (2.2.1) and the scale is ``f^{e1/2}``, so
    no power can overflow far from the shape (``logaddexp`` is stable). The radial distance
    (3.3.4) is ``|x| |1 - 1/scale|``.

    The third value maps ``dL/d dist (B, N)`` to ``dL/dx (B, N, 3)``, ``dL/d log_a (B, 3)``,
    ``dL/de (B, 2)`` and ``dL/dk (B, 1)``: the chain rule written out (a unit test checks it
    against finite differences).
    """
    e1, e2 = e[:, 0:1], e[:, 1:2]
    inv_az = np.exp(-log_a[:, 2:3])  # (B, 1)
    k_az = k * inv_az
    xz = x[..., 2]
    t_raw = xz * k_az + 1.0  # (B, N)
    log_t = np.log(np.maximum(t_raw, TAPER_MIN))
    p_xy, p_z = 2.0 / e2, 2.0 / e1
    expo = np.concatenate([p_xy, p_xy, p_z], -1)[:, None, :]  # (B, 1, 3)
    ax = np.abs(x)
    y = (np.log(np.maximum(ax, 1e-30)) - log_a[:, None, :]) * expo  # (B, N, 3)
    y0, y1, y2 = y[..., 0], y[..., 1], y[..., 2]
    l_xy = _logaddexp(y0, y1)
    inner = l_xy - log_t * p_xy
    ratio = e2 / e1
    A = inner * ratio
    Z = _logaddexp(A, y2)
    log_scale = Z * (0.5 * e1)
    norm = np.sqrt((x * x).sum(-1))
    m = 1.0 - np.exp(-log_scale)
    dist = norm * np.abs(m)

    def vjp(g_dist: np.ndarray):
        g_S = g_dist * norm * np.sign(m) * (1.0 - m)  # through |1 - exp(-S)|
        g_Z = g_S * (0.5 * e1)
        g_A = g_Z * np.exp(A - Z)  # logaddexp's softmax weights
        g_inner = g_A * ratio
        g_y0 = g_inner * np.exp(y0 - l_xy)
        g_y = np.stack([g_y0, g_inner - g_y0, g_Z - g_A], -1)  # (B, N, 3)
        g_l = g_y * expo  # d/d(log|x| - log a)
        gy_y = (g_y * y).sum(1)  # (B, 3): y = l p, so dL/dp = sum g_y y / p
        g_pxy = (gy_y[:, 0:1] + gy_y[:, 1:2]) / p_xy - (g_inner * log_t).sum(-1, keepdims=True)
        g_ratio = (g_A * inner).sum(-1, keepdims=True)
        g_e1 = 0.5 * (g_S * Z).sum(-1, keepdims=True) - (g_ratio * ratio + gy_y[:, 2:3]) / e1
        g_e2 = g_ratio / e1 - 2.0 * g_pxy / (e2 * e2)
        g_t = (g_inner * -p_xy) / t_raw * (t_raw > TAPER_MIN)  # through log t (clamped: 0)
        g_x = np.divide(g_l, x, out=np.zeros_like(g_l), where=ax >= 1e-30)
        g_x += (g_dist * np.abs(m) / np.maximum(norm, 1e-30))[..., None] * x
        g_x[..., 2] += g_t * k_az
        gt_z = (g_t * xz).sum(-1, keepdims=True)  # (B, 1)
        g_log_a = -g_l.sum(1)
        g_log_a[:, 2:3] -= gt_z * k_az
        return g_x, g_log_a, np.concatenate([g_e1, g_e2], -1), gt_z * inv_az

    return dist, log_scale, vjp


def _grid_constants() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constants of the support grid (2.2.2) on a fixed ``(eta, omega)`` grid of ``G`` points.

    ``signed_pow(cos eta, e1) signed_pow(cos omega, e2)`` is ``sign * exp(e1 L1 + e2 L2)`` with
    ``L = log|.|``, so the whole surface of a batch is one ``exp`` of an affine map of ``(e1, e2)``.
    Returns ``sign (G, 3)``, ``L1 (G, 3)`` and ``L2 (G, 3)``.
    """
    eta = np.linspace(-math.pi / 2, math.pi / 2, 7)
    omega = np.linspace(-math.pi, math.pi, 9)[:-1]
    E, W = (g.reshape(-1) for g in np.meshgrid(eta, omega, indexing="ij"))
    ce, se, cw, sw = np.cos(E), np.sin(E), np.cos(W), np.sin(W)
    sign = np.stack([np.sign(ce) * np.sign(cw), np.sign(ce) * np.sign(sw), np.sign(se)], 1)

    def log(v):
        return np.log(np.maximum(np.abs(v), 1e-30))

    zero = np.zeros_like(E)
    L1 = np.stack([log(ce), log(ce), log(se)], 1)
    L2 = np.stack([log(cw), log(sw), zero], 1)
    return sign, L1, L2


_GRID_SIGN, _GRID_L1, _GRID_L2 = _grid_constants()
_LEVI = np.zeros((3, 9))
"""``w @ _LEVI`` is the flattened skew matrix ``[w]`` (one op instead of a stack of nine)."""
for _i, _j, _k, _s in ((2, 1, 0, 1), (1, 2, 0, -1), (0, 2, 1, 1), (2, 0, 1, -1), (1, 0, 2, 1),
                       (0, 1, 2, -1)):  # fmt: skip
    _LEVI[_k, 3 * _i + _j] = _s
_EYE = np.eye(3)

# columns of the single optimised variable ``u (B, 12)``
_A, _E, _K, _W, _T = slice(0, 3), slice(3, 5), slice(5, 6), slice(6, 9), slice(9, 12)


def _so3_exp(w: np.ndarray):
    """Rodrigues' formula for ``w (B, 3)`` in few ops (the optimiser's inner loop), and its
    vector-Jacobian product ``dL/dE (B, 3, 3) -> dL/dw (B, 3)``.

    Same as :func:`sqmanip.geometry.so3_exp`; near ``w = 0`` the derivatives of ``sin t / t``
    and ``(1 - cos t) / t^2`` switch to their series.
    """
    K = (w @ _LEVI).reshape(-1, 3, 3)
    t2 = np.maximum((w * w).sum(-1), 1e-12)[:, None, None]
    t = np.sqrt(t2)
    sin, cos = np.sin(t), np.cos(t)
    alpha, beta = sin / t, (1 - cos) / t2
    KK = K @ K
    E = _EYE + alpha * K + beta * KK

    def vjp(g_E: np.ndarray) -> np.ndarray:
        Kt = K.transpose(0, 2, 1)
        g_K = alpha * g_E + beta * (g_E @ Kt + Kt @ g_E)
        small = t2 < 1e-2
        d_alpha = np.where(small, t2 / 60 - 1 / 6, (t * cos - sin) / (2 * t2 * t))
        d_beta = np.where(small, t2 / 360 - 1 / 24, (t * sin - 2 * (1 - cos)) / (2 * t2 * t2))
        g_t2 = (g_E * K).sum((1, 2)) * d_alpha[:, 0, 0] + (g_E * KK).sum((1, 2)) * d_beta[:, 0, 0]
        return g_K.reshape(-1, 9) @ _LEVI.T + (2.0 * g_t2)[:, None] * w

    return E, vjp


class _Batch:
    """``B`` problems: fixed initial rotations ``R0``, translations ``t0`` (local frame) and one
    unconstrained variable ``u (B, 12) = [u_a, u_e, u_k, w, u_t]`` mapped to parameters by
    ``a = exp(lo + (hi - lo) sigmoid(u_a))`` (log space, between ``size_bounds``),
    ``e = 0.2 + 1.5 sigmoid(u_e)``, ``k = 0.99 tanh(u_k)``, ``R = R0 exp([w])`` and
    ``t = t0 + T_SCALE R0 u_t`` (translation steps in the initial object frame).

    One variable (instead of five) keeps the optimiser to a handful of ops per step.
    """

    def __init__(self, R0, t0, a0, e0, lo: float, hi: float, deformable: bool):
        R0, t0, a0, e0 = (np.asarray(v, dtype=np.float64) for v in (R0, t0, a0, e0))
        B = R0.shape[0]
        self.R0 = R0
        self.t0_obj = (t0[:, None, :] @ R0)[:, 0]  # t0 in the initial object frame
        self.log_lo, self.log_span = math.log(lo), math.log(hi) - math.log(lo)
        frac = (np.log(np.clip(a0, lo * 1.01, hi * 0.99)) - self.log_lo) / self.log_span
        u = np.zeros((B, 12))
        u[:, _A] = logit(frac)
        u[:, _E] = logit((e0 - E_LO) / E_SPAN)
        self.u = u
        self.deformable = deformable
        self.k_mask = 1.0 if deformable else 0.0

    def select(self, idx: np.ndarray) -> _Batch:
        new = object.__new__(_Batch)
        new.R0, new.t0_obj = self.R0[idx], self.t0_obj[idx]
        new.log_lo, new.log_span = self.log_lo, self.log_span
        new.deformable, new.k_mask = self.deformable, self.k_mask
        new.u = self.u[idx].copy()
        return new

    def unpack(self, u: np.ndarray | None = None):
        """``params (B, 9)``, the rotation update ``E = exp([w])`` (``R = R0 E``) and the
        translation ``t_obj (B, 3)`` in the initial object frame (``t = R0 t_obj``)."""
        log_a, e, k, E, t_obj, _ = self.fields(self.u if u is None else u)
        params = np.concatenate([np.exp(log_a), e, k, np.zeros_like(log_a)], -1)  # no bending
        return params, E, t_obj

    def fields(self, u: np.ndarray):
        """``log a (B, 3)``, ``e (B, 2)``, ``k (B, 1)``, ``E (B, 3, 3)``, ``t_obj (B, 3)`` of
        ``u``, and the map from the gradients w.r.t. those five to the gradient w.r.t. ``u``."""
        s_ae = expit(u[:, 0:5])
        log_a = self.log_lo + self.log_span * s_ae[:, 0:3]
        e = E_LO + E_SPAN * s_ae[:, 3:5]
        k_scale = K_MAX * self.k_mask
        tanh_k = np.tanh(u[:, _K])
        E, so3_vjp = _so3_exp(u[:, _W])

        def vjp(g_log_a, g_e, g_k, g_E, g_t) -> np.ndarray:
            g_ae = np.concatenate([g_log_a * self.log_span, g_e * E_SPAN], 1)
            g_uk = g_k * (k_scale * (1.0 - tanh_k * tanh_k))
            return np.concatenate(
                [g_ae * s_ae * (1.0 - s_ae), g_uk, so3_vjp(g_E), T_SCALE * g_t], 1
            )

        return log_a, e, k_scale * tanh_k, E, self.t0_obj + T_SCALE * u[:, _T], vjp

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """``R (B, 3, 3)`` and ``t (B, 3)`` in the local frame."""
        _, E, t_obj = self.unpack()
        return self.R0 @ E, (self.R0 @ t_obj[:, :, None])[..., 0]


@dataclasses.dataclass
class _Data:
    X: np.ndarray  # (B, P, 3) observed points, local frame
    F: np.ndarray  # (B, Fm, 3) free-space samples, local frame
    Fw: np.ndarray  # (B, Fm) weights (0 = padding)
    contact: np.ndarray  # (B,) True if the segment rests on the plane
    has_plane: bool

    def select(self, idx: np.ndarray) -> _Data:
        return _Data(self.X[idx], self.F[idx], self.Fw[idx], self.contact[idx], self.has_plane)

    def subset(self, n_points: int, n_free: int, rng: np.random.Generator) -> _Data:
        """The same problems on random subsets of the points and free-space samples."""
        P, Fm = self.X.shape[1], self.F.shape[1]
        if n_points >= P and n_free >= Fm:
            return self
        pi = rng.permutation(P)[: min(n_points, P)]
        fi = rng.permutation(Fm)[: min(n_free, Fm)]
        return _Data(self.X[:, pi], self.F[:, fi], self.Fw[:, fi], self.contact, self.has_plane)


class _Problem:
    """Loss of a batch on fixed data, with everything that does not depend on ``u`` hoisted:
    the points in each initial object frame (``(x - t) R0 E = (x R0 - t_obj) E``), the
    free-space weights with their normaliser and the contact mask."""

    def __init__(self, batch: _Batch, data: _Data, settings: PerceptionSettings, amodal: bool):
        self.batch, self.settings, self.amodal = batch, settings, amodal
        self.n = data.X.shape[1]
        self.use_free = amodal and data.F.shape[1] > 0 and settings.free_space_weight > 0
        pts = np.concatenate([data.X, data.F], 1) if self.use_free else data.X
        self.P0 = pts @ batch.R0  # (B, N, 3) in the initial object frames
        self.P0t = np.ascontiguousarray(self.P0.transpose(0, 2, 1))
        norm = settings.free_space_weight / np.maximum(data.Fw.sum(-1, keepdims=True), 1.0)
        self.Fw = data.Fw * norm  # (B, Fm): padding 0, each problem's weights sum to w_f
        self.use_support = amodal and data.has_plane and settings.support_weight > 0
        self.contact = np.asarray(data.contact, dtype=bool)
        self.R0z = batch.R0[:, 2:3, :]  # (B, 1, 3) local z row of R0
        c = settings.huber_delta
        self.c, self.c2, self.inv_n = c, c * c, 1.0 / self.n

    def __call__(self, u: np.ndarray, data_only: bool = False, grad: bool = False):
        """Per-problem loss ``(B,)`` and the radial distances ``(B, P)`` of the points; with
        ``grad``, also the gradient of ``loss.sum()`` w.r.t. ``u (B, 12)``, by the chain rule
        written out (see :func:`_log_radial`; a unit test checks it against finite
        differences)."""
        s, n = self.settings, self.n
        log_a, e, k, E, t_obj, fields_vjp = self.batch.fields(u)
        local = self.P0 @ E - t_obj[:, None, :] @ E  # (P0 - t_obj) E
        dist, log_scale, radial_vjp = _log_radial(local, log_a, e, k)
        delta, d_free = dist[:, :n], dist[:, n:]
        # pseudo-Huber c^2 (sqrt(1 + (d/c)^2) - 1) = c sqrt(c^2 + d^2) - c^2
        root = np.sqrt(delta * delta + self.c2)
        loss = root.sum(-1) * (self.c * self.inv_n) - self.c2
        if self.batch.deformable:
            loss = loss + s.taper_weight * k[:, 0] ** 2
        amodal = self.amodal and not data_only
        free_w = None
        if amodal and self.use_free:
            free_w = (log_scale[:, n:] < 0.0) * self.Fw  # samples inside the shape
            loss = loss + (free_w * d_free * d_free).sum(-1)
        support = None
        if amodal and self.use_support:
            support = self._support(log_a, e, k, E, t_obj)
            loss = loss + s.support_weight * support[0] ** 2
        if not grad:
            return loss, delta

        g_dist = np.zeros_like(dist)
        g_dist[:, :n] = delta / root * (self.c * self.inv_n)
        if free_w is not None:
            g_dist[:, n:] = 2.0 * free_w * d_free
        g_x, g_log_a, g_e, g_k = radial_vjp(g_dist)
        if self.batch.deformable:
            g_k = g_k + 2.0 * s.taper_weight * k
        sum_gx = g_x.sum(1)  # (B, 3)
        g_E = self.P0t @ g_x - t_obj[:, :, None] * sum_gx[:, None, :]
        g_t = -(E @ sum_gx[:, :, None])[..., 0]
        if support is not None:
            gap, support_vjp = support
            g_log_a, g_e, g_k, g_E, g_t = support_vjp(
                2.0 * s.support_weight * gap, g_log_a, g_e, g_k, g_E, g_t
            )
        return loss, delta, fields_vjp(g_log_a, g_e, g_k, g_E, g_t)

    def _support(self, log_a, e, k, E, t_obj):
        """The support gap ``(B,)``: the lowest point of the surface grid (2.2.2, tapered by
        2.3.11) above the plane if the segment rests on it, else how far it goes below; and the
        map adding ``dL/dgap`` (through the lowest grid point) to the other gradients."""
        a = np.exp(log_a)  # (B, 3)
        expo = e[:, None, 0:1] * _GRID_L1 + e[:, None, 1:2] * _GRID_L2  # (B, G, 3)
        grid = _GRID_SIGN * np.exp(expo)  # unit-size grid
        sx, sy, sz = grid[..., 0], grid[..., 1], grid[..., 2]
        taper_raw = k * sz + 1.0  # D_t (2.3.11), z / a3 = sz
        taper = np.maximum(taper_raw, TAPER_MIN)
        row = (self.R0z @ E)[:, 0]  # (B, 3): local z row of R = R0 E
        r = row * a  # times the sizes
        height = (self.R0z[:, 0] * t_obj).sum(-1)  # (B,)
        z = (sx * r[:, 0:1] + sy * r[:, 1:2]) * taper + sz * r[:, 2:3] + height[:, None]
        rows = np.arange(len(z))
        j = z.argmin(-1)
        zmin = z[rows, j]
        gap = np.where(self.contact, zmin, np.maximum(-zmin, 0.0))

        def vjp(g_gap, g_log_a, g_e, g_k, g_E, g_t):
            g_z = (g_gap * np.where(self.contact, 1.0, -1.0 * (zmin < 0.0)))[:, None]
            gj = grid[rows, j]  # (B, 3): the lowest grid point
            tj = taper[rows, j][:, None]
            free_taper = taper_raw[rows, j][:, None] > TAPER_MIN
            g_taper = g_z * (gj[:, 0:1] * r[:, 0:1] + gj[:, 1:2] * r[:, 1:2]) * free_taper
            g_r = g_z * np.concatenate([gj[:, :2] * tj, gj[:, 2:3]], 1)
            g_grid = np.concatenate([g_z * r[:, :2] * tj, g_z * r[:, 2:3] + g_taper * k], 1)
            g_expo = g_grid * gj  # d exp(expo) = exp(expo) d expo
            g_e = g_e + np.stack(
                [(g_expo * _GRID_L1[j]).sum(-1), (g_expo * _GRID_L2[j]).sum(-1)], 1
            )
            g_log_a = g_log_a + g_r * row * a
            g_E = g_E + self.R0z.transpose(0, 2, 1) * (g_r * a)[:, None, :]
            g_t = g_t + g_z * self.R0z[:, 0]
            return g_log_a, g_e, g_k + g_taper * gj[:, 2:3], g_E, g_t

        return gap, vjp


def _optimise(problem: _Problem, steps: int, lr: float, lr_final: float) -> None:
    """Adam on ``problem.batch.u`` (in place) for ``steps`` steps, the learning rate following
    a cosine from ``lr`` to ``lr_final`` (large moves first, then settle in few steps).

    Written out on the single variable, with the problem's own gradient: a handful of in-place
    ops per step.
    """
    if steps <= 0:
        return
    b1, b2, eps = 0.9, 0.999, 1e-8
    u = problem.batch.u.copy()
    m = np.zeros_like(u)
    v = np.zeros_like(u)
    for i in range(steps):
        _, _, g = problem(u, grad=True)
        cos = 0.5 * (1 + math.cos(math.pi * i / max(steps - 1, 1)))
        lr_i = lr_final + (lr - lr_final) * cos
        m *= b1
        m += (1 - b1) * g
        v *= b2
        v += (1 - b2) * g * g
        bc1, bc2 = 1 - b1 ** (i + 1), 1 - b2 ** (i + 1)
        u -= (lr_i / bc1) * m / (np.sqrt(v / bc2) + eps)
    problem.batch.u = u


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

    ``plane``, ``viewpoint`` and ``table_points`` (world points of the removed support plane and
    points seen below it, :func:`_free_space_samples`)
    feed the amodal terms (module docstring); ``amodal=False`` is the plain DSQOpt fit.
    Deterministic for ``seed``.
    """
    settings = settings or PerceptionSettings()
    if not segments:
        return []
    check_equal_sizes(segments)
    return _fit(segments, plane, viewpoint, table_points, settings, amodal, deformable, seed)


def check_equal_sizes(segments: list[np.ndarray]) -> None:
    """The batched fit needs every segment resampled to the same number of points."""
    sizes = {len(s) for s in segments}
    if len(sizes) != 1:
        raise ValueError(f"segments must all have the same number of points, got {sorted(sizes)}")


def seen_around(segments: list[np.ndarray], i: int, table_points: np.ndarray | None) -> np.ndarray:
    """World points seen besides segment ``i``: the other segments and the support's points."""
    rest = [np.asarray(s, dtype=np.float64) for j, s in enumerate(segments) if j != i]
    if table_points is not None:
        rest.append(np.asarray(table_points, dtype=np.float64))
    return np.concatenate(rest) if rest else np.zeros((0, 3))


def _initial_problems(segments, plane, viewpoint, table_points, settings, amodal, deformable, seed):
    """One problem per (segment, initial orientation): the batch, its data (local frames), the
    segment of each problem and each segment's frame."""
    rng = np.random.default_rng(seed)
    use_plane = amodal and plane is not None
    lo, hi = settings.size_bounds

    R0s, t0s, a0s, Xs, Fs, contacts, owner, frames = [], [], [], [], [], [], [], []
    for si, seg in enumerate(segments):
        pts = np.asarray(seg, dtype=np.float64)
        frame = _frame(pts, plane if use_plane else None)
        frames.append(frame)
        X = frame.to_local(pts)
        contact = use_plane and rests_on_support(
            X, frame.to_local(seen_around(segments, si, table_points)), settings.support_contact
        )
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
            contacts.append(contact)
            owner.append(si)

    B = len(R0s)
    fmax = max(len(f) for f in Fs)
    Fpad = np.zeros((B, fmax, 3))
    Fw = np.zeros((B, fmax))
    for i, f in enumerate(Fs):
        Fpad[i, : len(f)] = f
        Fw[i, : len(f)] = 1.0
    data = _Data(np.stack(Xs), Fpad, Fw, np.array(contacts), use_plane)
    e0 = np.broadcast_to(np.asarray(settings.initial_shape, dtype=np.float64), (B, 2))
    batch = _Batch(np.stack(R0s), np.stack(t0s), np.stack(a0s), e0, lo, hi, deformable)
    return batch, data, np.array(owner), frames


def _fit(segments, plane, viewpoint, table_points, settings, amodal, deformable, seed):
    batch, data, owner, frames = _initial_problems(
        segments, plane, viewpoint, table_points, settings, amodal, deformable, seed
    )
    full_data = data
    # stage 1: every initialisation on a random subset of the points and free-space samples,
    # for a few steps only: enough to rank the initialisations of each segment
    rng = np.random.default_rng([seed, 1])
    small = data.subset(settings.select_points, settings.select_free_points, rng)
    problem = _Problem(batch, small, settings, amodal)
    _optimise(problem, settings.fit_iterations, settings.learning_rate, settings.learning_rate)
    loss, _ = problem(batch.u)
    # stage 2: the best initialisations of each segment, on more points
    keep = np.concatenate(
        [
            idx[np.argsort(loss[idx], kind="stable")[: settings.refine_keep]]
            for idx in (np.flatnonzero(owner == si) for si in range(len(segments)))
        ]
    )
    batch = batch.select(keep)
    data = data.select(keep).subset(settings.refine_points, settings.refine_free_points, rng)
    owner = owner[keep]
    problem = _Problem(batch, data, settings, amodal)
    lr2 = settings.refine_learning_rate
    _optimise(problem, settings.refine_iterations, lr2, lr2 * (1.0 - settings.lr_decay))
    loss, _ = problem(batch.u)
    params, _, _ = batch.unpack()
    R, t = batch.pose()
    # residual on all points of each segment
    _, delta = _Problem(batch, full_data.select(keep), settings, False)(batch.u, data_only=True)
    results = []
    for si in range(len(segments)):
        idx = np.flatnonzero(owner == si)
        best = int(idx[np.argmin(loss[idx])])
        part = world_part(params[best], R[best], t[best], frames[si])
        results.append(FitResult(part, float((delta[best] ** 2).mean()), float(loss[best])))
    return results
