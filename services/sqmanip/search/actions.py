"""Push and pick-and-place actions, their scene prediction and the action sampler (5.4.4).

Push (Fig. 5.4): an object ``i`` and a direction, left (+y) or right (-y) across the shelf. The
closed gripper points into the shelf (+x) pitched 30 deg down about its own y axis (the closing
axis, here along the push), its pushing finger face 1 cm from the object's near side, the TCP at
the object's centre height; the pose is rejected when the gripper (with links 6-7) collides with
another object or a shelf board (the C.2 point test). ``d in {5, 10, 15} cm``. The next scene comes
from a pushing dynamics model ``predict(poses, params, actions (K, 6) = (p, v), kinds)`` such as
SQPD-Net (:class:`SQPDNetDynamics`), then objects are kept inside the shelf walls.

Pick-and-place: a rule-based C.3 grasp of object ``i`` whose 30 cm approach afterimage is
collision-free, and a place translation on the floor (no stacking: the object keeps its height
and orientation) where the object collides with no other object, no board and no pose the target
may still occupy (``f = 1``), and where the gripper's afterimage is collision-free. The next
scene applies ``T_place T_grasp^{-1}`` to the object.

Sampler: ``I_p`` (pushable) and ``I_g`` (graspable) objects; 30 indices are drawn from the
multiset ``I_g + I_p`` (or one of them for the 5.6.2 ablations) and one action is sampled for each.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Literal, Protocol

import numpy as np
import torch

from sqmanip.geometry import Superquadric
from sqmanip.geometry.sampling import sample_surface
from sqmanip.grasping import PANDA_HAND, GripperSpec, RuleOptions, gripper_points
from sqmanip.grasping.rule_based import rule_based_candidates
from sqmanip.sim.actions import push_tool_rotation

from .config import SearchConfig
from .shelf import Obstacles, SceneState, ShelfSpec, cluster_points


@dataclasses.dataclass(frozen=True)
class Push:
    kind: Literal["push"]
    obj: int
    direction: int
    """+1 pushes towards +y (left seen from the robot), -1 towards -y."""
    distance: float
    gripper_pose: np.ndarray
    start: np.ndarray
    displacement: np.ndarray

    @classmethod
    def sideways(
        cls, obj: int, direction: int, distance: float, gripper_pose: np.ndarray, start
    ) -> Push:
        """A push of ``distance`` towards ``direction`` * y (5.4.4 pushes left or right)."""
        return cls(
            "push",
            obj,
            direction,
            distance,
            gripper_pose,
            start,
            np.array([0.0, direction * distance, 0.0]),
        )

    @property
    def upright(self) -> bool:
        """The hand is turned on its side, its closing axis vertical
        (:meth:`ActionSampler.push_poses`)."""
        return abs(float(self.gripper_pose[2, 1])) > 0.9

    def as_vector(self) -> np.ndarray:
        """``(p, v)`` of the pushing dynamics model, (6,)."""
        return np.concatenate([self.start, self.displacement])


@dataclasses.dataclass(frozen=True)
class PickAndPlace:
    kind: Literal["pick_and_place"]
    obj: int
    grasp_pose: np.ndarray
    place_pose: np.ndarray

    @classmethod
    def to_random_spot(
        cls, obj: int, grasp: torch.Tensor, spots: torch.Tensor, rng: np.random.Generator
    ) -> PickAndPlace:
        """Pick ``obj`` with ``grasp (4, 4)`` and place it shifted by one of ``spots (S, 2)``
        (:meth:`ActionSampler.place_spots`), drawn by ``rng``."""
        place = grasp.double().numpy().copy()
        place[:2, 3] += spots[int(rng.integers(spots.shape[0]))].double().numpy()
        return cls("pick_and_place", obj, grasp.double().numpy(), place)

    @property
    def transform(self) -> np.ndarray:
        return self.place_pose @ np.linalg.inv(self.grasp_pose)


Action = Push | PickAndPlace


class PushDynamics(Protocol):
    def predict(self, poses, params, actions, kinds=None) -> torch.Tensor: ...


class SQPDNetDynamics:
    """SQPD-Net (Ch. 4) on the shelf floor: the net was trained on a table at ``z = 0`` and is
    SE(2)-equivariant but not equivariant to height, so scene and push are lowered by the floor
    height before the call and raised after.

    The net takes at most ``max_objects`` objects (its training scenes had up to 4): in a
    larger scene each push acts on the ``max_objects`` objects whose centres are nearest its
    start point (the pushed one and its neighbours) and the others stay (ours)."""

    def __init__(self, model, floor_z: float, max_objects: int = 4) -> None:
        self.model, self.floor_z, self.max_objects = model, float(floor_z), int(max_objects)

    def predict(self, poses, params, actions, kinds=None) -> torch.Tensor:
        poses = torch.as_tensor(poses).clone()
        actions = torch.as_tensor(actions).clone()
        params = torch.as_tensor(params)
        poses[:, 2, 3] -= self.floor_z
        actions[:, 2] -= self.floor_z
        n, m = poses.shape[0], self.max_objects
        with torch.no_grad():
            if n <= m:
                out = self.model.predict(poses, params, actions, kinds).clone()
            else:
                kinds_t = None if kinds is None else torch.as_tensor(kinds)
                d = torch.cdist(actions[:, None, :2], poses[None, :, :2, 3].to(actions.dtype))
                near = d[:, 0].argsort(-1)[:, :m].sort(-1).values  # (K, m)
                out = poses.unsqueeze(0).expand(len(actions), n, 4, 4).clone()
                for sub in torch.unique(near, dim=0):
                    ks = (near == sub).all(-1).nonzero().squeeze(-1)
                    k_sub = None if kinds_t is None else kinds_t[sub]
                    pred = self.model.predict(poses[sub], params[sub], actions[ks], k_sub)
                    out[ks[:, None], sub[None, :]] = pred.to(out.dtype)
        out[..., 2, 3] += self.floor_z
        return out


UPRIGHT_FLOOR_GAP = 0.01
"""Clearance (m) of an upright hand's palm above the floor board (ours)."""


