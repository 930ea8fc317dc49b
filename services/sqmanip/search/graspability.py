"""Graspability ``g`` and its dense variant ``g_c,m`` (5.4.1, 5.4.3, Appendix C.3) over ``X``.

Candidate grasps of the target come from the rule-based generator of
:mod:`sqmanip.grasping.rule_based` with the C.3 preset: side grasps pitched 20 deg towards the
floor, antipodal width <= 7.5 cm, approaching into the shelf (+x). A cylinder can be grasped from
any side (5.6.3), so the generator runs on the target turned by a few yaws (``grasp_yaws_deg``)
and ``grasp_heights`` heights each: ``N_gr = 51`` by default, 17 approach directions 10 deg
apart at three heights (thesis: 10 to 30; see ``SearchConfig.grasp_yaws_deg``).

For a grasp ``T_k`` the robot approaches 30 cm along the gripper z axis; the "afterimage" of the
open gripper and links 6-7 over that approach is ``n_gr = 2048`` points
(:func:`sqmanip.grasping.gripper_points` with ``include_wrist`` and ``approach_distance``). With
``n_k(x)`` the number of obstacles (objects and the five shelf boards) entered by the afterimage of
grasp ``k`` for the target at ``x``:

- ``g(x) = g_c(x) = 1(min_k n_k(x) = 0)`` (C.3.11-C.3.12, C.3.14);
- ``g_c,m(x) = 1 - min_k n_k(x)`` (C.3.13, C.3.15): 1, 0, -1, ... used by the objective.

The candidate set is the same for every grid position (only its yaw matters), so the grasps of
pose ``x`` are ``x T_k``; the shelf's contribution ``n_k^shelf(x)`` is computed once and cached,
and per scene only the objects are tested.

Fast object test (voxel correlation). The candidate grasps of pose ``x`` are rigid translations of
the templates (for a cylinder only the position varies), so the afterimage points of template
``k`` at pose ``(ix, iy)`` are ``p_kj + (x0 + r_g ix, y0 + r_g iy, z_x)``. On a voxel lattice of
size ``h = r_g / n`` (``n = round(r_g / 5 mm)``, so ``h`` is 5 mm at the default 2 cm grid)
anchored at the first grid pose, the voxel of that point is exactly ``base_kj + n (ix, iy, 0)``
with the integer ``base_kj = floor(p_kj / h)`` precomputed once: collision over all grid poses is
a correlation of each object's occupancy with the template's voxel offsets, evaluated by gathers
at shifted integer indices. The grid's x axis is bit-packed (``occupancy[rx + n q, y, z]`` for
``q = 0..62`` in one ``uint64`` per residue ``rx``), so one gather and one shift answer a whole
row of poses, and the OR over the ``n_gr`` points is one ``bitwise_or.at``
(:class:`VoxelAfterimage`).

Approximation (documented, tested against the exact point test): a point is taken to collide
when the centre of its voxel lies in the object *inflated* by ``delta = 1.5 h sqrt(3) / 2``
(6.5 mm at ``h = 5 mm``): sizes ``a_i + delta`` with the exponents clamped to ``<= 1`` for a plain
superellipsoid (a pinched ``e > 1`` shape lies inside its ``e = 1`` one), the bounding box grown
by ``delta`` for any other shape. A point inside the object is within ``h sqrt(3) / 2`` of its
voxel centre; the normal offset of a convex superellipsoid by ``d`` lies inside the one with
sizes ``a_i + 1.5 d`` (checked on 400 random shapes with ``e <= 1``, sizes 1-7 cm: no
exception; with ``1.0 d`` boxes fail at the faces, with ``1.2 d`` thin ellipses fail), so the
test does not call a colliding grasp free; it calls a grasp colliding when its afterimage passes
within about ``delta + h`` (1.1 cm) of an object. ``tests/unit/search`` measures the agreement
with the exact test (>= 95 % of (pose, grasp) pairs) and the false-free count (0).
The shelf part stays exact (cached once with the culled point test).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from sqmanip.errors import ValidationError
from sqmanip.geometry.raycast import bound_box
from sqmanip.geometry.superquadric import SUPERELLIPSOID, implicit_homogeneous
from sqmanip.geometry.transforms import rot_z
from sqmanip.grasping import PANDA_HAND, GripperSpec, RuleOptions, gripper_points
from sqmanip.grasping.rule_based import rule_based_candidates

from .config import SearchConfig
from .shelf import Obstacles, PoseGrid, SceneState, ShelfSpec, TargetSpec, cluster_points


def target_grasps(
    target: TargetSpec,
    theta: float,
    config: SearchConfig,
    dtype: torch.dtype = torch.float32,
    source=None,
) -> torch.Tensor:
    """Candidate grasp poses ``(K, 4, 4)`` in the frame of a target at the origin with yaw 0,
    for the target turned by ``theta`` about z (C.3 rule; ``[]`` when none fits the gripper).
    ``source`` (``(object, RuleOptions) -> (G, 4, 4)``, e.g. :class:`.actions.GraspSource`)
    generates them; default in-process."""
    opt = RuleOptions(
        top_down=False,
        per_direction=config.grasp_heights,
        max_width=config.grasp_max_width,
        tilt=math.radians(config.grasp_tilt_deg),
        facing=(1.0, 0.0, 0.0),
        facing_angle=math.radians(config.facing_angle_deg),
    )
    yaws = config.grasp_yaws_deg if target.kind == "cylinder" else (0.0,)
    out = []
    Rth = rot_z(torch.tensor(theta, dtype=torch.float64))
    for yaw in yaws:
        R = rot_z(torch.tensor(theta + math.radians(yaw), dtype=torch.float64))
        pose = np.eye(4)
        pose[:3, :3] = R.numpy()
        if source is None:
            cand = rule_based_candidates([target.superquadric(pose)], options=opt)
            poses = cand.poses if len(cand) else None
        else:
            poses = source(target.superquadric(pose), opt)
            poses = poses if poses.shape[0] else None
        if poses is not None:
            T = poses.clone().double()
            T[:, :3, :] = Rth.T @ T[:, :3, :]  # into the frame of the target with yaw theta
            out.append(T)
    if not out:
        return torch.zeros(0, 4, 4, dtype=dtype)
    return torch.cat(out).to(dtype)


def gripper_corners(gripper: GripperSpec) -> torch.Tensor:
    """``(24, 3)`` corners of the open gripper's boxes (fingers, palm) in the gripper frame."""
    from sqmanip.grasping.gripper import gripper_boxes

    out = []
    for lo, hi in gripper_boxes(gripper):
        for sx in (lo[0], hi[0]):
            for sy in (lo[1], hi[1]):
                for sz in (lo[2], hi[2]):
                    out.append((sx, sy, sz))
    return torch.tensor(out, dtype=torch.float64)


