"""Terminal costs ``q(s_{T+1})`` of the pushing tasks (4.4.6, 4.4.7, 4.7.9, B.5.13) and the batched
gripper-vs-superquadric collision test they and the MPC share (B.5.12).

Costs are small pure functions of predicted object poses ``(..., N, 4, 4)`` (any leading batch:
sequences, time steps), returning ``(...)``. The grasping cost needs geometry: the rule-based
candidates of the target (``sqmanip.grasping.rule_based``, B.5) are generated once in the target's
own frame and carried rigidly with the target into every predicted state (exact for the planar
motions SQPD-Net predicts, which keep the target's vertical axis), then checked for collisions
against the predicted table and other objects and for kinematic feasibility, all sequences and
candidates in one batch (:class:`GraspFeasibility`).

Multi-part objects are rigid: an object's state is the pose of its first part and every other part
keeps its offset from it (:class:`PackedScene`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
import torch

from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric
from sqmanip.geometry.raycast import bound_box, bound_radius
from sqmanip.geometry.superquadric import implicit_homogeneous
from sqmanip.geometry.transforms import se3_inverse, so3_exp
from sqmanip.grasping.config import Reachability
from sqmanip.grasping.gripper import gripper_boxes, gripper_points
from sqmanip.grasping.rule_based import part_box, rule_based_candidates
from sqmanip.grasping.types import Candidates, GripperSpec, RuleOptions

from .config import GraspCostSpec, TableSpec

__all__ = [
    "GraspFeasibility",
    "GripperCloud",
    "PackedScene",
    "edge_grasp_candidates",
    "gripper_part_values",
    "grasping_cost",
    "interactive_moving_cost",
    "moving_cost",
    "objects_off_table",
    "rotation_distance",
    "singulation_cost",
    "table_contacts",
]


# --- task costs -----------------------------------------------------------------------------------


def _check_poses(poses: torch.Tensor, name: str = "poses") -> None:
    if poses.ndim < 3 or poses.shape[-2:] != (4, 4):
        raise ValueError(f"{name} must have shape (..., N, 4, 4), got {tuple(poses.shape)}")


def rotation_distance(R1: torch.Tensor, R2: torch.Tensor) -> torch.Tensor:
    """``d_SO(3)(I, R1^{-1} R2) = 1 - cos(angle(R1^T R2))`` in [0, 2], ``(..., 3, 3) -> (...)``.

    For rotations about z this is ``1 - cos(theta_1 - theta_2)`` of (B.3.11), the measure
    SQPD-Net is trained with; for general rotations it uses the angle of ``R1^T R2`` from its
    trace.
    """
    tr = (R1 * R2).sum((-1, -2))
    return 1.0 - ((tr - 1.0) / 2.0).clamp(-1.0, 1.0)


def moving_cost(
    poses: torch.Tensor,
    goals: torch.Tensor,
    beta: float = 0.0,
    weights: torch.Tensor | None = None,
) -> torch.Tensor:
    """Moving (4.4.6): ``sum_i w_i (||t_i - t_d,i||^2 + beta d_SO(3)(I, R_d,i^{-1} R_i))``.

    ``poses (..., N, 4, 4)`` predicted, ``goals (N, 4, 4)``, ``weights (N,)`` (1 for objects with
    a goal, 0 otherwise; default all 1). Returns ``(...)``; 0 exactly at the goals.
    """
    _check_poses(poses)
    goals = torch.as_tensor(goals, dtype=poses.dtype)
    if goals.shape != poses.shape[-3:]:
        raise ValueError(
            f"goals must have shape {tuple(poses.shape[-3:])}, got {tuple(goals.shape)}"
        )
    trans = ((poses[..., :3, 3] - goals[..., :3, 3]) ** 2).sum(-1)
    per = trans + beta * rotation_distance(goals[..., :3, :3], poses[..., :3, :3])
    if weights is not None:
        per = per * torch.as_tensor(weights, dtype=poses.dtype)
    return per.sum(-1)


def singulation_cost(poses: torch.Tensor, tau: float = 0.20) -> torch.Tensor:
    """Singulation (4.4.7): ``-min_{i>j} min(||t_i - t_j|| - tau, 0)``, ``(..., N, 4, 4) -> (...)``.

    Non-negative: 0 once every pair is at least ``tau`` apart, otherwise how far the closest pair
    falls short of ``tau`` (so pushing the closest pair apart lowers it). Fewer than two objects: 0.
    """
    _check_poses(poses)
    n = poses.shape[-3]
    if n < 2:
        return torch.zeros(poses.shape[:-3], dtype=poses.dtype)
    t = poses[..., :3, 3]
    d = torch.linalg.vector_norm(t.unsqueeze(-2) - t.unsqueeze(-3), dim=-1)  # (..., N, N)
    i, j = torch.triu_indices(n, n, offset=1)
    shortfall = (d[..., i, j] - tau).clamp_max(0.0)  # (..., pairs), <= 0
    return -shortfall.amin(-1)


def interactive_moving_cost(
    poses: torch.Tensor, target: int, goal: torch.Tensor | np.ndarray
) -> torch.Tensor:
    """Interactive moving (4.7.9): ``||t_target - t_d||^2``, ``(..., N, 4, 4) -> (...)``."""
    _check_poses(poses)
    if not 0 <= target < poses.shape[-3]:
        raise ValueError(f"target must index one of {poses.shape[-3]} objects, got {target}")
    g = torch.as_tensor(goal, dtype=poses.dtype)
    return ((poses[..., target, :3, 3] - g) ** 2).sum(-1)


def grasping_cost(feasible: torch.Tensor | np.ndarray) -> torch.Tensor:
    """Grasping (B.5.13): ``1 - max_k feasible_k``, ``(..., C) bool -> (...)`` float (0 or 1).

    ``feasible[..., k]`` is "candidate ``k`` is collision-free and kinematically feasible" in
    the predicted state; no candidates at all (e.g. the target is wider than the opening) gives 1.
    """
    f = torch.as_tensor(feasible, dtype=torch.bool)
    if f.shape[-1] == 0:
        return torch.ones(f.shape[:-1], dtype=torch.float64)
    return 1.0 - f.any(-1).to(torch.float64)


def objects_off_table(poses: torch.Tensor, table: TableSpec, margin: float = 0.0) -> torch.Tensor:
    """Workspace constraint (4.6.3): is any object centre off the table (shrunk by ``margin``)?

    ``poses (..., N, 4, 4) -> (...)`` bool.
    """
    _check_poses(poses)
    xy = poses[..., :2, 3]
    lo = torch.as_tensor(table.lo + margin, dtype=poses.dtype)
    hi = torch.as_tensor(table.hi - margin, dtype=poses.dtype)
    inside = ((xy >= lo) & (xy <= hi)).all(-1)
    return ~inside.all(-1)


# --- the scene as the planner sees it -------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class PackedScene:
    """``N`` recognized objects made of ``M`` superquadric parts, packed for batched checks.

    An object's *state* is the pose of its first part; ``params[i]``, ``kinds[i]`` are that
    part's (what the dynamics model sees), and part ``m`` sits at ``state[part_object[m]] @
    part_offset[m]``.
    """

    ids: tuple[int, ...]
    poses: torch.Tensor
    """(N, 4, 4) float64 object states (first-part poses)."""
    params: torch.Tensor
    """(N, 9) float64 first-part parameters."""
    kinds: torch.Tensor
    """(N,) long first-part kinds."""
    parts: tuple[tuple[Superquadric, ...], ...]
    part_params: torch.Tensor
    """(M, 9) float32."""
    part_kinds: torch.Tensor
    """(M,) long."""
    part_object: torch.Tensor
    """(M,) long object index per part."""
    part_offset: torch.Tensor
    """(M, 4, 4) float32 part pose in its object's state frame."""
    part_radius: torch.Tensor
    """(M,) float32 bounding-sphere radius about the part origin."""
    part_half: torch.Tensor
    """(M, 3) float32 part-frame box ``|x| <= h`` holding the part."""

    @property
    def n_objects(self) -> int:
        return len(self.ids)

    @classmethod
    def from_objects(cls, objects: Sequence[tuple[Sequence[Superquadric], int]]) -> PackedScene:
        """Pack ``[(parts, id), ...]``; validates parts, ids (unique ints) and poses (finite)."""
        if len(objects) == 0:
            raise ValidationError("objects must hold at least one (parts, id) pair, got 0")
        ids: list[int] = []
        parts_all: list[tuple[Superquadric, ...]] = []
        for i, item in enumerate(objects):
            if not isinstance(item, tuple | list) or len(item) != 2:
                raise ValidationError(f"objects[{i}] must be a (parts, id) pair, got {item!r}")
            parts, oid = item
            if isinstance(oid, bool) or not isinstance(oid, int | np.integer):
                raise ValidationError(f"objects[{i}] id must be an integer, got {oid!r}")
            if isinstance(parts, Superquadric):
                parts = (parts,)
            parts = tuple(parts)
            if len(parts) == 0:
                raise ValidationError(f"objects[{i}] must have at least one part, got 0")
            for p in parts:
                if not isinstance(p, Superquadric):
                    raise ValidationError(
                        f"objects[{i}] parts must be Superquadric values, got {type(p).__name__}"
                    )
                if not np.isfinite(p.pose).all() or not np.isfinite(p.params()).all():
                    raise ValidationError(f"objects[{i}] parts must have finite poses and sizes")
            ids.append(int(oid))
            parts_all.append(parts)
        if len(set(ids)) != len(ids):
            raise ValidationError(f"objects ids must be unique, got {ids}")
        poses = torch.as_tensor(np.stack([p[0].pose for p in parts_all]), dtype=torch.float64)
        params = torch.as_tensor(np.stack([p[0].params() for p in parts_all]), dtype=torch.float64)
        kinds = torch.as_tensor([p[0].kind_index for p in parts_all], dtype=torch.long)
        flat = [(i, p) for i, ps in enumerate(parts_all) for p in ps]
        part_object = torch.as_tensor([i for i, _ in flat], dtype=torch.long)
        part_params = torch.as_tensor(np.stack([p.params() for _, p in flat]), dtype=torch.float32)
        part_kinds = torch.as_tensor([p.kind_index for _, p in flat], dtype=torch.long)
        inv = se3_inverse(poses)
        offs = torch.stack(
            [inv[i] @ torch.as_tensor(p.pose, dtype=torch.float64) for i, p in flat]
        ).to(torch.float32)
        radius = torch.zeros(len(flat))
        half = torch.zeros(len(flat), 3)
        for kind in torch.unique(part_kinds).tolist():
            sel = part_kinds == kind
            radius[sel] = bound_radius(part_params[sel], int(kind))
            half[sel] = bound_box(part_params[sel], int(kind))
        bent = part_params[:, 6].abs() > 0  # bending leaves the box; the sphere still bounds it
        half = torch.where(bent.unsqueeze(-1), radius.unsqueeze(-1).expand_as(half), half)
        return cls(
            ids=tuple(ids),
            poses=poses,
            params=params,
            kinds=kinds,
            parts=tuple(parts_all),
            part_params=part_params,
            part_kinds=part_kinds,
            part_object=part_object,
            part_offset=offs,
            part_radius=radius,
            part_half=half,
        )

    def part_poses(self, states: torch.Tensor) -> torch.Tensor:
        """World part poses ``(..., M, 4, 4)`` float32 for object states ``(..., N, 4, 4)``."""
        return states.to(torch.float32)[..., self.part_object, :, :] @ self.part_offset

    def parts_at(self, index: int, state: torch.Tensor | np.ndarray) -> list[Superquadric]:
        """Object ``index``'s parts moved to ``state (4, 4)``."""
        T = np.asarray(state, dtype=np.float64)
        T0 = self.poses[index].numpy()
        delta = T @ np.linalg.inv(T0)
        return [p.with_pose(delta @ p.pose) for p in self.parts[index]]


