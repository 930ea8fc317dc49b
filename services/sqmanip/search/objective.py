"""Dynamics of ``f`` and ``g`` (5.4.2) and the MPC objective (5.4.6-5.4.7).

``F(f_t, a)(x) = f_t(x) f(x; s_{t+1}, c_t)`` and ``G(g_t, a)(x) = g(x; s_{t+1})`` (5.4.5), with
``s_{t+1}`` from the action's scene prediction (:mod:`.actions`) and the visibility kept,
``c_{t+1} = c_t``. Because ``f_{t+1} <= f_t``, ``f`` and ``g`` are only evaluated where ``f_t = 1``.

``J_t = sum_x f_t(x) + alpha f_t(x) (1 - g_t(x))`` (5.4.7, search-for-grasp, with the dense
``g_c,m`` of C.3.13), or for search-and-grasp ``J_t = sum_x f_t(x)`` before the target is seen and
``1 - g_t(x*)`` after (5.3). The cost of a sequence is ``sum_t gamma^t (J_{t+1} - J_t)`` (5.4.6).

Per-object caching: both ``f_c`` and the afterimage collisions of ``g`` (the voxel correlation
of :class:`.graspability.VoxelAfterimage`, all grid poses at once) are ORs / sums over objects, and a rollout step moves one object (pick-and-place) or a few (push), so each object's
contribution is cached by its (shape, pose) and only moved objects are re-tested.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from .config import SearchConfig
from .existence import ExistenceModel, depth_condition
from .graspability import GraspabilityModel
from .shelf import Obstacles, SceneState


@dataclasses.dataclass
class Maps:
    """``f``, ``g`` and ``g_m`` over the grid ``(P,)`` and the objective value ``J``."""

    f: torch.Tensor
    g: torch.Tensor
    g_m: torch.Tensor
    best_grasp: torch.Tensor
    J: float


class _ObjectEntry:
    def __init__(self, P: int, K: int) -> None:
        self.depth: torch.Tensor | None = None
        self.fc_done = torch.zeros(P, dtype=torch.bool)
        self.fc_hit = torch.zeros(P, dtype=torch.bool)
        self.g_done = torch.zeros(P, dtype=torch.bool)
        self.g_hit = torch.zeros(P, K, dtype=torch.bool)


class FGEvaluator:
    """Evaluates ``f``, ``g`` and ``J`` for predicted scenes, caching per-object collision tests."""

    def __init__(
        self, existence: ExistenceModel, grasp: GraspabilityModel, config: SearchConfig
    ) -> None:
        self.em, self.gm, self.config = existence, grasp, config
        self.P = len(existence.grid)
        self.grasp = grasp
        self._cache: dict[bytes, _ObjectEntry] = {}
        fp = existence._foot
        self._pixels, self._foot_pixel = torch.unique(fp.pixel, return_inverse=True)

    def _entry(self, scene: SceneState, i: int) -> _ObjectEntry:
        key = (
            np.round(scene.params[i].double().numpy(), 6).tobytes()
            + np.round(scene.poses[i].double().numpy(), 6).tobytes()
            + bytes([int(scene.kinds[i])])
        )
        e = self._cache.get(key)
        if e is None:
            if len(self._cache) > 4096:
                self._cache.clear()
            e = self._cache[key] = _ObjectEntry(self.P, self.grasp.n_candidates)
        return e

    def _single(self, scene: SceneState, i: int) -> Obstacles:
        return Obstacles.from_tensors(
            scene.params[i : i + 1], scene.poses[i : i + 1], scene.kinds[i : i + 1]
        )

    def collision_free(self, scene: SceneState, mask: torch.Tensor) -> torch.Tensor:
        ex = self.em
        out = ex.fc_shelf & mask
        for i in range(len(scene)):
            e = self._entry(scene, i)
            if not bool(e.fc_done[0]):  # all poses at once (voxel correlation)
                e.fc_hit = ex.object_collisions(scene, i)
                e.fc_done[:] = True
            out &= ~e.fc_hit
        return out

    def graspability(
        self,
        scene: SceneState,
        mask: torch.Tensor,
        allowed: tuple[torch.Tensor | int, ...] | None = None,
    ):
        """``(g, g_m, best)`` on ``mask`` as :meth:`GraspabilityModel.evaluate`; ``allowed =
        (i, ok (K,))`` keeps only the candidates ``ok`` at grid pose ``i`` (those the robot can
        execute there, :meth:`SearchPlanner.decide`'s ``grasp_check``); ``(i, ok, extra (K,))``
        also adds ``extra`` obstacles to each candidate's count there."""
        gm = self.grasp
        P, K = self.P, gm.n_candidates
        n_obs = len(scene) + 5
        g_m = torch.full((P,), float(1 - n_obs), dtype=gm.dtype)
        best = torch.full((P,), -1, dtype=torch.long)
        idx = mask.nonzero().squeeze(-1)
        if idx.numel() == 0 or K == 0:
            return (g_m >= 1).to(gm.dtype), g_m, best
        n = gm.n_shelf[idx].clone()
        for i in range(len(scene)):
            e = self._entry(scene, i)
            if not bool(e.g_done[0]):  # all poses at once by voxel correlation (C.3, fast)
                e.g_hit = gm.object_hits(scene, i)
                e.g_done[:] = True
            n += e.g_hit[idx].long()
        valid = gm.local_valid[gm._theta_index[idx]]
        if allowed is not None:
            row = (idx == allowed[0]).nonzero().squeeze(-1)
            if row.numel():
                valid = valid.clone()
                valid[row] &= allowed[1].to(valid.device)
                if len(allowed) > 2:  # obstacles the robot's own plan found that g does not see
                    n = n.clone()
                    n[row] += allowed[2].to(n.device)
        n = torch.where(valid, n, torch.full_like(n, n_obs))
        n_min, k = n.min(-1)
        g_m[idx] = (1 - n_min).to(gm.dtype)
        best[idx] = torch.where(n_min < n_obs, k, torch.full_like(k, -1))
        return (g_m >= 1).to(gm.dtype), g_m, best

    def invisible(self, scene: SceneState, mask: torch.Tensor) -> torch.Tensor:
        """``f_d`` on ``mask`` as :meth:`ExistenceModel.invisible`, with the objects' depth
        ``D_0 = min_i D_i`` from per-object soft depths cached on every footprint pixel.

        The min is reduction 2 of :mod:`.existence` applied between objects: exact in the hard
        limit for objects that do not overlap along a ray, and within ``exp(-tau w) / tau`` of the
        joint soft render for an occluder of thickness ``w`` (0.5 mm at 3 cm)."""
        ex = self.em
        out = torch.zeros(self.P, dtype=torch.bool)
        fp = ex._foot
        keep = mask[fp.pose]
        if not bool(keep.any()):
            return mask.clone()
        d0 = torch.full((self._pixels.numel(),), ex.config.t_far, dtype=ex.dtype)
        for i in range(len(scene)):
            e = self._entry(scene, i)
            if e.depth is None:
                e.depth = ex.object_depth(_single_scene(scene, i), self._pixels)
            d0 = torch.minimum(d0, e.depth)
        out = depth_condition(
            fp.pose[keep],
            d0[self._foot_pixel[keep]],
            fp.depth[keep],
            ex.n_foot,
            ex.config,
            ex.pixel_area,
        )
        return out & mask

    def existence(self, scene, *, visible=False, target_pose=None, mask=None) -> torch.Tensor:
        ex = self.em
        if visible:
            return ex.evaluate(scene, visible=True, target_pose=target_pose, mask=mask)
        m = torch.ones(self.P, dtype=torch.bool) if mask is None else mask.bool()
        fc = self.collision_free(scene, m)
        return (fc & self.invisible(scene, fc)).to(ex.dtype)

    def maps(
        self,
        scene: SceneState,
        *,
        visible: bool = False,
        target_pose=None,
        prior: torch.Tensor | None = None,
        allowed: tuple[torch.Tensor | int, ...] | None = None,
    ) -> Maps:
        """``f_{t+1} = prior * f(s)`` (5.4.5) and ``g(s)`` where ``f_{t+1} = 1``, with ``J``
        (``allowed``: see :meth:`graspability`)."""
        mask = None if prior is None else prior.bool()
        f = self.existence(scene, visible=visible, target_pose=target_pose, mask=mask)
        need_g = self.config.method == "search_for_grasp" or visible
        if need_g:
            g, g_m, best = self.graspability(scene, f.bool(), allowed)
        else:
            P = self.P
            g = torch.zeros(P, dtype=f.dtype)
            g_m = torch.zeros(P, dtype=f.dtype)
            best = torch.full((P,), -1, dtype=torch.long)
        return Maps(f, g, g_m, best, objective_value(f, g_m, self.config, visible))


def _single_scene(scene: SceneState, i: int) -> SceneState:
    return SceneState(scene.params[i : i + 1], scene.poses[i : i + 1], scene.kinds[i : i + 1])


def objective_value(
    f: torch.Tensor, g_m: torch.Tensor, config: SearchConfig, visible: bool
) -> float:
    """``J`` (5.4.7) for search-for-grasp; ``sum f`` / ``1 - g(x*)`` for search-and-grasp (5.3)."""
    if config.method == "search_and_grasp":
        if visible:
            return float((f * (1 - g_m)).sum())
        return float(f.sum())
    return float((f + config.alpha * f * (1 - g_m)).sum())


def sequence_cost(J: list[float], gamma: float) -> float:
    """``sum_{t=0}^{M-1} gamma^t (J_{t+1} - J_t)`` (5.4.6) for ``J = [J_0, ..., J_M]``."""
    return float(sum(gamma**t * (J[t + 1] - J[t]) for t in range(len(J) - 1)))