class KinematicPushDynamics:
    """A simple push model: the pushed object (the one whose near side the pusher faces) slides
    rigidly by the push length minus the initial gap; the others stay. For tests and as a
    fallback when no trained SQPD-Net is available."""

    def __init__(self, gap: float = 0.01) -> None:
        self.gap = gap

    def predict(self, poses, params, actions, kinds=None) -> torch.Tensor:
        poses = torch.as_tensor(poses)
        actions = torch.as_tensor(actions, dtype=poses.dtype)
        K, N = actions.shape[0], poses.shape[0]
        out = poses.unsqueeze(0).expand(K, N, 4, 4).clone()
        if N == 0:
            return out
        p, v = actions[:, :3], actions[:, 3:]
        length = v.norm(dim=-1).clamp_min(1e-9)
        u = v / length.unsqueeze(-1)
        rel = poses[:, :3, 3].unsqueeze(0) - p.unsqueeze(1)  # (K, N, 3)
        along = (rel * u.unsqueeze(1)).sum(-1)
        across = (rel - along.unsqueeze(-1) * u.unsqueeze(1))[..., :2].norm(dim=-1)
        score = torch.where(along > 0, across + 0.1 * along, torch.full_like(along, math.inf))
        i = score.argmin(-1)
        move = (length - self.gap).clamp_min(0).unsqueeze(-1) * u
        k = torch.arange(K)
        ok = torch.isfinite(score[k, i])
        out[k[ok], i[ok], :3, 3] += move[ok]
        return out


def keep_inside(poses: torch.Tensor, radii: torch.Tensor, shelf: ShelfSpec) -> torch.Tensor:
    """Clamp object centres ``(..., N, 4, 4)`` so their horizontal bounding circle (``radii (N,)``)
    stays between the shelf walls: a pushed object stops at a wall."""
    lo_y = -shelf.inner_width / 2 + radii
    hi_y = shelf.inner_width / 2 - radii
    lo_x = shelf.front_x + radii * 0.0
    hi_x = shelf.front_x + shelf.depth - radii
    out = poses.clone()
    out[..., 1, 3] = torch.maximum(torch.minimum(out[..., 1, 3], hi_y), lo_y)
    out[..., 0, 3] = torch.maximum(torch.minimum(out[..., 0, 3], hi_x), lo_x)
    return out