INFLATE = 1.5
"""Objects are inflated by this times half the voxel diagonal (see the module doc)."""


class VoxelAfterimage:
    """Per-object afterimage collisions of every template grasp at every grid pose, by voxel
    correlation (see the module doc).

    ``grid_shape`` is ``(n_x, n_y)`` or ``(n_x, n_y, n_theta)``; ``points_rel (T, K, J, 3)`` are
    the afterimage points of template ``k`` for the grid yaw ``t``, relative to the first grid
    pose's horizontal position (so ``z`` is absolute); ``origin (2,)`` that position.
    """

    def __init__(
        self,
        points_rel: torch.Tensor,
        origin: torch.Tensor,
        grid_shape: tuple[int, ...],
        resolution: float,
        voxel: float = 0.005,
        inflate: float = INFLATE,
    ) -> None:
        if points_rel.ndim != 4 or points_rel.shape[-1] != 3:
            raise ValidationError(
                f"points_rel must have shape (T, K, J, 3), got {tuple(points_rel.shape)}"
            )
        self.n = max(1, round(resolution / voxel))
        self.h = resolution / self.n
        self.delta = inflate * self.h * math.sqrt(3.0) / 2.0
        self.origin = np.array([float(origin[0]), float(origin[1]), 0.0])
        self.nx, self.ny = int(grid_shape[0]), int(grid_shape[1])
        self.n_theta = int(grid_shape[2]) if len(grid_shape) > 2 else 1
        if self.nx > 64:
            raise ValidationError(f"grid has {self.nx} x steps; at most 64 fit one packed word")
        T, K, J, _ = points_rel.shape
        if self.n_theta != T:
            raise ValidationError(f"points_rel has {T} yaws, the grid {self.n_theta}")
        self.K = K
        base = np.floor(points_rel.double().numpy() / self.h).astype(np.int64)  # (T, K, J, 3)
        tk = np.broadcast_to(np.arange(T * K).reshape(T, K, 1), (T, K, J))
        # one voxel per (template, point): duplicates change no OR
        flat = np.concatenate([tk.reshape(-1, 1), base.reshape(-1, 3)], 1)
        flat = np.unique(flat, axis=0)
        # two orders, by template then descending x (or y): the first pose row a point can
        # reach along that axis is then non-decreasing, so equal rows form contiguous runs
        self._orders = []
        for axis in (0, 1):
            o = np.lexsort((-flat[:, 1 + axis], flat[:, 0]))
            self._orders.append(
                (np.ascontiguousarray(flat[o, 0]), np.ascontiguousarray(flat[o, 1:]))
            )
        self.tk, self.base = self._orders[0]

    def occupancy(
        self, params: torch.Tensor, pose: torch.Tensor, kind: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Conservative occupancy of one posed superquadric on the lattice: ``(lo (3,), occ
        (Dx, Dy, Dz) bool)`` with ``lo`` the integer voxel of ``occ[0, 0, 0]``."""
        p = params.double()
        T = pose.double()
        plain = kind == SUPERELLIPSOID and float(p[5].abs()) == 0 and float(p[6].abs()) == 0
        half = bound_box(p, kind)
        ext = (T[:3, :3].abs() @ half).numpy() + self.delta
        c = T[:3, 3].numpy()
        lo = np.floor((c - ext - self.origin) / self.h).astype(np.int64)
        hi = np.floor((c + ext - self.origin) / self.h).astype(np.int64) + 1
        axes = [self.origin[i] + (np.arange(lo[i], hi[i]) + 0.5) * self.h for i in range(3)]
        Rn = T[:3, :3].numpy()
        if plain and abs(Rn[2, 2]) > 1 - 1e-9:
            # upright (object z = +-world z): the implicit separates into an (x, y) and a z part
            a = p[:3].abs().numpy() + self.delta
            e1, e2 = (min(1.0, max(0.2, float(v))) for v in p[3:5])
            dx, dy = axes[0] - c[0], axes[1] - c[1]
            lx = dx[:, None] * Rn[0, 0] + dy[None, :] * Rn[1, 0]
            ly = dx[:, None] * Rn[0, 1] + dy[None, :] * Rn[1, 1]
            lz = axes[2] - c[2]
            xy = (np.abs(lx / a[0]) ** (2 / e2) + np.abs(ly / a[1]) ** (2 / e2)) ** (e2 / e1)
            zz = np.abs(lz / a[2]) ** (2 / e1)
            return lo, (xy[:, :, None] + zz[None, None, :]) <= 1.0
        g = torch.stack(
            torch.meshgrid(*(torch.as_tensor(x) for x in axes), indexing="ij"), -1
        )  # (Dx, Dy, Dz, 3)
        local = (g.reshape(-1, 3) - T[:3, 3]) @ T[:3, :3]  # world -> object frame
        if plain:
            q = p.clone()
            q[:3] = q[:3].abs() + self.delta
            q[3:5] = q[3:5].clamp(max=1.0)  # a pinched (e > 1) shape lies inside its e = 1 one
            inside = implicit_homogeneous(local.unsqueeze(0), q.unsqueeze(0), SUPERELLIPSOID)[0]
            occ = inside <= 1.0
        else:  # any other shape: its bounding box grown by delta
            occ = (local.abs() <= half + self.delta).all(-1)
        return lo, occ.reshape(g.shape[:3]).numpy()

    def hits(self, params: torch.Tensor, pose: torch.Tensor, kind: int) -> torch.Tensor:
        """``(P, K)`` bool: the afterimage of template ``k`` at grid pose ``p`` enters the object
        (conservatively, see the module doc). ``P = n_x n_y n_theta`` in the grid's order.

        The grid axis along which the object is longer (in voxels) is bit-packed, the other one
        (``e``) is expanded: the work is about (afterimage points near the object) x (object
        width in grid steps along ``e``)."""
        lo, occ = self.occupancy(params, pose, kind)
        n, nth, K = self.n, self.n_theta, self.K
        n_pose = [self.nx, self.ny]
        pk = 0 if occ.shape[0] >= occ.shape[1] else 1  # packed axis
        ex = 1 - pk
        tk, base = self._orders[ex]
        b = base - lo  # point voxel relative to the object box, at grid pose (0, 0)
        if pk == 1:
            occ = occ.transpose(1, 0, 2)
            b = b[:, [1, 0, 2]]
        npk, nex = n_pose[pk], n_pose[ex]
        Dp, De, Dz = occ.shape
        keep = (b[:, 2] >= 0) & (b[:, 2] < Dz)
        keep &= (b[:, 0] < Dp) & (b[:, 0] + n * (npk - 1) >= 0)
        keep &= (b[:, 1] < De) & (b[:, 1] + n * (nex - 1) >= 0)
        b, tk = b[keep], tk[keep]
        span = -(-De // n) + 1  # rows j of the expanded axis one point can meet
        width = nex + span  # output rows per template, padded so no row index is clipped
        out = np.zeros((nth * K * width,), dtype=np.uint64)
        if b.shape[0]:
            r = np.mod(b[:, 0], n)
            s = (b[:, 0] - r) // n  # pose i (packed axis) reads bit i + s of the residue-r word
            j0 = np.maximum(0, -np.floor_divide(b[:, 1], n))  # first row with b_e + n j >= 0
            dst0 = tk * width + j0  # non-decreasing (see __init__)
            starts = np.flatnonzero(np.r_[True, dst0[1:] != dst0[:-1]])
            rows = dst0[starts]
            steps = np.arange(span)
            chunk = 64 - npk  # bit q of a word sits at q + npk, so every shift is >= 0
            nq = -(-Dp // n)
            pad = n * span  # zero rows past the box along e: reads there give 0
            for q0 in range(0, nq, chunk):
                packed = np.zeros((n, De + pad, Dz), dtype=np.uint64)
                for res in range(n):
                    sl = occ[res + n * q0 : res + n * (q0 + chunk) : n]
                    if sl.shape[0]:
                        w = np.uint64(1) << (
                            np.arange(sl.shape[0], dtype=np.uint64) + np.uint64(npk)
                        )
                        packed[res, :De] = np.bitwise_or.reduce(
                            np.where(sl, w[:, None, None], np.uint64(0)), axis=0
                        )
                sq = s - q0 + npk  # in [0, 64) wherever the window overlaps this chunk
                ok = (sq >= 0) & (sq < 64)
                src0 = (r * (De + pad) + b[:, 1] + n * j0) * Dz + b[:, 2]
                src0 = np.where(ok, src0, 0)
                shift = np.where(ok, sq, 64 - 1).astype(np.uint64)
                words = packed.ravel().take(src0[:, None] + (n * Dz) * steps) >> shift[:, None]
                words[~ok] = 0
                red = np.bitwise_or.reduceat(words, starts, axis=0)  # (runs, span)
                for j in range(span):
                    out[rows + j] |= red[:, j]
        # unpack: bit i of out[t, k, j] -> hit at packed index i, expanded index j
        out = out.reshape(nth * K, width)[:, :nex]
        bits = (out[..., None] >> np.arange(npk, dtype=np.uint64)) & np.uint64(1)
        hit = bits.astype(bool).reshape(nth, K, nex, npk)
        hit = hit.transpose(3, 2, 0, 1) if pk == 0 else hit.transpose(2, 3, 0, 1)  # (ix, iy, t, k)
        return torch.from_numpy(np.ascontiguousarray(hit).reshape(-1, K))


class GraspabilityModel:
    """``g`` and ``g_c,m`` over a pose grid (C.3), with the shelf part cached."""

    def __init__(
        self,
        shelf: ShelfSpec,
        target: TargetSpec,
        grid: PoseGrid,
        config: SearchConfig | None = None,
        gripper: GripperSpec = PANDA_HAND,
        grasp_source=None,
    ) -> None:
        """``grasp_source``: generator of the target's C.3 candidates (see :func:`target_grasps`)."""
        self.shelf, self.target, self.grid = shelf, target, grid
        self.config = cfg = config or SearchConfig()
        self.gripper = gripper
        self.dtype = grid.poses.dtype
        # afterimage of the open gripper + links 6-7 over the 30 cm approach (C.3.11)
        pts = gripper_points(
            gripper,
            cfg.n_gripper_points,
            include_wrist=True,
            approach_distance=cfg.approach_distance,
        )
        self.points, self.point_centers, self.point_radii = cluster_points(pts, 64, self.dtype)
        # candidates per distinct yaw of the grid, in the frame of the target (translation only)
        thetas = torch.unique(grid.theta)
        sets = [target_grasps(target, float(t), cfg, self.dtype, grasp_source) for t in thetas]
        k_max = max((len(s) for s in sets), default=0)
        self.n_candidates = k_max
        self.local_grasps = torch.zeros(len(thetas), k_max, 4, 4, dtype=self.dtype)
        self.local_valid = torch.zeros(len(thetas), k_max, dtype=torch.bool)
        for i, s in enumerate(sets):
            self.local_grasps[i, : len(s)] = s
            self.local_valid[i, : len(s)] = True
            self.local_grasps[i, len(s) :] = torch.eye(4, dtype=self.dtype)
        # fingers must clear the floor board: a grasp whose open gripper reaches within
        # floor_clearance of the floor is dropped (the point test, with points ~1 cm apart, and
        # the robot's collision margin would disagree there)
        if k_max:
            corners = gripper_corners(gripper)  # (C, 3)
            z = (corners @ self.local_grasps[..., :3, :3].transpose(-1, -2).double())[..., 2]
            z = z + self.local_grasps[..., None, 2, 3].double() + target.size[2]
            self.local_valid &= z.amin(-1) >= cfg.floor_clearance
        self._theta_index = torch.searchsorted(thetas, grid.theta)
        shelf_obs = Obstacles.from_parts(shelf.boxes(), self.dtype)
        self.n_shelf = self._counts(shelf_obs, torch.arange(len(grid)))  # (P, K) int
        # voxel correlation for the objects: template afterimages relative to the first pose
        n_th = len(thetas)
        rep = self.grid.poses[:n_th].double()  # poses (0, 0, t) of each yaw t
        G = rep.unsqueeze(1) @ self.local_grasps.double()  # (T, K, 4, 4)
        raw = torch.tensor(np.asarray(pts), dtype=torch.float64)
        world = raw @ G[..., :3, :3].transpose(-1, -2) + G[..., None, :3, 3]  # (T, K, J, 3)
        world[..., :2] -= rep[0, :2, 3]
        self.voxels = (
            VoxelAfterimage(world, rep[0, :2, 3], grid.shape, grid.resolution, cfg.grasp_voxel)
            if self.n_candidates
            else None
        )

    def grasp_poses(self, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World grasp poses ``(len(idx), K, 4, 4)`` of grid poses ``idx`` and their validity."""
        ti = self._theta_index[idx]
        T = self.grid.poses[idx].unsqueeze(1) @ self.local_grasps[ti]
        return T, self.local_valid[ti]

    def object_hits(self, scene: SceneState, i: int) -> torch.Tensor:
        """``(P, K)`` bool: afterimages entering object ``i`` of ``scene`` at every grid pose
        (voxel correlation, conservative; see the module doc)."""
        if self.voxels is None:
            return torch.zeros(len(self.grid), 0, dtype=torch.bool)
        return self.voxels.hits(scene.params[i], scene.poses[i], int(scene.kinds[i]))

    def exact_counts(self, scene: SceneState, idx: torch.Tensor) -> torch.Tensor:
        """``(len(idx), K)`` obstacle counts with the exact point test (objects and shelf)."""
        return self.n_shelf[idx] + self._counts(scene.obstacles(), idx)

    def _counts(self, obstacles: Obstacles, idx: torch.Tensor) -> torch.Tensor:
        """``(len(idx), K)`` number of obstacles each candidate's afterimage enters."""
        K = self.n_candidates
        if K == 0 or idx.numel() == 0 or len(obstacles) == 0:
            return torch.zeros(idx.numel(), K, dtype=torch.long)
        T, _ = self.grasp_poses(idx)
        hit = obstacles.hits(self.points, self.point_centers, self.point_radii, T.reshape(-1, 4, 4))
        return hit.sum(-1).reshape(idx.numel(), K)

    def evaluate(
        self, scene: SceneState, mask: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(g, g_m, best)`` over the grid: ``g (P,)`` in {0, 1}, ``g_m (P,)`` in {1, 0, -1, ...}
        (C.3.13) and the index of the grasp with the fewest collisions ``best (P,)`` (-1 if none).

        Only poses in ``mask`` are evaluated (the objective needs ``g`` where ``f = 1``, 5.3);
        elsewhere ``g = 0``, ``g_m = 1 - (N + 5)`` (every obstacle counted) and ``best = -1``.
        """
        P = len(self.grid)
        n_obs = len(scene) + 5
        g_m = torch.full((P,), float(1 - n_obs), dtype=self.dtype)
        best = torch.full((P,), -1, dtype=torch.long)
        m = torch.ones(P, dtype=torch.bool) if mask is None else mask.bool()
        idx = m.nonzero().squeeze(-1)
        if idx.numel() and self.n_candidates:
            n = self.n_shelf[idx].clone()
            for i in range(len(scene)):
                n += self.object_hits(scene, i)[idx].long()
            valid = self.local_valid[self._theta_index[idx]]
            n = torch.where(valid, n, torch.full_like(n, n_obs))
            n_min, k = n.min(-1)
            g_m[idx] = (1 - n_min).to(self.dtype)
            best[idx] = torch.where(n_min < n_obs, k, torch.full_like(k, -1))
        g = (g_m >= 1.0).to(self.dtype)
        return g, g_m, best
