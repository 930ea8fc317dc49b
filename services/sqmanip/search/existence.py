"""Existence function ``f = f_d f_c`` (5.4.1, Appendix C.2), batched over the pose set ``X``.

``f_c(x) = 1(min_{i,j} S_i(x_j^o) > 1)`` (C.2.10) with ``n_o = 512`` target surface points against
every recognized object and the five shelf boards. The boards never move, so their part is
computed once per (shelf, target, grid) and cached (exact point test). Per scene the objects are
tested by the voxel correlation of :class:`.graspability.VoxelAfterimage` (the target's points
at every grid pose are translations of one set, so one gather per point and row of poses),
without inflation: a point collides when the centre of its 5 mm voxel is inside the object, so
the answer is exact up to half a voxel (:meth:`collision_free` keeps the exact culled point test
of :meth:`Obstacles.hits` as the reference; the tests compare the two).

``f_d(x) = 1`` iff the depth images (C.2.5-C.2.8, ``p = 1000``, ``tau = 100``,
``[t_n, t_f] = [0, 1.5]``) rendered with and without the target at ``x`` are "identical" on the
target's own pixels -- the pixels whose ray meets the hypothesised target, i.e. where it would be
visible if nothing hid it. The C.2 test is an MSE below 0.001; taken over the whole image
(``W H`` = 18,849 pixels) it accepts a target that is mostly in plain view (a 5 x 10 cm target
covers ~1 % of the image), so the mean is over the target's pixels instead, and a hypothesis is
also rejected when more than ``found_pixels = 100`` camera pixels (5.5.1's detection criterion;
one render pixel is ``1 / render_scale^2`` = 49 camera pixels) would see it nearer, by more than
``seen_margin``, than the objects: the target would have been found there. The fast path computes
it with three exact reductions:

1. pixels whose ray misses the target's bounding box have identical depth with and without the
   target (the ray samples and the integrand are unchanged there): only the target's footprint
   matters, and the footprint is also the denominator of the mean;
2. ``f_d`` matters only where ``f_c = 1`` (``f = f_d f_c``), i.e. where the target does not
   intersect any object; along a ray the occupancy of the union is then that of two disjoint
   sets, and the depth with the target is ``min(D_0, D_T)`` -- ``D_0`` the depth of the objects,
   ``D_T`` that of the target alone (exact in the hard limit; the soft render differs by less
   than ``exp(-tau * thickness) / tau``, i.e. by nothing at 1 cm thickness and ``tau = 100``);
3. ``D_T`` on the footprint of every grid pose depends on the camera, target and grid only, so it
   is rendered once and cached; per scene only ``D_0`` on the union of the footprints is rendered
   (with C.2.9 ellipsoid culling: a ray integrates only the objects whose ellipsoid it meets).

Then, with ``Q(x)`` the footprint of ``x`` and ``e = relu(D_0 - D_T(x))``:
``f_d(x) = 1(sum_Q e^2 / |Q| < 0.001) * 1(#{e > seen_margin} / render_scale^2 <= 100)``
(:func:`depth_condition`). :func:`existence_reference` is the same test on full renders with
:func:`sqmanip.geometry.render.render_depth`, one scene per candidate pose (the tests check the
fast path against it).

``c = 1`` (the target is seen): ``f`` is 1 at the grid pose nearest the observed target pose only.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from sqmanip.errors import ValidationError
from sqmanip.geometry import PinholeCamera
from sqmanip.geometry.render import bound_ellipsoid, render_depth
from sqmanip.geometry.sampling import sample_surface
from sqmanip.geometry.superquadric import SUPERELLIPSOID, implicit_homogeneous

from .config import SearchConfig
from .shelf import Obstacles, PoseGrid, SceneState, ShelfSpec, TargetSpec, cluster_points


def _box_chords(o: torch.Tensor, d: torch.Tensor, half: torch.Tensor):
    """Slab test: ``t`` interval of rays ``o + t d`` (``(..., 3)``) in the box ``|x| <= half``."""
    inv = 1.0 / torch.where(d.abs() < 1e-12, torch.full_like(d, 1e-12), d)
    ta, tb = (-half - o) * inv, (half - o) * inv
    t0 = torch.minimum(ta, tb).amax(-1)
    t1 = torch.maximum(ta, tb).amin(-1)
    return t0, t1, t1 > t0


def _ellipsoid_chords(o: torch.Tensor, d: torch.Tensor, axes: torch.Tensor):
    """``t`` interval of rays in the ellipsoid ``E <= 1`` with semi-axes ``axes`` (C.2.9)."""
    o, d = o / axes, d / axes
    dd = (d * d).sum(-1).clamp_min(1e-30)
    od = (o * d).sum(-1)
    disc = od * od - dd * ((o * o).sum(-1) - 1.0)
    root = disc.clamp_min(0).sqrt()
    return (-od - root) / dd, (-od + root) / dd, disc > 0


def soft_depth_on_chords(
    values: torch.Tensor, entry: torch.Tensor, exit_: torch.Tensor, cfg: SearchConfig
) -> torch.Tensor:
    """Soft depth (C.2.6-C.2.8) of rays sampled at ``n`` interval midpoints of ``[entry, exit]``.

    ``values (R, n)`` are ``F = min_i S_i`` at those samples; occupancy is taken constant on each
    interval so the transmittance is integrated exactly there (as in ``geometry.render``).
    """
    n = values.shape[-1]
    dt = ((exit_ - entry) / n).unsqueeze(-1)
    V = torch.sigmoid(cfg.sharpness * (1.0 - values.clamp_max(1e6)))
    x_opt = cfg.tau * V * dt
    A = torch.exp(-torch.cumsum(x_opt, -1))
    A_before = torch.cat([torch.ones_like(A[:, :1]), A[:, :-1]], -1)
    phi = torch.where(x_opt > 1e-6, -torch.expm1(-x_opt) / x_opt.clamp_min(1e-6), 1 - 0.5 * x_opt)
    inside = (A_before * phi).sum(-1) * dt.squeeze(-1)
    return (entry + inside + A[:, -1] * (cfg.t_far - exit_)).clamp(cfg.t_near, cfg.t_far)


def depth_condition(
    pose: torch.Tensor,
    d0: torch.Tensor,
    d_t: torch.Tensor,
    n_foot: torch.Tensor,
    cfg: SearchConfig,
    pixel_area: float,
) -> torch.Tensor:
    """``f_d (P,)`` as bool from the target's footprint entries (see the module doc).

    ``pose (Q,)`` grid pose of each entry, ``d0 (Q,)`` depth without the target, ``d_t (Q,)``
    depth of the target alone, ``n_foot (P,)`` footprint size of every pose (the mean's
    denominator), ``pixel_area`` camera pixels per render pixel. A pose with no footprint
    (never in view) passes."""
    P = n_foot.shape[0]
    e = (d0 - d_t).clamp_min(0)
    sse = torch.zeros(P, dtype=e.dtype).index_add_(0, pose, e * e)
    seen = torch.zeros(P, dtype=e.dtype).index_add_(0, pose, (e > cfg.seen_margin).to(e.dtype))
    mse = sse / n_foot.clamp_min(1).to(e.dtype)
    return (mse < cfg.mse_threshold) & (seen * pixel_area <= cfg.found_pixels)


@dataclasses.dataclass
class _Footprints:
    pose: torch.Tensor  # (Q,) grid pose index
    pixel: torch.Tensor  # (Q,) flat pixel index
    depth: torch.Tensor  # (Q,) target-alone soft depth D_T


class ExistenceModel:
    """``f``, ``f_d`` and ``f_c`` over a pose grid (C.2), with the scene-independent parts cached."""

    def __init__(
        self,
        shelf: ShelfSpec,
        target: TargetSpec,
        grid: PoseGrid,
        camera: PinholeCamera,
        config: SearchConfig | None = None,
    ) -> None:
        self.shelf, self.target, self.grid = shelf, target, grid
        self.config = cfg = config or SearchConfig()
        self.camera = camera.scaled(cfg.render_scale) if cfg.render_scale != 1.0 else camera
        self.dtype = grid.poses.dtype
        origin, dirs = self.camera.rays(self.dtype)
        self._origin, self._dirs = origin, dirs.reshape(-1, 3)
        self.n_pixels = self.camera.width * self.camera.height
        self.pixel_area = camera.width * camera.height / self.n_pixels
        """Camera pixels per render pixel (``1 / render_scale^2``)."""

        # f_c: target surface points (shrunk, C.2.10) in clusters, and the shelf part once; the
        # objects are tested with the target shrunk by object_tolerance more (their shapes are
        # recognized, the shelf's are known)
        def surface(shrink: float):
            pts, _ = sample_surface(
                torch.as_tensor(target.params(shrink), dtype=torch.float64),
                cfg.n_target_points,
                generator=cfg.seed,
            )
            return cluster_points(pts, 8, self.dtype)

        shelf_pts = surface(cfg.fc_shrink)
        self.points, self.point_centers, self.point_radii = surface(
            cfg.fc_shrink + cfg.object_tolerance
        )
        shelf_obs = Obstacles.from_parts(shelf.boxes(), self.dtype)
        self.fc_shelf = ~shelf_obs.hits(*shelf_pts, grid.poses).any(-1)
        self._foot = self._target_footprints()
        self.n_foot = torch.bincount(self._foot.pose, minlength=len(grid))
        """``(P,)`` render pixels on which the target at each grid pose would be visible."""
        # fast f_c: the target points are translations of one set per yaw, as the grasps of g
        from .graspability import VoxelAfterimage

        n_th = len(torch.unique(grid.theta))
        rep = grid.poses[:n_th].double()
        raw = self.points.reshape(-1, 3).double()
        world = raw @ rep[:, :3, :3].transpose(-1, -2) + rep[:, None, :3, 3]  # (T, J, 3)
        world[..., :2] -= rep[0, :2, 3]
        self.voxels = VoxelAfterimage(
            world.unsqueeze(1), rep[0, :2, 3], grid.shape, grid.resolution, cfg.grasp_voxel, 0.0
        )

    # --- caches -------------------------------------------------------------------------------

    def _target_footprints(self) -> _Footprints:
        """``D_T`` on every (grid pose, pixel) whose ray meets the target (reduction 3)."""
        cam, cfg = self.camera, self.config
        params = torch.as_tensor(self.target.params(), dtype=self.dtype)
        half = torch.as_tensor(self.target.size, dtype=self.dtype) * 1.01
        # image rectangle of each pose's box corners
        signs = torch.tensor(
            [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=self.dtype
        )
        corners = (signs * half) @ self.grid.poses[:, :3, :3].transpose(-1, -2) + self.grid.poses[
            :, None, :3, 3
        ]  # (P, 8, 3)
        cinv = torch.as_tensor(np.linalg.inv(cam.pose), dtype=self.dtype)
        pc = corners @ cinv[:3, :3].T + cinv[:3, 3]
        z = pc[..., 2].clamp_min(1e-3)
        u = cam.fx * pc[..., 0] / z + cam.cx
        v = cam.fy * pc[..., 1] / z + cam.cy
        u0 = u.amin(1).floor().clamp(0, cam.width - 1).long()
        u1 = u.amax(1).ceil().clamp(0, cam.width - 1).long()
        v0 = v.amin(1).floor().clamp(0, cam.height - 1).long()
        v1 = v.amax(1).ceil().clamp(0, cam.height - 1).long()
        pose_idx, pix_idx = [], []
        for p in range(len(self.grid)):
            uu = torch.arange(int(u0[p]), int(u1[p]) + 1)
            vv = torch.arange(int(v0[p]), int(v1[p]) + 1)
            pix = (vv[:, None] * cam.width + uu[None, :]).reshape(-1)
            pix_idx.append(pix)
            pose_idx.append(torch.full_like(pix, p))
        pose_i, pix_i = torch.cat(pose_idx), torch.cat(pix_idx)
        T = self.grid.poses[pose_i]
        Rt = T[:, :3, :3].transpose(-1, -2)
        o_l = (Rt @ (self._origin - T[:, :3, 3]).unsqueeze(-1)).squeeze(-1)
        d_l = (Rt @ self._dirs[pix_i].unsqueeze(-1)).squeeze(-1)
        t0, t1, hit = _box_chords(o_l, d_l, half)
        t0, t1 = t0.clamp_min(cfg.t_near), t1.clamp_max(cfg.t_far)
        hit &= t1 > t0
        pose_i, pix_i, o_l, d_l, t0, t1 = (a[hit] for a in (pose_i, pix_i, o_l, d_l, t0, t1))
        depth = torch.empty(t0.shape, dtype=self.dtype)
        n = cfg.n_ray_samples
        frac = (torch.arange(n, dtype=self.dtype) + 0.5) / n
        step = 1 << 15
        for s in range(0, t0.numel(), step):
            a, b = t0[s : s + step], t1[s : s + step]
            t = a.unsqueeze(-1) + (b - a).unsqueeze(-1) * frac
            x = o_l[s : s + step, None] + t.unsqueeze(-1) * d_l[s : s + step, None]
            S = implicit_homogeneous(x, params, SUPERELLIPSOID)
            depth[s : s + step] = soft_depth_on_chords(S, a, b, cfg)
        meets = depth < cfg.t_far - 1e-6
        return _Footprints(pose_i[meets], pix_i[meets], depth[meets])

    # --- per scene ----------------------------------------------------------------------------

    def collision_free(self, scene: SceneState, mask: torch.Tensor | None = None) -> torch.Tensor:
        """``f_c (P,)`` as bool (C.2.10); poses outside ``mask`` are reported False."""
        P = len(self.grid)
        sel = self.fc_shelf.clone() if mask is None else self.fc_shelf & mask
        idx = sel.nonzero().squeeze(-1)
        if idx.numel() and len(scene):
            hit = (
                scene.obstacles()
                .hits(self.points, self.point_centers, self.point_radii, self.grid.poses[idx])
                .any(-1)
            )
            sel[idx[hit]] = False
        return sel if P else torch.zeros(0, dtype=torch.bool)

    def object_collisions(self, scene: SceneState, i: int) -> torch.Tensor:
        """``(P,)`` bool: the target at each grid pose meets object ``i`` (voxel correlation of
        :class:`.graspability.VoxelAfterimage` without inflation: a target point collides when
        its 5 mm voxel's centre is inside the object, i.e. exact up to half a voxel)."""
        return self.voxels.hits(scene.params[i], scene.poses[i], int(scene.kinds[i]))[:, 0]

    def collision_free_fast(
        self, scene: SceneState, mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        """``f_c`` as :meth:`collision_free` with the objects tested by voxel correlation."""
        sel = self.fc_shelf.clone() if mask is None else self.fc_shelf & mask
        for i in range(len(scene)):
            sel &= ~self.object_collisions(scene, i)
        return sel

    def object_depth(self, scene: SceneState, pixels: torch.Tensor) -> torch.Tensor:
        """Soft depth ``D_0`` of the objects alone (C.2.5-C.2.9) on flat ``pixels (R,)``."""
        cfg = self.config
        out = torch.full((pixels.numel(),), cfg.t_far, dtype=self.dtype)
        if len(scene) == 0 or pixels.numel() == 0:
            return out
        dirs = self._dirs[pixels]  # (R, 3)
        inv = scene.obstacles().inv
        R, t = inv[:, :3, :3], inv[:, :3, 3]  # (M, 3, 3), (M, 3)
        o_l = R @ self._origin + t  # (M, 3)
        d_l = torch.einsum("mij,rj->rmi", R, dirs)  # (R, M, 3)
        axes = bound_ellipsoid(scene.params, scene.kinds)  # (M, 3)
        t0, t1, hit = _ellipsoid_chords(o_l.unsqueeze(0), d_l, axes.unsqueeze(0))
        t0, t1 = t0.clamp_min(cfg.t_near), t1.clamp_max(cfg.t_far)
        hit &= t1 > t0
        inf = torch.tensor(float("inf"), dtype=self.dtype)
        entry = torch.where(hit, t0, inf).amin(1)
        exit_ = torch.where(hit, t1, -inf).amax(1)
        ri, mi = hit.nonzero(as_tuple=True)  # only (ray, object) pairs whose ellipsoid is met
        if ri.numel() == 0:
            return out
        n = cfg.n_ray_samples
        frac = (torch.arange(n, dtype=self.dtype) + 0.5) / n
        ts = entry[ri].unsqueeze(-1) + (exit_[ri] - entry[ri]).unsqueeze(-1) * frac  # (Q, n)
        x = o_l[mi].unsqueeze(1) + ts.unsqueeze(-1) * d_l[ri, mi].unsqueeze(1)  # (Q, n, 3)
        S = torch.empty(ts.shape, dtype=self.dtype)
        for kind in torch.unique(scene.kinds).tolist():
            sel = scene.kinds[mi] == kind
            S[sel] = implicit_homogeneous(x[sel], scene.params[mi[sel]], int(kind))
        active = hit.any(1).nonzero().squeeze(-1)
        pos = torch.full((hit.shape[0],), -1, dtype=torch.long)
        pos[active] = torch.arange(active.numel())
        F = torch.full((active.numel(), n), float("inf"), dtype=self.dtype)
        F.scatter_reduce_(0, pos[ri].unsqueeze(-1).expand(-1, n), S, reduce="amin")
        out[active] = soft_depth_on_chords(F, entry[active], exit_[active], cfg)
        return out

    def invisible(self, scene: SceneState, mask: torch.Tensor) -> torch.Tensor:
        """``f_d (P,)`` as bool on the poses in ``mask`` (False elsewhere), by reductions 1-3."""
        P = len(self.grid)
        out = torch.zeros(P, dtype=torch.bool)
        fp = self._foot
        keep = mask[fp.pose]
        pose_i, pix_i, d_t = fp.pose[keep], fp.pixel[keep], fp.depth[keep]
        if pose_i.numel() == 0:
            out[mask] = True
            return out
        pixels, inverse = torch.unique(pix_i, return_inverse=True)
        d0 = self.object_depth(scene, pixels)[inverse]
        out = depth_condition(pose_i, d0, d_t, self.n_foot, self.config, self.pixel_area)
        return out & mask

    def seen_empty(self, depth: np.ndarray) -> torch.Tensor:
        """``(P,)`` poses where the target would have stood in plain view of the camera's depth
        image ``depth (H, W)`` (metres along the optical axis at the camera's full resolution,
        0 where nothing was hit): on at least ``seen_fraction`` of its footprint the observed
        surface lies more than ``seen_margin`` behind it. Measured on the image itself, not on
        the recognized shapes, so recognition error cannot rule out where the target is: at its
        true pose the image shows the target or something in front of it (ours)."""
        cam, cfg = self.camera, self.config
        depth = np.asarray(depth, np.float64)
        H, W = depth.shape
        s = cam.width / W
        u = np.clip(np.round((np.arange(cam.width) + 0.5) / s - 0.5).astype(int), 0, W - 1)
        v = np.clip(np.round((np.arange(cam.height) + 0.5) / s - 0.5).astype(int), 0, H - 1)
        z = torch.as_tensor(depth[np.ix_(v, u)].reshape(-1), dtype=self.dtype)
        # z-depth to distance along each render pixel's unit ray
        optical_z = torch.as_tensor(cam.pose[:3, 2], dtype=self.dtype)
        t_obs = z / (self._dirs @ optical_z).clamp_min(1e-6)
        t_obs = torch.where(z > 0, t_obs, torch.full_like(t_obs, cfg.t_far))
        fp = self._foot
        behind = (t_obs[fp.pixel] - fp.depth > cfg.seen_margin).to(self.dtype)
        n_behind = torch.zeros(len(self.grid), dtype=self.dtype).index_add_(0, fp.pose, behind)
        return (self.n_foot > 0) & (n_behind >= cfg.seen_fraction * self.n_foot)

    def evaluate(
        self,
        scene: SceneState,
        *,
        visible: bool = False,
        target_pose: np.ndarray | torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``f (P,)`` in {0, 1} (float): ``f_d f_c`` on ``mask`` (all poses by default), or the
        one-hot of the observed pose when ``visible`` (``c = 1``)."""
        P = len(self.grid)
        if visible:
            if target_pose is None:
                raise ValidationError("target_pose is required when the target is visible")
            f = torch.zeros(P, dtype=self.dtype)
            i = self.grid.nearest(target_pose)
            if mask is None or bool(mask[i]):
                f[i] = 1.0
            return f
        m = torch.ones(P, dtype=torch.bool) if mask is None else mask.bool()
        fc = self.collision_free_fast(scene, m)
        fd = self.invisible(scene, fc)
        return (fc & fd).to(self.dtype)


def existence_reference(
    model: ExistenceModel, scene: SceneState, poses: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Reference ``(f_d, f_c)`` as bool over the grid (or ``poses`` indices): full renders with
    :func:`render_depth` (ellipsoid culling) of one scene per pose (objects + target at ``x``)
    against the render without the target, compared on the target's own pixels (those of the
    target rendered alone, see the module doc), and the dense ``f_c`` over all 512 points."""
    cfg = model.config
    idx = torch.arange(len(model.grid)) if poses is None else poses
    kw = dict(
        t_near=cfg.t_near,
        t_far=cfg.t_far,
        n_samples=4 * cfg.n_ray_samples,
        sharpness=cfg.sharpness,
        tau=cfg.tau,
    )
    d0 = render_depth(scene.params, scene.poses, model.camera, scene.kinds, **kw)
    tp = torch.as_tensor(model.target.params(), dtype=model.dtype)

    n = len(scene)
    B = idx.numel()
    params = torch.cat([scene.params.expand(B, n, 9), tp.expand(B, 1, 9)], 1)
    poses_b = torch.cat([scene.poses.expand(B, n, 4, 4), model.grid.poses[idx].unsqueeze(1)], 1)
    kinds = torch.cat([scene.kinds, torch.tensor([SUPERELLIPSOID])])
    fd = torch.zeros(B, dtype=torch.bool)
    for s in range(0, B, 16):
        d = render_depth(params[s : s + 16], poses_b[s : s + 16], model.camera, kinds, **kw)
        d_t = render_depth(  # the target alone: its own pixels are where it meets the ray
            tp.expand(d.shape[0], 1, 9),
            poses_b[s : s + 16, n:],
            model.camera,
            kinds[n:],
            **kw,
        )
        own = d_t < cfg.t_far - 1e-6  # (b, H, W) the target's pixels
        e = (d0 - d).clamp_min(0)
        n = own.sum((-1, -2)).clamp_min(1)
        mse = (e * e * own).sum((-1, -2)) / n
        seen = ((e > cfg.seen_margin) & own).sum((-1, -2)) * model.pixel_area
        fd[s : s + 16] = (mse < cfg.mse_threshold) & (seen <= cfg.found_pixels)
    pts = model.points.reshape(-1, 3)
    world = (
        pts @ model.grid.poses[idx, :3, :3].transpose(-1, -2) + model.grid.poses[idx, None, :3, 3]
    )
    obs = Obstacles.from_parts(model.shelf.boxes(), model.dtype)
    allp = torch.cat([obs.params, scene.params])
    allT = torch.cat([obs.poses, scene.poses])
    allk = torch.cat([obs.kinds, scene.kinds])
    from sqmanip.geometry.world import world_implicit

    S = world_implicit(world, allp, allT, allk)  # (B, M, J)
    fc = S.flatten(1).amin(-1) > 1.0
    return fd, fc