# --- batched gripper collisions (B.5.12) -------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class GripperCloud:
    """Gripper-frame points ``x_gr,j`` (B.5) split into the gripper's boxes, for culling.

    Each segment (left finger, right finger, palm; points outside every box form one more) keeps
    its points in homogeneous columns ``(4, P_g)`` and its own bounding box, so a part is tested
    only against the segments its bounding sphere reaches.
    """

    points: torch.Tensor
    """(P, 3) float32, all points."""
    segments: tuple[tuple[torch.Tensor, torch.Tensor, torch.Tensor], ...]
    """Per segment: homogeneous points (4, P_g), box centre (3,), box half extents (3,)."""

    @classmethod
    def from_spec(
        cls,
        spec: GripperSpec,
        n_points: int,
        opening: float | None = None,
        include_wrist: bool = False,
    ) -> GripperCloud:
        pts = gripper_points(spec, n_points, opening=opening, include_wrist=include_wrist)
        pts = np.array(pts, dtype=np.float64)
        label = np.full(len(pts), -1)
        for b, (lo, hi) in enumerate(gripper_boxes(spec, opening)):
            inside = ((pts >= lo - 1e-9) & (pts <= hi + 1e-9)).all(-1) & (label < 0)
            label[inside] = b
        segs = []
        for b in np.unique(label):
            p = pts[label == b]
            lo, hi = p.min(0), p.max(0)
            ph = np.concatenate([p.T, np.ones((1, len(p)))], 0)
            segs.append(
                (
                    torch.as_tensor(ph, dtype=torch.float32),
                    torch.as_tensor(0.5 * (lo + hi), dtype=torch.float32),
                    torch.as_tensor(0.5 * (hi - lo), dtype=torch.float32),
                )
            )
        return cls(torch.as_tensor(pts, dtype=torch.float32), tuple(segs))