def horizontal_radius(scene: SceneState) -> torch.Tensor:
    """``(N,)`` radius of a vertical cylinder about each centre holding the object (box bound)."""
    corners = torch.tensor(
        [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
        dtype=scene.params.dtype,
    )
    c = (corners * scene.params[:, None, :3]) @ scene.poses[:, :3, :3].transpose(-1, -2)
    return c[..., :2].norm(dim=-1).amax(-1)


def world_half_extents(scene: SceneState) -> torch.Tensor:
    """``(N, 3)`` world-axis half extents of each object's box."""
    return (scene.poses[:, :3, :3].abs() @ scene.params[:, :3].unsqueeze(-1)).squeeze(-1)


class GraspSource:
    """C.3 rule-based grasp candidates ``(G, 4, 4)`` of one lone object (no collision check).

    ``planner=None``: in-process (:func:`rule_based_candidates`). Otherwise any object with
    :class:`sqmanip.grasping.GraspPlanner`'s ``plan`` -- the grasp service through
    :class:`sqmanip.rpc.client.RemoteGraspPlanner` when search runs as a service -- asked for
    the ``rule_based`` candidates of the object alone: no support plane, no obstacles, no
    result limit (the search makes its own afterimage checks, C.3). The answer for a shape and
    orientation is reused by translation (:meth:`ActionSampler.grasps`), so a service is asked
    once per object shape and turn, not per predicted scene."""

    def __init__(self, planner=None, dtype: torch.dtype = torch.float32) -> None:
        self.planner, self.dtype = planner, dtype

    def __call__(self, obj: Superquadric, rule: RuleOptions) -> torch.Tensor:
        if self.planner is None:
            cand = rule_based_candidates([obj], options=rule, dtype=self.dtype)
            return cand.poses if len(cand) else torch.zeros(0, 4, 4, dtype=self.dtype)
        from sqmanip.grasping.types import Environment, PlanOptions

        options = PlanOptions(method="rule_based", rule=rule, max_results=None, check_target=False)
        grasps = self.planner.plan([obj], (), Environment(support_normal=None), None, options)
        if not grasps:
            return torch.zeros(0, 4, 4, dtype=self.dtype)
        return torch.as_tensor(np.stack([g.pose for g in grasps]), dtype=self.dtype)


class ActionSampler:
    """Valid push and pick-and-place actions for a scene (5.4.4); grasp candidates of the
    objects come from ``grasp_source`` (in-process by default)."""

    def __init__(
        self,
        shelf: ShelfSpec,
        config: SearchConfig,
        gripper: GripperSpec = PANDA_HAND,
        dtype: torch.dtype = torch.float32,
        grasp_source: GraspSource | None = None,
        target_height: float = math.inf,
    ) -> None:
        self.shelf, self.config, self.gripper, self.dtype = shelf, config, gripper, dtype
        self.target_height = float(target_height)
        self.grasp_source = grasp_source or GraspSource(dtype=dtype)
        self._local: dict[bytes, torch.Tensor] = {}
        self._last: tuple[SceneState, tuple[int, int], Obstacles] | None = None
        self.boards = Obstacles.from_parts(shelf.boxes(), dtype)
        closed = gripper_points(gripper, 512, include_wrist=True, opening=0.0)
        self.closed = cluster_points(closed, 16, dtype)
        after = gripper_points(
            gripper,
            config.n_gripper_points,
            include_wrist=True,
            approach_distance=config.approach_distance,
        )
        self.after = cluster_points(after, 64, dtype)
        self.rule = RuleOptions(
            top_down=False,
            max_width=config.grasp_max_width,
            tilt=math.radians(config.grasp_tilt_deg),
            facing=(1.0, 0.0, 0.0),
            facing_angle=math.radians(config.facing_angle_deg),
        )
        b = shelf.inner_bounds()
        xs = np.arange(b[0, 0] + config.place_resolution / 2, b[1, 0], config.place_resolution)
        ys = np.arange(b[0, 1] + config.place_resolution / 2, b[1, 1], config.place_resolution)
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        self.spots = torch.as_tensor(np.stack([gx.ravel(), gy.ravel()], -1), dtype=dtype)

    # --- helpers ---------------------------------------------------------------------------

    def _obstacles(self, scene: SceneState) -> Obstacles:
        """The shelf's boards and the objects of ``scene``, their level half sizes less
        :attr:`SearchConfig.action_tolerance` (their heights are kept); built once per scene
        (the last one asked for is kept while its tensors are unchanged)."""
        key = (scene.params._version, scene.poses._version)
        last = self._last
        if last is not None and last[0] is scene and last[1] == key:
            return last[2]
        params = scene.params.clone()
        tol = self.config.action_tolerance
        if tol > 0 and len(scene):
            vertical = scene.poses[:, 2, :3].abs().argmax(-1)
            level = torch.ones_like(params[:, :3], dtype=torch.bool)
            level[torch.arange(len(scene)), vertical] = False
            sizes = params[:, :3].abs()
            params[:, :3] = torch.where(level, (sizes - tol).clamp(min=0.005), sizes)
        obstacles = Obstacles.from_tensors(
            torch.cat([self.boards.params, params]),
            torch.cat([self.boards.poses, scene.poses]),
            torch.cat([self.boards.kinds, scene.kinds]),
        )
        self._last = (scene, key, obstacles)
        return obstacles

    def _free(self, scene: SceneState, i: int, pts, poses: torch.Tensor) -> torch.Tensor:
        """``(P,)``: gripper points ``pts`` at ``poses`` meet neither the shelf nor any object
        of ``scene`` but ``i``."""
        obstacles = self._obstacles(scene)
        others = torch.ones(poses.shape[0], len(obstacles), dtype=torch.bool)
        others[:, len(self.boards) + i] = False
        return ~obstacles.hits(*pts, poses.to(self.dtype), others).any(-1)

    # --- push ------------------------------------------------------------------------------

    def push_poses(
        self, scene: SceneState, i: int, keep_out: torch.Tensor | None = None
    ) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Collision-free ``(direction, gripper pose, start point)`` for pushing object ``i``.

        The pose of 5.4.4 first: the closing axis along the push, the hand pitched
        ``push_tilt_deg`` down. Its 20 cm palm then runs across the push, so it needs about
        12.5 cm beside the object (15 cm from a side board in the simulator). Where it does not
        fit, the hand turned on its side (:attr:`Push.upright`) is tried: its 6.3 cm thickness
        across the push, the palm upright and clear of the floor (the simulator pushes level in
        the shelf, so the tilt is left out). The simulator executes it 9.5 cm from a side board
        (ours; see :data:`.mpc.UPRIGHT_WALL_GAP`).

        With ``keep_out (Q, 3)`` discs where the target may stand, a pose is also dropped when
        the closed hand, moving in from the shelf front along +x to it (the simulator's
        pre-push path), passes through a disc below the target's top: the pusher would knock
        the hidden target along instead of the object (ours).

        Pushes straight into the shelf (+x, the hand coming in at the object's front: the
        simulator moved a cylinder 8.9 cm for 10 cm, upright at 15 of 15 floor positions and
        with the hand 1.8 cm from a side board) were tried where these are stuck, for a wide
        object between a seen target and a board. R-Search-for-Grasp on the seed-2900 scenes,
        paired: 26/23/20/20 of 30 grasped at 2/4/6/8 objects against 27/24/21/19 (4 won, 6
        lost), decisions at 8 objects 2.1 s against 1.95 s
        (``benchmarks/results/search_r_sfg_*_seed2900_30x_intoshelf.json``); offered always,
        among the others, 27/22/19 at 2/4/6. Not kept."""
        cfg, g = self.config, self.gripper
        c = scene.poses[i, :3, 3].double().numpy()
        half = world_half_extents(scene)[i].double().numpy()
        tilt = math.radians(cfg.push_tilt_deg)
        out = []
        for direction in (1, -1):
            u = np.array([0.0, float(direction), 0.0])
            z = np.array([math.cos(tilt), 0.0, -math.sin(tilt)])
            level = self._push_pose(
                i, scene, u,
                R=np.stack([np.cross(u, z), u, z], -1),
                offset=half[1] + cfg.push_gap + g.finger_thickness,
                height=max(c[2], self.shelf.bottom_z + 0.03),
                keep_out=keep_out,
            )  # fmt: skip
            upright = None
            if level is None and cfg.upright_push:
                upright = self._push_pose(
                    i, scene, u,
                    R=push_tool_rotation(u, down=False, upright=True),  # as the robot pushes
                    offset=half[1] + cfg.push_gap + g.palm_size[0] / 2,
                    height=self.shelf.bottom_z + g.palm_size[1] / 2 + UPRIGHT_FLOOR_GAP,
                    keep_out=keep_out,
                )  # fmt: skip
            pose = level if level is not None else upright
            if pose is not None:
                out.append((direction, *pose))
        return out

    def _push_pose(self, i, scene, u, R, offset, height, keep_out):
        """``(gripper pose, start point)`` with rotation ``R`` and the tool ``offset`` back
        from object ``i``'s centre along ``-u`` at ``height``; ``None`` when the closed hand
        there is not free (or touches ``keep_out``, see :meth:`push_poses`)."""
        T = np.eye(4)
        T[:3, :3] = R
        tcp = scene.poses[i, :3, 3].double().numpy() - u * offset
        tcp[2] = height
        T[:3, 3] = tcp
        T_t = torch.as_tensor(T[None])
        free = self._free(scene, i, self.closed, T_t)
        if keep_out is not None and keep_out.numel():
            free &= ~self._touches_keep_out(self.closed, T_t, keep_out, sweep=True)
        return (T, tcp) if bool(free[0]) else None

    def _touches_keep_out(
        self, pts, poses: torch.Tensor, keep_out: torch.Tensor, sweep: bool = False
    ) -> torch.Tensor:
        """``(P,)``: gripper points ``pts`` (:func:`cluster_points`) at ``poses (P, 4, 4)`` come
        into a keep-out disc ``(x, y, r)`` below the target's top; with ``sweep``, anywhere on
        their way in from the shelf front along +x (the pusher's approach)."""
        return self._keep_out_contacts(pts, poses, keep_out, sweep).any(-1)

    def _keep_out_contacts(
        self, pts, poses: torch.Tensor, keep_out: torch.Tensor, sweep: bool = False
    ) -> torch.Tensor:
        """``(P, Q)``: which discs :meth:`_touches_keep_out` finds touched. Only the point
        clusters whose bounding sphere comes near some disc are tested point by point (the
        afterimage's 30 cm approach lies mostly in front of where the target may stand)."""
        clusters, centres, radii = pts
        R, t = poses[:, :3, :3].double(), poses[:, None, :3, 3].double()
        ko = keep_out.double()
        top = self.shelf.bottom_z + self.target_height
        c = centres.double() @ R.transpose(-1, -2) + t  # (P, C, 3)
        rho = radii.double()[None, :, None]  # (1, C, 1)
        near = _disc_contacts(c[..., :2], ko, sweep, rho)  # (P, C, Q)
        near &= (c[..., 2:] - rho) < top
        hits = torch.zeros(poses.shape[0], ko.shape[0], dtype=torch.int32)
        p, k = near.any(-1).nonzero(as_tuple=True)
        if p.numel():
            world = clusters[k].double() @ R[p].transpose(-1, -2) + t[p]  # (K, J', 3)
            inside = _disc_contacts(world[..., :2], ko, sweep) & (world[..., 2:] < top)
            hits.index_add_(0, p, inside.any(1).int())
        return hits > 0

    # --- pick and place --------------------------------------------------------------------

    def candidate_grasps(self, scene: SceneState, i: int) -> torch.Tensor:
        """C.3 grasps ``(G, 4, 4)`` of object ``i`` before collision checks: the candidates
        translate with the object, so they are computed (by :attr:`grasp_source`) once per
        shape and orientation and shifted."""
        T = scene.poses[i].double()
        key = (
            np.round(scene.params[i].double().numpy(), 5).tobytes()
            + np.round(T[:3, :3].numpy(), 4).tobytes()
            + bytes([int(scene.kinds[i])])
        )
        local = self._local.get(key)
        if local is None:
            obj = scene.objects()[i]
            centred = obj.pose.copy()
            centred[:3, 3] = 0.0
            local = self.grasp_source(dataclasses.replace(obj, pose=centred), self.rule)
            local = local.to(self.dtype)
            if len(self._local) >= 2048:
                self._local.clear()
            self._local[key] = local
        cand = local.clone()
        cand[:, :3, 3] += T[:3, 3].to(cand.dtype)
        return cand

    def grasps(
        self, scene: SceneState, i: int, keep_out: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Collision-free C.3 grasps ``(G, 4, 4)`` of object ``i`` (afterimage test); with
        ``keep_out`` discs where the target may stand, also those whose afterimage stays out
        of them (fingers reaching past the object would drag a target behind it along)."""
        cand = self.candidate_grasps(scene, i)
        if cand.shape[0] == 0:
            return cand
        free = self._free(scene, i, self.after, cand)
        if keep_out is not None and keep_out.numel():
            free &= ~self._touches_keep_out(self.after, cand, keep_out)
        return cand[free]

    def place_spots(
        self, scene: SceneState, i: int, grasp: torch.Tensor, keep_out: torch.Tensor | None
    ) -> torch.Tensor:
        """Free translations ``(S, 2)`` for object ``i`` held by ``grasp`` (see module doc).

        ``keep_out (Q, 3)``: ``(x, y, radius)`` discs where the target may stand (``f = 1``)."""
        cfg = self.config
        c = scene.poses[i, :2, 3]
        r = horizontal_radius(scene)
        d = self.spots - c
        new_c = self.spots
        ok = d.norm(dim=-1) > 0.02
        ok &= new_c[:, 1].abs() <= self.shelf.inner_width / 2 - r[i]
        ok &= (new_c[:, 0] >= self.shelf.front_x + r[i]) & (
            new_c[:, 0] <= self.shelf.front_x + self.shelf.depth - r[i]
        )
        others = scene.without(i)
        if len(others):  # horizontal discs: no overlap with other objects (no stacking)
            ro = horizontal_radius(others)
            dist = torch.cdist(new_c, others.poses[:, :2, 3])
            ok &= (dist > (r[i] + ro).unsqueeze(0)).all(-1)
        if keep_out is not None and keep_out.numel():
            dist = torch.cdist(new_c, keep_out[:, :2])
            ok &= (dist > (r[i] + keep_out[:, 2]).unsqueeze(0)).all(-1)
        idx = ok.nonzero().squeeze(-1)
        if idx.numel() > cfg.max_place_spots:
            g = torch.Generator().manual_seed(cfg.seed + i)
            idx = idx[torch.randperm(idx.numel(), generator=g)[: cfg.max_place_spots]]
        if idx.numel() == 0:
            return torch.zeros(0, 2, dtype=self.dtype)
        shift = d[idx]
        T = grasp.to(self.dtype).expand(idx.numel(), 4, 4).clone()
        T[:, :2, 3] += shift
        free = self._free(scene, i, self.after, T)
        return shift[free]

    # --- sampling --------------------------------------------------------------------------

    def push_distances(
        self, scene: SceneState, i: int, direction: int, keep_out: torch.Tensor | None
    ) -> list[float]:
        """The push lengths ``d`` (5.4.4) after which object ``i``, sliding ``d`` towards
        ``direction``, has not swept into a place where the target may stand (``keep_out
        (Q, 3)`` discs ahead of it, see :meth:`place_spots`; the object as its world-axis
        box). The push model moves the pushed
        object only, but the target there would be shoved along (into a wall, out of every
        grasp): the same no-contact rule as for a place spot (ours). Across the push, a
        disc counts less the overlap f_c grants (see :meth:`_slide_contacts`): R-Search-for-
        Grasp on fresh seed-2100 scenes grasped 18 of 30 at 8 objects against 15 with whole
        discs (5 won, 2 lost) and 20 against 21 at 6 (mean steps to a grasp 4.55 against
        5.19; ``benchmarks/results/search_r_sfg_6_8obj_seed2100_30x*.json``); on the seed-1900
        scenes, against the committed runs of the planner before it, 22 against 21 at 2
        objects and 18 against 16 at 4 (``search_r_sfg_2_4obj_seed1900_30x_slide.json``)."""
        ds = [float(d) for d in self.config.push_distances]
        if keep_out is None or keep_out.numel() == 0:
            return ds
        first = float(self._slide_contacts(scene, i, direction, keep_out).min())
        return [d for d in ds if d - self.config.push_gap <= first]

    def _slide_contacts(
        self, scene: SceneState, i: int, direction: int, keep_out: torch.Tensor
    ) -> torch.Tensor:
        """``(Q,)`` slide length at which object ``i`` (its world-axis box) pushed towards
        ``direction`` meets each keep-out disc (``inf``: never)."""
        c = scene.poses[i, :2, 3].double()
        hx, hy = (float(v) for v in world_half_extents(scene)[i, :2])
        rel = keep_out[:, :2].double() - c
        along = rel[:, 1] * float(direction)  # pushes go along +-y
        rk = keep_out[:, 2].double()
        # the object's box (world half extents) slides along y: it meets the disc ahead of it
        # whose centre is within hx + r of its x, once it has moved along - hy - r. Across the
        # push, the disc is the target less the overlap f_c grants a recognized object
        # (fc_shrink + object_tolerance): f = 1 right behind an object means the target may
        # stand there, with the object's estimated back up to that far into it; with the
        # whole disc, the occluder of such poses could never be pushed aside (ours)
        cfg = self.config
        across = rk - (cfg.fc_shrink + cfg.object_tolerance)
        ahead = (along > 0) & (rel[:, 0].abs() < hx + across)
        contact = (along - hy - rk).clamp(min=0.0)
        return torch.where(ahead, contact, torch.full_like(contact, math.inf))

    def push_risk(self, scene: SceneState, push: Push, keep_out: torch.Tensor | None) -> float:
        """Share of the keep-out discs (the poses where the target may stand) that ``push``
        may touch: the closed hand on its way in from the shelf front, or the pushed object
        over its slide (see :meth:`push_poses` and :meth:`push_distances`). With the target
        equally likely at each, this is the probability that the push shoves it (ours)."""
        if keep_out is None or keep_out.numel() == 0:
            return 0.0
        T = torch.as_tensor(push.gripper_pose[None])
        hand = self._keep_out_contacts(self.closed, T, keep_out, sweep=True)[0]
        slide = self._slide_contacts(scene, push.obj, push.direction, keep_out)
        touched = hand | (slide < push.distance - self.config.push_gap)
        return float(touched.double().mean())

    def candidates(
        self,
        scene: SceneState,
        keep_out: torch.Tensor | None,
        hand_keep_out: bool = True,
        pick_ok: Callable[[torch.Tensor], bool] | None = None,
        slide_keep_out: bool = True,
        seen_target: torch.Tensor | None = None,
    ):
        """``I_p`` and ``I_g`` with their valid pushes / (grasps, spots) per object; a push is
        ``(direction, gripper pose, start, lengths)``. ``hand_keep_out=False`` lets the hand on
        its way in, ``slide_keep_out=False`` the pushed object's slide, sweep where the target
        may stand (the fallbacks of :meth:`.mpc.SearchPlanner.decide`); the hand still keeps out
        of ``seen_target`` (``(1, 3)``, a disc about a seen target's axis): it may graze the
        target, not come in through it. An object's pick uses its first collision-free grasp with a
        free spot that ``pick_ok`` (the robot's own IK and arm checks, when known) accepts."""
        pushes, picks = {}, {}
        hand_out = keep_out if hand_keep_out else seen_target
        slide_out = keep_out if slide_keep_out else None
        for i in range(len(scene)):
            if self.config.actions in ("both", "push"):
                p = [
                    (*q, ds)
                    for q in self.push_poses(scene, i, hand_out)
                    if (ds := self.push_distances(scene, i, q[0], slide_out))
                ]
                if p:
                    pushes[i] = p
            if self.config.actions in ("both", "pick_and_place"):
                pick = self.pick(scene, i, keep_out, pick_ok)
                if pick is not None:
                    picks[i] = pick
        return pushes, picks

    def pick(
        self,
        scene: SceneState,
        i: int,
        keep_out: torch.Tensor | None,
        pick_ok: Callable[[torch.Tensor], bool] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor] | None:
        """``(grasp (4, 4), spots (S, 2))`` of object ``i``: its first collision-free grasp
        (:meth:`grasps`) with a free place spot (:meth:`place_spots`) that ``pick_ok`` (when
        given) accepts; ``None`` when there is none.

        The floor is checked after this choice (:meth:`.mpc.SearchPlanner.feasible`): when the
        first grasp is the lowest, 1.5 cm above the floor, the object has no pick although its
        higher grasps clear the floor (scenario seed 8711 ends with no valid action so).
        Skipping too-low grasps here gave more objects a pick and fewer "no valid action"
        endings, but fewer grasped targets: 69 against 77 of the 124 saved seed-300/500/700
        scenes (``benchmarks/results/search_r_sfg_6_8_*_floorgrasps.json``), so it is kept."""
        gr = self.grasps(scene, i, keep_out)
        for k in range(gr.shape[0]):
            spots = self.place_spots(scene, i, gr[k], keep_out)
            if spots.shape[0] and (pick_ok is None or pick_ok(gr[k])):
                return gr[k], spots
        return None

    def sample(
        self,
        scene: SceneState,
        rng: np.random.Generator,
        n: int,
        keep_out: torch.Tensor | None = None,
        candidates=None,
    ) -> list[Action]:
        """``n`` actions drawn from the multiset ``I_g + I_p`` (5.4.4); fewer if none is valid."""
        pushes, picks = candidates if candidates is not None else self.candidates(scene, keep_out)
        pool = [("push", i) for i in pushes] + [("pick", i) for i in picks]
        if not pool:
            return []
        out: list[Action] = []
        for j in rng.integers(0, len(pool), size=n):
            kind, i = pool[int(j)]
            if kind == "push":
                direction, T, tcp, ds = pushes[i][int(rng.integers(len(pushes[i])))]
                out.append(Push.sideways(i, direction, ds[int(rng.integers(len(ds)))], T, tcp))
            else:
                out.append(PickAndPlace.to_random_spot(i, *picks[i], rng))
        return out


def _disc_contacts(
    xy: torch.Tensor, discs: torch.Tensor, sweep: bool, grow: torch.Tensor | float = 0.0
) -> torch.Tensor:
    """``(..., Q)``: points ``xy (..., 2)`` within keep-out discs ``(Q, 3)`` grown by ``grow``
    (a point cluster's radius); with ``sweep``, anywhere on their way along +x from the shelf
    front to the point: in the disc's strip along x and past its front."""
    dx = xy[..., None, 0] - discs[:, 0]
    dy = xy[..., None, 1] - discs[:, 1]
    r = discs[:, 2] + grow
    if sweep:
        return (dy.abs() < r) & (dx > -r)
    return dx * dx + dy * dy < r * r


def apply_actions(
    scene: SceneState, actions: list[Action], dynamics: PushDynamics, shelf: ShelfSpec
) -> list[SceneState]:
    """Predicted next scenes ``s_{t+1} = S(s_t, a)`` for each action (5.4.2); pushes batched."""
    out: list[SceneState | None] = [None] * len(actions)
    push_idx = [k for k, a in enumerate(actions) if isinstance(a, Push)]
    if push_idx:
        vec = torch.as_tensor(np.stack([actions[k].as_vector() for k in push_idx]))
        nxt = dynamics.predict(scene.poses, scene.params, vec.to(scene.poses.dtype), scene.kinds)
        nxt = keep_inside(nxt.to(scene.poses.dtype), horizontal_radius(scene), shelf)
        for j, k in enumerate(push_idx):
            out[k] = scene.with_poses(nxt[j])
    for k, a in enumerate(actions):
        if isinstance(a, PickAndPlace):
            T = torch.as_tensor(a.transform, dtype=scene.poses.dtype)
            out[k] = scene.with_pose(a.obj, T @ scene.poses[a.obj])
    return [s for s in out if s is not None]


def object_surface_points(scene: SceneState, n: int = 128) -> torch.Tensor:
    """``(N, n, 3)`` world surface points of each object (for checks and plots)."""
    pts, _ = sample_surface(scene.params.double(), n, generator=0)
    return (
        pts @ scene.poses.double()[:, :3, :3].transpose(-1, -2)
        + scene.poses.double()[:, None, :3, 3]
    ).to(scene.params.dtype)
