"""The shelf, the target and the target pose set ``X`` (Ch. 5.3, 5.5, 5.6.3, C.2, C.3), plus
packed obstacle sets with a culled point-in-superquadric test shared by ``f_c``, ``g`` and the
action checks.

Frames: world z up, the shelf opening faces ``-x`` (the robot and the camera stand in front of it);
the layout matches :class:`sqmanip.sim.config.ShelfGeometry` (same field names and defaults) so the
simulator and the planner can share one :class:`ShelfSpec` (:meth:`ShelfSpec.from_geometry`).

Target pose set (5.3, 5.5, 5.6.3). An upright cylinder is rotationally symmetric, so ``X`` is an
``R^2`` grid of floor positions; a box target needs ``SE(2)``: the same grid times ``n_theta`` yaws
in ``[0, pi)`` (a box is symmetric under a half turn). The thesis does not state its resolution;
we use ``resolution = 2 cm`` (``f(x) = 1`` then means "the target can stand within about 1 cm of
``x``", the reading of 5.3) and 8 yaws (22.5 deg) for boxes. Grid positions keep the target's
horizontal bounding circle inside the side, back and front limits of the floor.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
import torch

from sqmanip.errors import ValidationError
from sqmanip.geometry import PinholeCamera, Superquadric, pack
from sqmanip.geometry.raycast import bound_box, bound_radius
from sqmanip.geometry.superquadric import implicit_homogeneous
from sqmanip.geometry.transforms import se2_matrix
from sqmanip.sim.config import ShelfGeometry

BOX_E = 0.2
"""Shape exponents of the box-like superquadrics of the shelf boards (C.3)."""


@dataclasses.dataclass(frozen=True)
class ShelfSpec:
    """Five-box shelf (C.3): bottom, top, back, left and right boards; opening towards ``-x``.

    ``front_x`` is the x of the opening, ``bottom_z`` the height of the floor (the bottom board's
    top face), ``inner_*`` the free space between the boards. Defaults equal the simulator's.
    """

    front_x: float = 0.50
    depth: float = 0.36
    inner_width: float = 0.70
    inner_height: float = 0.40
    bottom_z: float = 0.20
    thickness: float = 0.02

    def __post_init__(self) -> None:
        for name in ("depth", "inner_width", "inner_height", "thickness"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ValidationError(f"{name} must be finite and > 0, got {v!r}")
        for name in ("front_x", "bottom_z"):
            if not math.isfinite(float(getattr(self, name))):
                raise ValidationError(f"{name} must be finite, got {getattr(self, name)!r}")

    @classmethod
    def from_geometry(cls, geometry) -> ShelfSpec:
        """From any object with the same six fields (e.g. ``sim.config.ShelfGeometry``)."""
        return cls(**{f.name: float(getattr(geometry, f.name)) for f in dataclasses.fields(cls)})

    @property
    def floor_z(self) -> float:
        return self.bottom_z

    def board_boxes(
        self,
    ) -> list[tuple[str, tuple[float, float, float], tuple[float, float, float]]]:
        """``(name, half_extents, centre)`` of the five boards in the world frame (the
        simulator's own layout, so the search sees the boards the simulator builds)."""
        return ShelfGeometry(**dataclasses.asdict(self)).boxes()

    def boxes(self) -> list[Superquadric]:
        """The five boards as box-like superquadrics (``e1 = e2 = 0.2``, C.3)."""
        out = []
        for _, half, centre in self.board_boxes():
            pose = np.eye(4)
            pose[:3, 3] = centre
            out.append(Superquadric(size=half, shape=(BOX_E, BOX_E), pose=pose))
        return out

    def inner_bounds(self) -> np.ndarray:
        """``(2, 3)`` lower / upper corners of the free space inside the shelf."""
        return np.array(
            [
                [self.front_x, -self.inner_width / 2, self.bottom_z],
                [
                    self.front_x + self.depth,
                    self.inner_width / 2,
                    self.bottom_z + self.inner_height,
                ],
            ]
        )

    def camera(
        self,
        width: int = 1280,
        height: int = 720,
        *,
        distance: float = 0.40,
        elevation: float = 0.30,
        hfov_deg: float = 90.0,
    ) -> PinholeCamera:
        """The fixed front camera (Azure Kinect colour mode, 1280 x 720, 90 deg horizontal FOV):
        ``distance`` in front of the opening, ``elevation`` above the floor, looking at the
        centre of the floor a little above it."""
        f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
        eye = (self.front_x - distance, 0.0, self.bottom_z + elevation)
        target = (self.front_x + self.depth / 2, 0.0, self.bottom_z + 0.05)
        return PinholeCamera.look_at(
            eye,
            target,
            fx=f,
            fy=f,
            cx=(width - 1) / 2,
            cy=(height - 1) / 2,
            width=width,
            height=height,
        )


@dataclasses.dataclass(frozen=True)
class TargetSpec:
    """The known target: an upright cylinder (``R^2`` poses) or box (``SE(2)`` poses).

    ``size`` are superquadric half extents ``(a1, a2, a3)`` (for a cylinder ``a1 = a2 =`` radius,
    ``a3`` half the height); ``shape`` ``(e1, e2)``: flat caps ``e1 = 0.2`` and a round
    (``e2 = 1``) or square (``e2 = 0.2``) cross-section.
    """

    kind: Literal["cylinder", "box"] = "cylinder"
    size: tuple[float, float, float] = (0.03, 0.03, 0.06)
    shape: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("cylinder", "box"):
            raise ValidationError(f"kind must be 'cylinder' or 'box', got {self.kind!r}")
        if len(self.size) != 3 or not all(math.isfinite(v) and v > 0 for v in self.size):
            raise ValidationError(f"size must be three positive lengths, got {self.size!r}")
        if self.kind == "cylinder" and abs(self.size[0] - self.size[1]) > 1e-9:
            raise ValidationError(f"a cylinder needs size[0] == size[1], got {self.size!r}")
        if self.shape is None:
            object.__setattr__(self, "shape", (BOX_E, 1.0 if self.kind == "cylinder" else BOX_E))

    @classmethod
    def cylinder(cls, radius: float, height: float) -> TargetSpec:
        return cls("cylinder", (radius, radius, height / 2))

    @classmethod
    def box(cls, sx: float, sy: float, height: float) -> TargetSpec:
        return cls("box", (sx / 2, sy / 2, height / 2))

    @property
    def horizontal_radius(self) -> float:
        a1, a2, _ = self.size
        return a1 if self.kind == "cylinder" else math.hypot(a1, a2)

    def params(self, shrink: float = 0.0) -> np.ndarray:
        """Packed ``(9,)`` parameters, optionally every half extent reduced by ``shrink`` (m)."""
        a = [max(1e-4, v - shrink) for v in self.size]
        return np.array([*a, *self.shape, 0.0, 0.0, 0.0, 0.0])

    def superquadric(self, pose: np.ndarray | None = None) -> Superquadric:
        return Superquadric(
            size=tuple(self.size), shape=tuple(self.shape), pose=np.eye(4) if pose is None else pose
        )


@dataclasses.dataclass(frozen=True)
class PoseGrid:
    """The finite target pose set ``X`` (5.3): ``P`` upright target poses on the shelf floor.

    ``xy (P, 2)``, ``theta (P,)`` and the world poses ``(P, 4, 4)`` of the target's centre; the
    grid is ``shape = (n_x, n_y)`` or ``(n_x, n_y, n_theta)`` in C order (for plotting maps).
    """

    xy: torch.Tensor
    theta: torch.Tensor
    poses: torch.Tensor
    shape: tuple[int, ...]
    resolution: float

    def __len__(self) -> int:
        return self.xy.shape[0]

    def nearest(self, pose: np.ndarray | torch.Tensor) -> int:
        """Index of the grid pose nearest to a target pose ``(4, 4)`` (yaw folded mod pi)."""
        T = torch.as_tensor(np.asarray(pose), dtype=self.xy.dtype)
        if T.shape != (4, 4):
            raise ValidationError(f"pose must have shape (4, 4), got {tuple(T.shape)}")
        d = ((self.xy - T[:2, 3]) ** 2).sum(-1)
        if self.theta.numel() and float(self.theta.abs().max()) > 0:
            yaw = torch.atan2(T[1, 0], T[0, 0])
            dth = torch.remainder(self.theta - yaw + math.pi / 2, math.pi) - math.pi / 2
            d = d + (0.05 * dth) ** 2  # 1 rad ~ 5 cm
        return int(d.argmin())


def make_pose_grid(
    shelf: ShelfSpec,
    target: TargetSpec,
    resolution: float = 0.02,
    n_theta: int = 8,
    dtype: torch.dtype = torch.float32,
) -> PoseGrid:
    """The pose set ``X``: an ``R^2`` grid (cylinder) or ``SE(2)`` grid (box, ``n_theta`` yaws)."""
    if not (math.isfinite(resolution) and 0.002 <= resolution <= 0.2):
        raise ValidationError(f"resolution must be in [0.002, 0.2] m, got {resolution!r}")
    if target.kind == "box" and n_theta < 1:
        raise ValidationError(f"n_theta must be >= 1, got {n_theta!r}")
    m = target.horizontal_radius + 1e-3
    lo = np.array([shelf.front_x + m, -shelf.inner_width / 2 + m])
    hi = np.array([shelf.front_x + shelf.depth - m, shelf.inner_width / 2 - m])
    if np.any(hi < lo):
        raise ValidationError(f"target of radius {m:.3f} m does not fit on the shelf floor")
    axes = []
    for a, b in zip(lo, hi, strict=True):
        n = int(math.floor((b - a) / resolution + 1e-9)) + 1
        start = (a + b) / 2 - (n - 1) * resolution / 2  # centred in the free span
        axes.append(start + resolution * np.arange(n))
    gx, gy = np.meshgrid(axes[0], axes[1], indexing="ij")
    xy = np.stack([gx.ravel(), gy.ravel()], -1)
    shape: tuple[int, ...] = gx.shape
    if target.kind == "box":
        thetas = np.pi * np.arange(n_theta) / n_theta
        theta = np.tile(thetas, len(xy))
        xy = np.repeat(xy, n_theta, axis=0)
        shape = (*shape, n_theta)
    else:
        theta = np.zeros(len(xy))
    xy_t = torch.as_tensor(xy, dtype=dtype)
    th_t = torch.as_tensor(theta, dtype=dtype)
    poses = se2_matrix(th_t, xy_t[:, 0], xy_t[:, 1]).to(dtype)
    poses[:, 2, 3] = shelf.bottom_z + target.size[2]
    return PoseGrid(xy_t, th_t, poses, shape, float(resolution))


# --- packed obstacles and the culled point-in-superquadric test ---------------------------------


@dataclasses.dataclass(frozen=True)
class Obstacles:
    """``M`` posed superquadrics packed for :meth:`hits`: params, poses, inverse poses, kinds, and
    bounds (object-frame boxes ``|x| <= half`` containing each shape; a sphere's for bent shapes)."""

    params: torch.Tensor
    poses: torch.Tensor
    kinds: torch.Tensor
    inv: torch.Tensor
    half: torch.Tensor
    radius: torch.Tensor
    inner: torch.Tensor
    """(M, 3) half extents of a box certainly inside each shape (zeros when not known)."""

    def __len__(self) -> int:
        return self.params.shape[0]

    @classmethod
    def from_tensors(
        cls, params: torch.Tensor, poses: torch.Tensor, kinds: torch.Tensor
    ) -> Obstacles:
        m = params.shape[0]
        half = torch.zeros(m, 3, dtype=params.dtype)
        radius = torch.zeros(m, dtype=params.dtype)
        for kind in torch.unique(kinds).tolist():
            sel = kinds == kind
            box = bound_box(params[sel], int(kind))
            r = bound_radius(params[sel], int(kind))
            bent = params[sel, 6].abs() > 0
            half[sel] = torch.where(bent.unsqueeze(-1), r.unsqueeze(-1).expand_as(box), box)
            radius[sel] = r
        R, t = poses[:, :3, :3], poses[:, :3, 3]
        inv = torch.zeros_like(poses)
        inv[:, :3, :3] = R.transpose(-1, -2)
        inv[:, :3, 3] = -(R.transpose(-1, -2) @ t.unsqueeze(-1)).squeeze(-1)
        inv[:, 3, 3] = 1.0
        # undeformed superellipsoid: (s a1, s a2, s a3) is inside iff (2^{e2/e1} + 1) s^{2/e1} <= 1
        e1, e2 = params[:, 3].clamp(0.2, 1.7), params[:, 4].clamp(0.2, 1.7)
        s = (2.0 ** (e2 / e1) + 1.0) ** (-e1 / 2) * 0.999
        plain = (kinds == 0) & (params[:, 5].abs() == 0) & (params[:, 6].abs() == 0)
        inner = torch.where(plain.unsqueeze(-1), s.unsqueeze(-1) * params[:, :3].abs(), 0.0)
        return cls(params, poses, kinds.long(), inv, half, radius, inner)

    @classmethod
    def from_parts(
        cls, parts: Sequence[Superquadric], dtype: torch.dtype = torch.float32
    ) -> Obstacles:
        t = pack(list(parts), dtype=dtype)
        return cls.from_tensors(t.params, t.poses, t.kinds)

    @property
    def centers(self) -> torch.Tensor:
        return self.poses[:, :3, 3]

    def hits(
        self,
        base: torch.Tensor,
        base_centers: torch.Tensor,
        base_radii: torch.Tensor,
        group_poses: torch.Tensor,
        pairs: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Which obstacles each placed point set enters: ``(B, M)`` boolean, ``min_j S_m(x_j) <= 1``.

        The points of group ``b`` are ``group_poses[b] @ base`` with ``base (C, J, 3)`` split in
        ``C`` clusters bounded by spheres ``base_centers (C, 3)``, ``base_radii (C,)`` (see
        :func:`cluster_points`); ``group_poses (B, 4, 4)``. Exact for the points (C.2.10, C.3.11):
        a point outside an obstacle's bounding box has ``S > 1``, so only (cluster, obstacle)
        pairs whose sphere meets the box, and then only points inside the box, are evaluated.
        ``pairs (B, M)`` (optional) restricts the test to those pairs.
        """
        C, J, _ = base.shape
        B, M = group_poses.shape[0], len(self)
        out = torch.zeros(B, M, dtype=torch.bool)
        if B == 0 or M == 0 or C == 0 or J == 0:
            return out
        dt = self.params.dtype
        base, base_centers = base.to(dt), base_centers.to(dt)
        base_radii, group_poses = base_radii.to(dt), group_poses.to(dt)
        # group level: the sphere holding all clusters vs the obstacle's bounding sphere
        c0 = base_centers.mean(0)
        r0 = ((base_centers - c0).norm(dim=-1) + base_radii).amax()
        g_center = group_poses[:, :3, :3] @ c0 + group_poses[:, :3, 3]  # (B, 3)
        near = torch.cdist(g_center, self.centers) <= (r0 + self.radius).unsqueeze(0)
        if pairs is not None:
            near &= pairs
        bi, mi = near.nonzero(as_tuple=True)
        if bi.numel() == 0:
            return out
        A = self.inv[mi] @ group_poses[bi]  # (Q, 4, 4): base frame -> obstacle frame
        AR, At = A[:, :3, :3], A[:, :3, 3]
        # cluster level: sphere vs oriented bounding box; a cluster sphere inside the inner box
        # is a certain hit and its pair needs no point test
        qc = base_centers @ AR.transpose(-1, -2) + At.unsqueeze(1)  # (Q, C, 3)
        gap = (qc.abs() - self.half[mi].unsqueeze(1)).clamp_min(0).norm(dim=-1)
        sure = ((qc.abs() + base_radii.unsqueeze(-1)) <= self.inner[mi].unsqueeze(1)).all(-1)
        sure_q = sure.any(-1)
        out.view(-1).index_fill_(0, (bi * M + mi)[sure_q], True)
        test = (gap <= base_radii) & ~sure_q.unsqueeze(-1)
        q_idx, c_idx = test.nonzero(as_tuple=True)
        if q_idx.numel() == 0:
            return out
        local = base[c_idx] @ AR[q_idx].transpose(-1, -2) + At[q_idx].unsqueeze(1)  # (Q2, J, 3)
        m2 = mi[q_idx]
        la = local.abs()
        inside_box = (la <= self.half[m2].unsqueeze(1)).all(-1)  # (Q2, J)
        sure_p = (la <= self.inner[m2].unsqueeze(1)).all(-1).any(-1)  # (Q2,) certain hits
        pair = (bi * M + mi)[q_idx]
        out.view(-1).index_fill_(0, pair[sure_p], True)
        inside_box &= ~out.view(-1)[pair].unsqueeze(-1)
        r_idx, j_idx = inside_box.nonzero(as_tuple=True)
        if r_idx.numel() == 0:
            return out
        x = local[r_idx, j_idx]  # (E, 3)
        mm = m2[r_idx]
        hit = torch.zeros(x.shape[0], dtype=torch.bool)
        kinds = self.kinds[mm]
        for kind in torch.unique(kinds).tolist():
            sel = kinds == kind
            s = implicit_homogeneous(x[sel].unsqueeze(-2), self.params[mm[sel]], int(kind))
            hit[sel] = s.squeeze(-1) <= 1.0
        out.view(-1).index_fill_(0, pair[r_idx][hit], True)
        return out


def cluster_points(
    points: np.ndarray | torch.Tensor, n_clusters: int, dtype: torch.dtype = torch.float32
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Split ``points (J, 3)`` into about ``n_clusters`` (rounded down to a power of 2) compact
    clusters by recursive median splits along the widest axis.

    Returns ``clusters (C, J', 3)`` (short clusters padded by repeating their first point, which
    changes no test), their box centres ``(C, 3)`` and bounding radii ``(C,)``.
    """
    pts = torch.tensor(np.asarray(points), dtype=torch.float64)
    groups = [pts]
    levels = max(0, int(math.floor(math.log2(max(1, n_clusters)))))
    for _ in range(levels):
        nxt = []
        for g in groups:
            if g.shape[0] < 2:
                nxt.append(g)
                continue
            ax = int((g.amax(0) - g.amin(0)).argmax())
            order = g[:, ax].argsort()
            h = g.shape[0] // 2
            nxt += [g[order[:h]], g[order[h:]]]
        groups = nxt
    jmax = max(g.shape[0] for g in groups)
    out = torch.stack([torch.cat([g, g[:1].expand(jmax - g.shape[0], 3)]) for g in groups])
    centers = 0.5 * (out.amax(1) + out.amin(1))
    radii = (out - centers.unsqueeze(1)).norm(dim=-1).amax(1) + 1e-6
    return out.to(dtype), centers.to(dtype), radii.to(dtype)


@dataclasses.dataclass(frozen=True)
class SceneState:
    """The recognized objects ``s = {(q_i, T_i)}`` (5.4.1), packed: ``params (N, 9)``,
    ``poses (N, 4, 4)``, ``kinds (N,)``; one superquadric per object (Ch. 5)."""

    params: torch.Tensor
    poses: torch.Tensor
    kinds: torch.Tensor

    def __post_init__(self) -> None:
        n = self.params.shape[0]
        if self.params.shape != (n, 9) or self.poses.shape != (n, 4, 4) or self.kinds.shape != (n,):
            raise ValidationError(
                f"need params (N, 9), poses (N, 4, 4), kinds (N,), got {tuple(self.params.shape)}, "
                f"{tuple(self.poses.shape)}, {tuple(self.kinds.shape)}"
            )

    def __len__(self) -> int:
        return self.params.shape[0]

    @classmethod
    def from_objects(
        cls, objects: Sequence[Superquadric], dtype: torch.dtype = torch.float32
    ) -> SceneState:
        for o in objects:
            if not isinstance(o, Superquadric):
                raise ValidationError(
                    f"objects must hold Superquadric values, got {type(o).__name__}"
                )
        t = pack(list(objects), dtype=dtype)
        return cls(t.params, t.poses, t.kinds)

    def with_poses(self, poses: torch.Tensor) -> SceneState:
        return SceneState(self.params, poses.to(self.params.dtype), self.kinds)

    def with_pose(self, i: int, pose: torch.Tensor) -> SceneState:
        poses = self.poses.clone()
        poses[i] = pose.to(poses.dtype)
        return SceneState(self.params, poses, self.kinds)

    def without(self, i: int) -> SceneState:
        keep = torch.arange(len(self)) != i
        return SceneState(self.params[keep], self.poses[keep], self.kinds[keep])

    def obstacles(self) -> Obstacles:
        return Obstacles.from_tensors(self.params, self.poses, self.kinds)

    def objects(self) -> list[Superquadric]:
        from sqmanip.geometry.superquadric import KINDS

        out = []
        for p, T, k in zip(self.params.double(), self.poses.double(), self.kinds, strict=True):
            a = p.tolist()
            out.append(
                Superquadric(
                    size=(a[0], a[1], a[2]),
                    shape=(a[3], a[4]),
                    pose=T.numpy(),
                    kind=KINDS[int(k)],
                    taper=a[5],
                    bend=a[6],
                    bend_direction=a[7],
                    a4=a[8],
                )
            )
        return out