def _apply(A: torch.Tensor, pts_h: torch.Tensor) -> torch.Tensor:
    """``A (T, 4, 4)`` applied to homogeneous columns ``(4, P)``: ``(T, 3, P)`` (one GEMM)."""
    return (A[:, :3, :].reshape(-1, 4) @ pts_h).reshape(A.shape[0], 3, pts_h.shape[1])


_CHUNK = 4096
"""(gripper, part) pairs transformed at once (bounds memory to ~CHUNK * 3 * P floats)."""


def gripper_part_values(
    frames: torch.Tensor,
    cloud: GripperCloud,
    part_poses: torch.Tensor,
    scene: PackedScene,
    part_mask: torch.Tensor | None = None,
    pair_mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """``min_j S_m(T_m^{-1} F_sq x_j)`` per (scene, gripper, part), ``inf`` where culled.

    ``frames (S, Q, 4, 4)``: ``Q`` gripper poses in each of ``S`` scenes; ``cloud`` the
    gripper-frame points; ``part_poses (S or 1, M, 4, 4)`` world part poses of each scene;
    ``part_mask (M,)`` parts to test (default all), ``pair_mask (S, Q)`` grippers to test
    (default all). Returns ``(S, Q, M)`` float32; a value ``< 1`` is a collision
    (``S = f^{e1}``, C.3.11 / B.5.12).

    Culling keeps this cheap and exact: a part is tested against a gripper segment only when its
    bounding sphere reaches the segment's box (in the gripper frame), and ``S`` is evaluated only
    at points inside the part's bounding box; the result equals the dense test.
    """
    frames = frames.to(torch.float32)
    S, Q = frames.shape[:2]
    M = part_poses.shape[-3]
    out = torch.full((S * Q * M,), math.inf)
    if S == 0 or Q == 0 or M == 0:
        return out.reshape(S, Q, M)
    part_poses = part_poses.to(torch.float32).expand(S, M, 4, 4)
    # part centres in each gripper frame: (S, Q, M, 3)
    Rg, tg = frames[..., :3, :3], frames[..., :3, 3]
    c = part_poses[:, None, :, :3, 3] - tg[:, :, None, :]
    c_local = (c.unsqueeze(-2) @ Rg[:, :, None]).squeeze(-2)  # R^T (c - t)
    mask = torch.ones(S, Q, M, dtype=torch.bool)
    if part_mask is not None:
        mask &= part_mask.to(torch.bool)
    if pair_mask is not None:
        mask &= pair_mask.to(torch.bool).unsqueeze(-1)
    reach = scene.part_radius * 1.001 + 1e-6
    inv_parts = se3_inverse(part_poses)  # (S, M, 4, 4)
    for pts_h, box_c, box_h in cloud.segments:
        gap = ((c_local - box_c).abs() - box_h).clamp_min(0.0)
        near = (torch.linalg.vector_norm(gap, dim=-1) <= reach) & mask
        s_all, q_all, m_all = near.nonzero(as_tuple=True)
        for lo in range(0, s_all.numel(), _CHUNK):
            s_idx, q_idx, m_idx = (x[lo : lo + _CHUNK] for x in (s_all, q_all, m_all))
            A = inv_parts[s_idx, m_idx] @ frames[s_idx, q_idx]  # part-from-gripper (T, 4, 4)
            local = _apply(A, pts_h)  # (T, 3, P_g)
            inbox = (local.abs() <= scene.part_half[m_idx].unsqueeze(-1)).all(1)  # (T, P_g)
            t_idx, p_idx = inbox.nonzero(as_tuple=True)
            if t_idx.numel() == 0:
                continue
            x = local[t_idx, :, p_idx]  # (R, 3)
            kinds = scene.part_kinds[m_idx[t_idx]]
            vals = torch.empty(t_idx.numel())
            for kind in torch.unique(kinds).tolist():
                sel = (kinds == kind).nonzero().squeeze(-1)
                prm = scene.part_params[m_idx[t_idx[sel]]]
                vals[sel] = implicit_homogeneous(x[sel].unsqueeze(-2), prm, int(kind)).squeeze(-1)
            flat = (s_idx[t_idx] * Q + q_idx[t_idx]) * M + m_idx[t_idx]
            out.scatter_reduce_(0, flat, vals, reduce="amin")
    return out.reshape(S, Q, M)


_SIGNS = torch.tensor(
    [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=torch.float32
)


def table_contacts(
    frames: torch.Tensor, cloud: GripperCloud, table: TableSpec, clearance: float
) -> torch.Tensor:
    """Does each posed gripper touch the table box? ``frames (S, Q, 4, 4)`` -> ``(S, Q)`` bool.

    A point touches when it lies over the table (x-y) and between the table's bottom and
    ``height + clearance``. Segments whose box corners all clear that height are skipped.
    """
    frames = frames.to(torch.float32)
    S, Q = frames.shape[:2]
    hit = torch.zeros(S * Q, dtype=torch.bool)
    if S == 0 or Q == 0:
        return hit.reshape(S, Q)
    F_all = frames.reshape(S * Q, 4, 4)
    top, bottom = table.height + clearance, table.height - table.thickness
    lo_xy = torch.as_tensor(table.lo, dtype=torch.float32)
    hi_xy = torch.as_tensor(table.hi, dtype=torch.float32)
    for pts_h, box_c, box_h in cloud.segments:
        corners = box_c + _SIGNS * box_h  # (8, 3)
        cw = corners @ F_all[:, :3, :3].transpose(-1, -2) + F_all[:, None, :3, 3]  # (SQ, 8, 3)
        cz = cw[..., 2]
        maybe = (cz.amin(-1) < top) & (cz.amax(-1) > bottom) & ~hit
        maybe &= ((cw[..., :2].amax(1) >= lo_xy) & (cw[..., :2].amin(1) <= hi_xy)).all(-1)
        rows = maybe.nonzero().squeeze(-1)
        for lo in range(0, rows.numel(), _CHUNK):
            r = rows[lo : lo + _CHUNK]
            w = _apply(F_all[r], pts_h)  # (T, 3, P_g)
            inside = (
                (w[:, 0] >= lo_xy[0])
                & (w[:, 0] <= hi_xy[0])
                & (w[:, 1] >= lo_xy[1])
                & (w[:, 1] <= hi_xy[1])
                & (w[:, 2] < top)
                & (w[:, 2] > bottom)
            )
            hit[r] |= inside.any(-1)
    return hit.reshape(S, Q)


ROBOT_BASE = (0.0, 0.0, 0.10)
"""The simulator's Panda base position (``sqmanip.sim.config.ROBOT_BASE_POSITION``)."""
ARM_REACH = 0.855
"""The Panda's reach (m) from its base; a table edge farther than this is no place to grasp."""


def edge_gaps(xy: torch.Tensor, table: TableSpec) -> torch.Tensor:
    """``(..., 4)`` signed distances of points ``xy (..., 2)`` inside the table edges ``x = lo,
    x = hi, y = lo, y = hi`` (the order of :func:`grasp_edges`); negative past an edge."""
    lo = torch.as_tensor(table.lo, dtype=xy.dtype)
    hi = torch.as_tensor(table.hi, dtype=xy.dtype)
    return torch.stack(
        [xy[..., 0] - lo[0], hi[0] - xy[..., 0], xy[..., 1] - lo[1], hi[1] - xy[..., 1]], -1
    )


def grasp_edges(table: TableSpec, base: Sequence[float] = ROBOT_BASE) -> np.ndarray:
    """``(4,)`` bool over the table edges ``x = lo, x = hi, y = lo, y = hi``: may an object
    overhanging there be grasped? Not at the edge nearest the robot (its pedestal stands there)
    nor at one whose nearest point lies beyond :data:`ARM_REACH` of the base."""
    lo, hi, b = np.asarray(table.lo), np.asarray(table.hi), np.asarray(base[:2])
    nearest = np.array(
        [[lo[0], np.clip(b[1], lo[1], hi[1])], [hi[0], np.clip(b[1], lo[1], hi[1])],
         [np.clip(b[0], lo[0], hi[0]), lo[1]], [np.clip(b[0], lo[0], hi[0]), hi[1]]]
    )  # fmt: skip
    dist = np.linalg.norm(nearest - b, axis=1)
    ok = dist <= ARM_REACH
    ok[int(np.argmin(dist))] = False
    return ok


# --- grasp candidates ------------------------------------------------------------------------------


def _frame(y: np.ndarray, z: np.ndarray) -> np.ndarray:
    return np.stack([np.cross(y, z), y, z], -1)


def edge_grasp_candidates(
    parts: Sequence[Superquadric],
    options: RuleOptions,
    up: np.ndarray = np.array([0.0, 0.0, 1.0]),
    turns_deg: Sequence[float] = (0.0,),
) -> Candidates:
    """Side grasps that close across a part's *vertical* axis (world frame), ``options`` style.

    For each part whose height ``2 b_v`` fits ``options.max_width``: four horizontal approach
    directions (``+-`` each horizontal axis), the TCP ``grasp_depth`` past the near face at
    mid-height, ``per_direction`` positions spread along the other horizontal axis; fingers on
    the top and bottom faces (width ``2 b_v``, exact for box-like parts, an upper bound otherwise).
    The rule-based generator of ``sqmanip.grasping`` closes only across horizontal axes, so a
    flat object wider than the opening has no candidate there; these reach its rim where it
    overhangs the table (4.6.3 "grasping large").

    Each grasp comes once per angle of ``turns_deg``, turned by it about ``up`` through its TCP
    (fingers still on the top and bottom faces). A plate overhanging a side edge at an angle is
    reached by the arm only from its own side with the wrist off the table; the unturned hand,
    aligned with the plate's axes, then has its wrist over the table on one of the two yaws.
    """
    poses, widths, contacts = [], [], []
    e = np.eye(3)
    axis = torch.as_tensor(up, dtype=torch.float64) / float(np.linalg.norm(up))
    turns = [so3_exp(axis * math.radians(float(a))).numpy() for a in turns_deg]
    for part in parts:
        c, b = part_box(part)
        R_o, t_o = part.pose[:3, :3], part.pose[:3, 3]
        up_l = R_o.T @ up
        iv = int(np.argmax(np.abs(up_l)))
        w = 2.0 * b[iv]
        if w > options.max_width or w <= 0:
            continue
        for ha, hb in ((a, o) for a in range(3) for o in range(3) if iv not in (a, o) and a != o):
            for sign in (1.0, -1.0):
                R = _frame(e[iv], sign * e[ha])
                n = options.per_direction
                spread = (
                    c[hb] + np.linspace(-options.spread * b[hb], options.spread * b[hb], n)
                    if n > 1
                    else np.array([c[hb]])
                )
                for s in spread:
                    p = c.copy()
                    p[ha] = c[ha] - sign * (b[ha] - min(options.grasp_depth, b[ha]))
                    p[hb] = s
                    c1, c2 = p.copy(), p.copy()
                    c1[iv], c2[iv] = c[iv] - b[iv], c[iv] + b[iv]
                    for turn in turns:
                        T = np.eye(4)
                        T[:3, :3] = turn @ R_o @ R
                        T[:3, 3] = R_o @ p + t_o
                        poses.append(T)
                        widths.append(w)
                        contacts.append(np.stack([R_o @ c1 + t_o, R_o @ c2 + t_o]))
    if not poses:
        return Candidates.empty()
    return Candidates(
        torch.as_tensor(np.stack(poses)),
        torch.as_tensor(np.asarray(widths)),
        torch.as_tensor(np.stack(contacts)),
    )


def _cap(cands: Candidates, limit: int) -> Candidates:
    """At most ``limit`` candidates, evenly spread over the list (as the rule-based generator)."""
    if len(cands) <= limit:
        return cands
    keep = torch.as_tensor(
        np.unique(np.round(np.linspace(0, len(cands) - 1, limit)).astype(np.int64))
    )
    return Candidates(cands.poses[keep], cands.widths[keep], cands.contacts[keep])


class GraspFeasibility:
    """Batched B.5.13 test: which rule-based grasps of the target are feasible in each state.

    ``reachability`` is the kinematic-feasibility callable of ``sqmanip.grasping``
    (``(K, 4, 4) -> bool (K,)``; the Panda IK in the stack, ``WorkspaceReachability`` as a
    stand-in). Candidates are widths within ``spec.rule.max_width`` and the gripper's opening.
    A grasp whose TCP lies past a table edge the arm cannot use (:func:`grasp_edges` from the
    robot ``base``) is infeasible. The IK reaches a box overhanging the near edge, beside the
    pedestal, but the arm's links would hit the table and the pedestal on the way there.
    """

    def __init__(
        self,
        reachability: Reachability,
        *,
        spec: GraspCostSpec,
        gripper: GripperSpec,
        table: TableSpec,
        base: Sequence[float] = ROBOT_BASE,
    ) -> None:
        self.reachability = reachability
        self.spec = spec
        self.gripper = gripper
        self.table = table
        rule = spec.rule
        if rule.max_width > gripper.max_opening:
            rule = dataclasses.replace(rule, max_width=gripper.max_opening)
        self.rule = rule
        self.cloud = GripperCloud.from_spec(gripper, spec.gripper_points)
        # against the table and the mount, links 7 and 6 behind the hand count too: a low side
        # grasp at the table edge keeps the hand past the edge, while the wrist is over the table
        self.static_cloud = GripperCloud.from_spec(gripper, spec.gripper_points, include_wrist=True)
        self.blocked_edges = ~grasp_edges(table, base)
        self._last_candidates: tuple[bytes, Candidates] | None = None

    def candidates(self, parts: Sequence[Superquadric]) -> Candidates:
        """Rule-based (B.5) plus edge candidates of one object, world frame, each at most its cap.

        The last object's candidates are kept: a planning step asks for the same target's up to
        four times (current cost, terminal cost, earliest-success tie-break), ~40 ms each.
        """
        key = b"".join(np.asarray(p.params()).tobytes() + p.pose.tobytes() for p in parts)
        if self._last_candidates is not None and self._last_candidates[0] == key:
            return self._last_candidates[1]
        cands = self._candidates(parts)
        self._last_candidates = (key, cands)
        return cands

    def _candidates(self, parts: Sequence[Superquadric]) -> Candidates:
        cands = rule_based_candidates(parts, options=self.rule, dtype=torch.float64)
        cands = _cap(cands, self.spec.max_candidates)
        if self.spec.edge_grasps:
            edge = edge_grasp_candidates(parts, self.rule, turns_deg=self.spec.edge_turns_deg)
            if len(edge):
                edge = _cap(edge, self.spec.max_edge_candidates)
                cands = Candidates(
                    torch.cat([cands.poses, edge.poses]),
                    torch.cat([cands.widths, edge.widths]),
                    torch.cat([cands.contacts, edge.contacts]),
                )
        return cands

    def feasible(self, scene: PackedScene, states: torch.Tensor, target: int) -> torch.Tensor:
        """``(S, C)`` bool: candidate ``k`` is collision-free and reachable in state ``s``.

        ``states (S, N, 4, 4)`` predicted object states. Candidates come from the target's
        current parts and move rigidly with it; the check against the target itself does not
        depend on the state and is done once.
        """
        frames, ok = self._collision_free(scene, states, target)
        s_idx, c_idx = ok.nonzero(as_tuple=True)
        if s_idx.numel():
            ok[s_idx, c_idx] = torch.as_tensor(self._reachable(frames[s_idx, c_idx]))
        return ok

    def any_feasible(self, scene: PackedScene, states: torch.Tensor, target: int) -> torch.Tensor:
        """``(S,)`` bool: some candidate is feasible in state ``s``, which is all the 0/1 cost
        of B.5.13 needs. Equals ``feasible(...).any(-1)``, but each state's IK stops at its first
        reachable candidate: IK (per pose) is most of a grasping planning step."""
        frames, ok = self._collision_free(scene, states, target)
        out = torch.zeros(ok.shape[0], dtype=torch.bool)
        for s in ok.any(-1).nonzero().squeeze(-1).tolist():
            for c in ok[s].nonzero().squeeze(-1).tolist():
                if self._reachable(frames[s, c][None])[0]:
                    out[s] = True
                    break
        return out

    def static_collisions(self, frames: torch.Tensor) -> torch.Tensor:
        """``(Q,)`` bool: the hand or the wrist (links 6-7) at ``frames (Q, 4, 4)`` or at its
        pre-grasp pose touches the table or the robot mount."""
        back = torch.eye(4, dtype=frames.dtype)
        back[2, 3] = -self.spec.approach_distance
        both = torch.stack([frames, frames @ back])  # (2, Q, 4, 4)
        clearance = self.spec.table_clearance
        hit = table_contacts(both, self.static_cloud, self.table, clearance).any(0)
        if self.spec.mount is not None:
            hit |= table_contacts(both, self.static_cloud, self.spec.mount, clearance).any(0)
        return hit

    def past_blocked_edge(self, frames: torch.Tensor) -> torch.Tensor:
        """``(Q,)`` bool: the TCP of ``frames (Q, 4, 4)`` lies past an edge the arm cannot use."""
        past = edge_gaps(frames[:, :2, 3], self.table) < 0.0  # (Q, 4)
        return (past & torch.as_tensor(self.blocked_edges)).any(-1)

    def _reachable(self, frames: torch.Tensor) -> np.ndarray:
        """Kinematic feasibility of ``frames (K, 4, 4)`` (last: IK is per pose)."""
        poses = frames.numpy()
        reach = np.asarray(self.reachability(poses), dtype=bool)
        if reach.shape != (len(poses),):
            raise ValueError(f"reachability must return shape ({len(poses)},), got {reach.shape}")
        return reach

    def _collision_free(
        self, scene: PackedScene, states: torch.Tensor, target: int
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Candidate grasp frames ``(S, C, 4, 4)`` in each state and ``(S, C)`` bool: free of
        the target, the table and the other objects (one batched call each)."""
        states = torch.as_tensor(states, dtype=torch.float64)
        if states.ndim != 4 or states.shape[1:] != (scene.n_objects, 4, 4):
            raise ValueError(
                f"states must have shape (S, {scene.n_objects}, 4, 4), got {tuple(states.shape)}"
            )
        S = states.shape[0]
        cands = self.candidates(scene.parts[target])
        C = len(cands)
        if C == 0 or S == 0:
            return torch.zeros(S, C, 4, 4, dtype=torch.float64), torch.zeros(S, C, dtype=torch.bool)
        local = se3_inverse(scene.poses[target]) @ cands.poses  # (C, 4, 4) in the target's frame
        frames = states[:, target, None] @ local  # (S, C, 4, 4) float64
        ok = torch.ones(S, C, dtype=torch.bool)
        # the target itself: state-independent
        is_target = scene.part_object == target
        if self.spec.check_target:
            own = gripper_part_values(
                cands.poses[None].to(torch.float32),
                self.cloud,
                scene.part_poses(scene.poses)[None],
                scene,
                is_target,
            )
            ok &= ~(own < 1.0).any(-1)
        # table and the other objects, per predicted state (only still-feasible pairs)
        s_idx, c_idx = ok.nonzero(as_tuple=True)
        if s_idx.numel() == 0:
            return frames, ok
        ok[s_idx, c_idx] = ~(
            self.static_collisions(frames[s_idx, c_idx])
            | self.past_blocked_edge(frames[s_idx, c_idx])
        )
        if scene.n_objects > 1 and bool(ok.any()):
            vals = gripper_part_values(
                frames, self.cloud, scene.part_poses(states), scene, ~is_target, ok
            )
            ok &= ~(vals < 1.0).any(-1)
        return frames, ok
