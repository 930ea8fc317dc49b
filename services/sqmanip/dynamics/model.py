"""SQPD-Net: the SE(2)-equivariant pushing dynamics network of Ch. 4.3 and Appendix B.3.

For every object ``i`` (all at once, batched over tuples, objects and actions):

1. (optional, 4.6) *shape alignment*: relabel the object axes so that z points up and x along
   the push, permuting the sizes to match (an exact symmetry of the shape);
2. decompose ``T_i = C_i U_i`` (B.1.1, :func:`sqmanip.geometry.transforms.decompose_pose`);
3. express the action and every object in ``C_i``'s frame: ``C_i^{-1}(p, v)``, ``C_i^{-1} T_j``;
4. encode: action ``(C_i^{-1} p, cos, sin)`` (5-d), ego ``(U_i, q_i)`` (12-d), scene
   ``(C_i^{-1} T_j, q_j)`` (12-d each, max-pooled over the real objects ``j``); B.3 widths;
5. decode a planar motion ``dT_i`` of the form (B.1.3) and output ``T'_i = T_i dT_i`` (4.3).

Because every network input is invariant to ``T_j -> C T_j``, ``(p, v) -> C (p, v)`` for ``C``
of the form (4.3.2) (Proposition B.1), ``f`` is SE(2)-equivariant by construction (4.3.1).

Convention:
- an object feature is ``(t, q, a1, a2, a3, e1, e2)``: translation, xyzw quaternion with
  ``w >= 0`` (``geometry.matrix_to_quat``), and the first five packed shape parameters (B.3);
- the push direction is ``(cos, sin)`` of ``v``'s horizontal part; the push length is not an
  input (fixed in the 4.5 sampler); a zero horizontal ``v`` reads as ``(0, 0)``;
- the scene set includes object ``i`` itself (4.3 "for all j = 1..N", as in the public code);
- padded objects (``mask`` false) are ignored by the pooling and returned unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from sqmanip.geometry.superquadric import N_PARAMS, SUPERELLIPSOID
from sqmanip.geometry.transforms import decompose_pose, matrix_to_quat, se3_inverse

from .config import ACTION_DIM, OBJECT_DIM, SQPDNetConfig
from .data import PushBatch

__all__ = [
    "MLP",
    "SQPDNet",
    "align_objects",
    "count_parameters",
    "make_model",
    "planar_motion",
    "sqpd_loss",
    "rotation_cos",
]


class MLP(nn.Sequential):
    """Linear layers with LeakyReLU between them (none after the last), as the public code."""

    def __init__(self, in_dim: int, hidden: Sequence[int], out_dim: int, slope: float) -> None:
        layers: list[nn.Module] = []
        dims = [in_dim, *hidden, out_dim]
        for k in range(len(dims) - 1):
            layers.append(nn.Linear(dims[k], dims[k + 1]))
            if k < len(dims) - 2:
                layers.append(nn.LeakyReLU(slope))
        super().__init__(*layers)


# --- geometry helpers -----------------------------------------------------------------------------


def object_features(T: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
    """``(t, q_xyzw, a1, a2, a3, e1, e2)``: ``T (..., 4, 4)``, ``params (..., 9)`` -> ``(..., 12)``."""
    return torch.cat([T[..., :3, 3], matrix_to_quat(T[..., :3, :3]), params[..., :5]], -1)


def action_features(p: torch.Tensor, v: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """``(p, cos, sin)`` of B.3 from a start point and displacement ``(..., 3)`` -> ``(..., 5)``."""
    vxy = v[..., :2]
    norm = torch.linalg.vector_norm(vxy, dim=-1, keepdim=True)
    return torch.cat([p, vxy / norm.clamp_min(eps)], -1)


def planar_motion(dxy: torch.Tensor, cs: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """``dT`` of the form (B.1.3) from ``(dx, dy) (..., 2)`` and an unnormalised ``(cos, sin)``.

    ``(cos, sin)`` is divided by its norm (clamped at ``eps``; a zero vector gives a zero
    rotation block, which cannot occur for trained heads but stays finite).
    """
    cs = cs / torch.linalg.vector_norm(cs, dim=-1, keepdim=True).clamp_min(eps)
    c, s = cs.unbind(-1)
    o, one = torch.zeros_like(c), torch.ones_like(c)
    rows = [
        torch.stack([c, -s, o, dxy[..., 0]], -1),
        torch.stack([s, c, o, dxy[..., 1]], -1),
        torch.stack([o, o, one, o], -1),
        torch.stack([o, o, o, one], -1),
    ]
    return torch.stack(rows, -2)


ALIGNMENT_TIE_TOL = 1e-4
"""Relative tolerance under which the two candidate x axes of the shape alignment tie."""


def _alignment_axes(
    poses: torch.Tensor, params: torch.Tensor, kinds: torch.Tensor, e_tol: float
) -> tuple[torch.Tensor, ...]:
    """The action-independent half of :func:`align_objects`: which objects are aligned
    (``ok``), their new z axis (``z_idx``, ``z_sign``) and the two candidate x axes ``i1, i2``
    (cyclic after ``z_idx``); all ``(..., M)``."""
    zc = poses[..., 2, :3]  # (..., M, 3): world-z component of each object axis
    ok = (kinds == SUPERELLIPSOID) & (params[..., 5] == 0) & (params[..., 6] == 0)
    free_z = ok & ((params[..., 3] - params[..., 4]).abs() < e_tol)
    z_idx = torch.where(free_z, zc.abs().argmax(-1), torch.full_like(kinds, 2))
    z_val = zc.gather(-1, z_idx.unsqueeze(-1)).squeeze(-1)
    z_sign = torch.where(z_val < 0, -1.0, 1.0).to(poses.dtype)
    return ok, z_idx, z_sign, (z_idx + 1) % 3, (z_idx + 2) % 3


def _alignment_choice(
    R: torch.Tensor, i1: torch.Tensor, i2: torch.Tensor, v: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The action-dependent half: ``use1`` (x is axis ``i1``, else ``i2``) and the x sign.

    ``R (..., M, 3, 3)``, ``i1, i2 (..., M)``, ``v (..., 3)``; returns two ``(..., M)`` tensors.
    """
    vxy = torch.cat([v[..., :2], torch.zeros_like(v[..., :1])], -1).unsqueeze(-2)  # (..., 1, 3)
    d = (R * vxy.unsqueeze(-1)).sum(-2)  # (..., M, 3): push direction . axis
    d1, d2 = d.gather(-1, i1.unsqueeze(-1)).squeeze(-1), d.gather(-1, i2.unsqueeze(-1)).squeeze(-1)
    # Ties (|d1| = |d2|: the 4.5 sampler pushes along the object diagonals) go to i1 up to a
    # tolerance, so rounding of a transformed input cannot flip the variant (equivariance).
    tol = ALIGNMENT_TIE_TOL * torch.linalg.vector_norm(vxy, dim=-1)  # (..., 1)
    use1 = d1.abs() >= d2.abs() - tol
    x_val = torch.where(use1, d1, d2)
    return use1, torch.where(x_val < 0, -1.0, 1.0).to(R.dtype)


def _alignment_apply(
    poses: torch.Tensor,
    params: torch.Tensor,
    ok: torch.Tensor,
    z_idx: torch.Tensor,
    z_sign: torch.Tensor,
    x_idx: torch.Tensor,
    x_sign: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(T P, permuted params, P)`` from the chosen axes (shapes as :func:`align_objects`)."""
    eye = torch.eye(3, dtype=poses.dtype, device=poses.device)
    ex = eye[x_idx] * x_sign.unsqueeze(-1)  # new x axis in old object coordinates
    ez = eye[z_idx] * z_sign.unsqueeze(-1)
    ey = torch.linalg.cross(ez, ex)
    P3 = torch.stack([ex, ey, ez], -1)  # columns: new axes in old coordinates
    P3 = torch.where(ok[..., None, None], P3, eye.expand_as(P3))
    P = torch.zeros_like(poses)
    P[..., :3, :3] = P3
    P[..., 3, 3] = 1.0
    # Sizes follow their axes: new a_k = old a_{axis(k)}; P3 entries are 0/+-1.
    a = params[..., :3].unsqueeze(-2)  # (..., M, 1, 3)
    a_new = (P3.abs().transpose(-1, -2) * a).sum(-1)  # (..., M, 3)
    params = torch.cat([a_new, params[..., 3:]], -1)
    return poses @ P, params, P


def align_objects(
    poses: torch.Tensor,
    params: torch.Tensor,
    kinds: torch.Tensor,
    v: torch.Tensor,
    e_tol: float = 0.01,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Shape alignment of 4.6: relabel object axes so z points up and x along the push.

    ``poses (..., M, 4, 4)``, ``params (..., M, 9)``, ``kinds (..., M)``, ``v (..., 3)``.
    Returns aligned poses ``T P``, params with ``a1 a2 a3`` permuted, and ``P (..., M, 4, 4)``,
    a rotation that permutes and flips axes (so ``T = T_aligned P^T``).

    Convention: only undeformed superellipsoids (``k = b = 0``) are aligned (for them an axis
    relabelling with permuted sizes describes the same solid). If ``|e1 - e2| < e_tol`` any
    axis may become z (the one closest to world z; the same solid for ``e1 = e2``, close to it
    for nearly equal exponents), otherwise z keeps its axis and only its sign changes. x is the
    remaining axis closest (up to sign) to the horizontal push direction.

    The action only picks one of four variants per object (x is axis ``i1`` or ``i2``, with
    either sign); :meth:`SQPDNet.predict` exploits this to encode each object once per variant.
    """
    ok, z_idx, z_sign, i1, i2 = _alignment_axes(poses, params, kinds, e_tol)
    use1, x_sign = _alignment_choice(poses[..., :3, :3], i1, i2, v)
    x_idx = torch.where(use1, i1, i2)
    return _alignment_apply(poses, params, ok, z_idx, z_sign, x_idx, x_sign)


# --- loss (4.3.3) ---------------------------------------------------------------------------------


def rotation_cos(R1: torch.Tensor, R2: torch.Tensor) -> torch.Tensor:
    """``cos`` of the angle of ``R1^T R2`` from its trace, ``(..., 3, 3) -> (...)``, in [-1, 1].

    For rotations about z this is ``cos(theta_1 - theta_2)`` of (B.3.11).
    """
    tr = (R1 * R2).sum((-1, -2))  # trace(R1^T R2)
    return ((tr - 1.0) / 2.0).clamp(-1.0, 1.0)


def sqpd_loss(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, alpha: float = 0.1
) -> tuple[torch.Tensor, dict[str, float]]:
    """The pushing loss (4.3.3) averaged over real objects.

    ``||t' - t^'||^2 + alpha d^2(I, R'^{-1} R^')`` with ``d = 1 - cos(angle)`` (B.3.11).
    ``pred, target (..., M, 4, 4)``, ``mask (..., M)``. The thesis sums over the ``N`` objects
    of a tuple; averaging over all real objects of the batch (as the public code) weights
    1- and 4-object scenes alike. Returns ``(loss, {"loss", "translation", "rotation"})``; an
    all-padding batch gives 0.
    """
    if pred.shape != target.shape or pred.shape[-2:] != (4, 4):
        raise ValueError(
            f"pred and target must have equal shapes (..., M, 4, 4), got {tuple(pred.shape)} "
            f"and {tuple(target.shape)}"
        )
    if mask.shape != pred.shape[:-2]:
        raise ValueError(f"mask must have shape {tuple(pred.shape[:-2])}, got {tuple(mask.shape)}")
    w = mask.to(pred.dtype)
    n = w.sum().clamp_min(1.0)
    trans = ((pred[..., :3, 3] - target[..., :3, 3]) ** 2).sum(-1)
    rot = (1.0 - rotation_cos(target[..., :3, :3], pred[..., :3, :3])) ** 2
    t_mean, r_mean = (trans * w).sum() / n, (rot * w).sum() / n
    loss = t_mean + alpha * r_mean
    return loss, {"loss": loss.item(), "translation": t_mean.item(), "rotation": r_mean.item()}


# --- the network ----------------------------------------------------------------------------------


class SQPDNet(nn.Module):
    """SQPD-Net (B.3). ``forward`` maps padded scenes and one action per scene to next poses."""

    def __init__(self, config: SQPDNetConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or SQPDNetConfig()
        f, slope = config.feature_dim, config.leaky_slope
        self.action_encoder = MLP(ACTION_DIM, config.action_hidden, f, slope)
        self.ego_encoder = MLP(OBJECT_DIM, config.ego_hidden, f, slope)
        self.scene_encoder = MLP(OBJECT_DIM, config.scene_hidden, f, slope)
        self.scene_post = MLP(f, config.scene_post_hidden, f, slope)
        # One decoder, as B.3 describes, with outputs (dx, dy, cos, sin).
        self.decoder = MLP(3 * f, config.decoder_hidden, 4, slope)
        # Start near "no motion": small (dx, dy) and (cos, sin) = (1, 0).
        with torch.no_grad():
            last = self.decoder[-1]
            last.weight.mul_(0.01)  # type: ignore[operator]
            last.bias.copy_(torch.tensor([0.0, 0.0, 1.0, 0.0]))  # type: ignore[operator]

    # -- frames: the SE(2) module; the baseline overrides these two methods ---------------------

    def input_frames(self, poses: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(C_i, U_i)`` for poses ``(..., M, 4, 4)``: the frames the inputs are expressed in."""
        return decompose_pose(poses)

    def compose(
        self, poses: torch.Tensor, C: torch.Tensor, U: torch.Tensor, dT: torch.Tensor
    ) -> torch.Tensor:
        """Apply the planar motion: ``T dT`` (4.3) or ``C dT U`` (``composition="table"``)."""
        if self.config.composition == "table":
            return C @ dT @ U
        return poses @ dT

    # -- forward ---------------------------------------------------------------------------------

    def forward(
        self,
        poses: torch.Tensor,
        params: torch.Tensor,
        kinds: torch.Tensor,
        mask: torch.Tensor,
        action_p: torch.Tensor,
        action_v: torch.Tensor,
    ) -> torch.Tensor:
        """Next poses ``(B, M, 4, 4)``.

        ``poses (B, M, 4, 4)``, ``params (B, M, 9)``, ``kinds (B, M)``, ``mask (B, M)`` (real
        objects), ``action_p, action_v (B, 3)``; padded rows are returned unchanged.
        """
        self._check(poses, params, kinds, mask, action_p, action_v)
        cfg = self.config
        if cfg.shape_alignment:
            poses_a, params_a, P = align_objects(
                poses, params, kinds, action_v, cfg.alignment_e_tol
            )
        else:
            poses_a, params_a, P = poses, params, None
        C, U = self.input_frames(poses_a)  # (B, M, 4, 4) each
        C_inv = se3_inverse(C)
        Rc = C_inv[..., :3, :3]  # (B, M, 3, 3)
        p_i = (Rc @ action_p[:, None, :, None]).squeeze(-1) + C_inv[..., :3, 3]  # (B, M, 3)
        v_i = (Rc @ action_v[:, None, :, None]).squeeze(-1)  # (B, M, 3)
        a = self.action_encoder(action_features(p_i, v_i))  # (B, M, F)
        b = self.ego_encoder(object_features(U, params_a))  # (B, M, F)
        rel = C_inv.unsqueeze(2) @ poses_a.unsqueeze(1)  # (B, M_i, M_j, 4, 4) = C_i^-1 T_j
        params_j = params_a.unsqueeze(1).expand(-1, rel.shape[1], -1, -1)  # (B, M_i, M_j, 9)
        c_ij = self.scene_encoder(object_features(rel, params_j))  # (B, M, M, F)
        neg = torch.finfo(c_ij.dtype).min
        c_ij = c_ij.masked_fill(~mask[:, None, :, None], neg)
        c = c_ij.amax(2)  # (B, M, F): max over the real objects j
        c = torch.where(mask.unsqueeze(-1), c, torch.zeros_like(c))
        c = self.scene_post(c)
        y = torch.cat([a, b, c], -1)  # (B, M, 3F)
        out = self.decoder(y)  # (B, M, 4)
        dT = planar_motion(out[..., :2], out[..., 2:])
        nxt = self.compose(poses_a, C, U, dT)
        if P is not None:
            nxt = nxt @ P.transpose(-1, -2)
        return torch.where(mask[..., None, None], nxt, poses)

    def _check(self, poses, params, kinds, mask, action_p, action_v) -> None:
        if poses.ndim != 4 or poses.shape[-2:] != (4, 4):
            raise ValueError(f"poses must have shape (B, M, 4, 4), got {tuple(poses.shape)}")
        b, m = poses.shape[:2]
        if m > self.config.max_objects:
            raise ValueError(
                f"poses has {m} objects, more than max_objects={self.config.max_objects}"
            )
        expected = {
            "params": (params, (b, m, N_PARAMS)),
            "kinds": (kinds, (b, m)),
            "mask": (mask, (b, m)),
            "action_p": (action_p, (b, 3)),
            "action_v": (action_v, (b, 3)),
        }
        for name, (x, shape) in expected.items():
            if tuple(x.shape) != shape:
                raise ValueError(f"{name} must have shape {shape}, got {tuple(x.shape)}")
        if mask.dtype != torch.bool:
            raise ValueError(f"mask must be bool, got {mask.dtype}")

    # -- training and inference helpers ------------------------------------------------------------

    def forward_batch(self, batch: PushBatch) -> torch.Tensor:
        return self(
            batch.poses, batch.params, batch.kinds, batch.mask, batch.action_p, batch.action_v
        )

    def loss(self, batch: PushBatch) -> tuple[torch.Tensor, dict[str, float]]:
        """``(loss, loss_dict)`` of (4.3.3) on a batch."""
        return sqpd_loss(self.forward_batch(batch), batch.next_poses, batch.mask, self.config.alpha)

    @torch.no_grad()
    def predict(
        self,
        poses: torch.Tensor | np.ndarray,
        params: torch.Tensor | np.ndarray,
        actions: torch.Tensor | np.ndarray,
        kinds: torch.Tensor | np.ndarray | Sequence[int] | None = None,
        *,
        fast: bool = True,
    ) -> torch.Tensor:
        """Next poses ``(K, N, 4, 4)`` of ``N`` objects under each of ``K`` actions, in one pass.

        ``poses (N, 4, 4)``, ``params (N, 9)``, ``actions (K, 6)`` rows ``(p, v)`` in the world
        frame, ``kinds (N,)`` (default all superellipsoids). MPC scores its 100 candidate pushes
        with one call.

        ``fast=True`` (default) encodes what does not depend on the action once
        (:meth:`_predict_fast`); ``fast=False`` is the reference: the scene broadcast over the
        action axis through :meth:`forward`. Both give the same poses to rounding (~1e-7 in
        float32, ~1e-15 in float64).
        """
        poses, params, actions, kinds_t = self._inputs(poses, params, actions, kinds, False)
        n, k = poses.shape[0], actions.shape[0]
        if k == 0 or n == 0:
            return poses.unsqueeze(0).expand(k, n, 4, 4).clone()
        if fast:
            return self._predict_fast(poses, params, kinds_t, actions)
        return self._forward_scenes(poses.unsqueeze(0).expand(k, n, 4, 4), params, kinds_t, actions)

    @torch.no_grad()
    def predict_batch(
        self,
        poses: torch.Tensor | np.ndarray,
        params: torch.Tensor | np.ndarray,
        actions: torch.Tensor | np.ndarray,
        kinds: torch.Tensor | np.ndarray | Sequence[int] | None = None,
    ) -> torch.Tensor:
        """Next poses ``(K, N, 4, 4)`` of ``K`` *different* scenes, one action each, in one pass.

        ``poses (K, N, 4, 4)``, ``params (N, 9)`` and ``kinds (N,)`` shared, ``actions (K, 6)``:
        the MPC's later horizon steps, where every sequence has its own predicted scene
        (:func:`sqmanip.planning.mpc.predict_scenes`).
        """
        poses, params, actions, kinds_t = self._inputs(poses, params, actions, kinds, True)
        if poses.shape[0] == 0 or poses.shape[1] == 0:
            return poses.clone()
        return self._forward_scenes(poses, params, kinds_t, actions)

    def _inputs(self, poses, params, actions, kinds, per_scene: bool):
        """The arguments of :meth:`predict` (``per_scene=False``: ``poses (N, 4, 4)``) or
        :meth:`predict_batch` (``poses (K, N, 4, 4)``, one row of ``actions`` per scene) as
        checked tensors in the model's dtype and device; ``kinds`` defaults to zeros."""
        self.eval()
        ref = next(self.parameters())
        poses = torch.as_tensor(poses, dtype=ref.dtype, device=ref.device)
        params = torch.as_tensor(params, dtype=ref.dtype, device=ref.device)
        actions = torch.as_tensor(actions, dtype=ref.dtype, device=ref.device)
        if poses.ndim != (4 if per_scene else 3) or poses.shape[-2:] != (4, 4):
            want = "(K, N, 4, 4)" if per_scene else "(N, 4, 4)"
            raise ValueError(f"poses must have shape {want}, got {tuple(poses.shape)}")
        n = poses.shape[-3]
        if n > self.config.max_objects:
            raise ValueError(
                f"poses has {n} objects, more than max_objects={self.config.max_objects}"
            )
        if params.shape != (n, N_PARAMS):
            raise ValueError(f"params must have shape ({n}, {N_PARAMS}), got {tuple(params.shape)}")
        if per_scene and actions.shape != (poses.shape[0], 6):
            raise ValueError(
                f"actions must have shape ({poses.shape[0]}, 6), got {tuple(actions.shape)}"
            )
        if actions.ndim != 2 or actions.shape[1] != 6:
            raise ValueError(f"actions must have shape (K, 6), got {tuple(actions.shape)}")
        if kinds is None:
            kinds_t = torch.zeros(n, dtype=torch.long, device=ref.device)
        else:
            kinds_t = torch.as_tensor(kinds, dtype=torch.long, device=ref.device)
            if kinds_t.shape != (n,):
                raise ValueError(f"kinds must have shape ({n},), got {tuple(kinds_t.shape)}")
        return poses, params, actions, kinds_t

    def _forward_scenes(
        self, poses: torch.Tensor, params: torch.Tensor, kinds: torch.Tensor, actions: torch.Tensor
    ) -> torch.Tensor:
        """:meth:`forward` on ``K`` scenes ``poses (K, N, 4, 4)`` sharing ``params`` / ``kinds``,
        all objects real, action ``k`` on scene ``k``."""
        k, n = poses.shape[:2]
        return self(
            poses,
            params.unsqueeze(0).expand(k, n, N_PARAMS),
            kinds.unsqueeze(0).expand(k, n),
            torch.ones(k, n, dtype=torch.bool, device=poses.device),
            actions[:, :3],
            actions[:, 3:],
        )

    def _predict_fast(
        self, poses: torch.Tensor, params: torch.Tensor, kinds: torch.Tensor, actions: torch.Tensor
    ) -> torch.Tensor:
        """:meth:`forward` for one scene ``(N, ...)`` and ``K`` actions, sharing the scene work.

        Only two things in :meth:`forward` depend on the action: the action encoding and, through
        the shape alignment, which of ``V = 4`` axis relabellings each object gets (x along
        ``i1`` or ``i2``, either sign; :func:`align_objects`). So:

        1. build the ``V`` aligned variants of every object and their frames ``C, U`` (B.1.1);
        2. encode the ego input per (variant, object) and the scene input ``C_i^{-1} T_j`` per
           (variant of i, i, variant of j, j): ``V N + V^2 N^2`` rows instead of ``K N (1 + N)``;
        3. per action, a variant code per object; the distinct code tuples (at most ``V N`` for
           a circle of push directions, whatever ``K``) get the max-pool and ``scene_post``;
        4. the decoder's first layer is split column-wise, ``W [a; b; c] = W_a a + W_b b +
           W_c c``: ``W_b b`` and ``W_c c`` are computed per variant / code tuple and gathered,
           so per (action, object) only the action encoder, ``W_a a`` and the rest of the
           decoder run.

        This is ~3x fewer multiply-adds than :meth:`forward` for 100 actions x 4 objects; the
        result equals it up to floating-point summation order. No ``mask``: all objects are real.
        """
        cfg = self.config
        n, k = poses.shape[0], actions.shape[0]
        dev = poses.device
        p, v = actions[:, :3], actions[:, 3:]
        ar = torch.arange(n, device=dev)
        if cfg.shape_alignment:
            ok, z_idx, z_sign, i1, i2 = _alignment_axes(poses, params, kinds, cfg.alignment_e_tol)
            nv = 4
            x_idx = torch.stack([i1, i1, i2, i2])  # (V, N)
            x_sign = torch.tensor([1.0, -1.0, 1.0, -1.0], dtype=poses.dtype, device=dev)
            x_sign = x_sign[:, None].expand(nv, n)
            poses_v, params_v, P_v = _alignment_apply(
                poses.expand(nv, n, 4, 4),
                params.expand(nv, n, N_PARAMS),
                ok.expand(nv, n),
                z_idx.expand(nv, n),
                z_sign.expand(nv, n),
                x_idx,
                x_sign,
            )  # (V, N, 4, 4), (V, N, 9), (V, N, 4, 4)
            use1, xs = _alignment_choice(poses[:, :3, :3], i1.expand(k, n), i2.expand(k, n), v)
            code = torch.where(use1, 0, 2) + (xs < 0).long()
            code = torch.where(ok, code, 0)  # unaligned objects: all variants are the same
        else:
            nv = 1
            poses_v, params_v, P_v = poses.unsqueeze(0), params.unsqueeze(0), None
            code = torch.zeros(k, n, dtype=torch.long, device=dev)
        C, U = self.input_frames(poses_v)  # (V, N, 4, 4)
        C_inv = se3_inverse(C)
        f = cfg.feature_dim
        lin0 = self.decoder[0]
        W = lin0.weight  # (H, 3F): columns for [a, b, c]
        # Ego features per (variant, object), through W_b.
        b = self.ego_encoder(object_features(U, params_v))  # (V, N, F)
        hb = b @ W[:, f : 2 * f].T  # (V, N, H)
        # Scene features per (variant_i, i, variant_j, j).
        rel = C_inv[:, :, None, None] @ poses_v[None, None]  # (V, N, V, N, 4, 4)
        params_j = params_v[None, None].expand(nv, n, nv, n, N_PARAMS)
        s = self.scene_encoder(object_features(rel, params_j))  # (V, N, V, N, F)
        # Distinct variant tuples over the actions: max-pool, scene_post and W_c once each.
        radix = nv ** torch.arange(n, device=dev)
        uniq, inv = torch.unique((code * radix).sum(-1), return_inverse=True)  # (Q,), (K,)
        q = uniq.shape[0]
        cu = torch.div(uniq[:, None], radix, rounding_mode="floor") % nv  # (Q, N)
        sq = s[cu[:, :, None], ar[None, :, None], cu[:, None, :], ar[None, None, :]]  # (Q,N,N,F)
        c = self.scene_post(sq.amax(2)).reshape(q * n, f)  # (Q N, F)
        W_fused, b_fused = self._fused_action_head()
        # Everything of the first decoder layer that is not the action: (Q N, H).
        h_obj = torch.addmm(hb[cu, ar].reshape(q * n, -1), c, W[:, 2 * f :].T)
        h_obj += lin0.bias + b_fused
        # Per (action, object), flattened to K N rows: frames of the chosen variants.
        frames = [C_inv, C, U, poses_v] + ([P_v] if P_v is not None else [])
        g = torch.stack(frames, 2).reshape(nv * n, len(frames), 4, 4)
        g = g.index_select(0, (code * n + ar).reshape(-1))  # (K N, 4 or 5, 4, 4)
        Rc, tc = g[:, 0, :3, :3], g[:, 0, :3, 3]
        p_i = (Rc @ p.repeat_interleave(n, 0).unsqueeze(-1)).squeeze(-1) + tc
        v_i = (Rc @ v.repeat_interleave(n, 0).unsqueeze(-1)).squeeze(-1)
        x = action_features(p_i, v_i)  # (K N, 5)
        enc = list(self.action_encoder)
        x = _run_layers(enc[:-1], x)  # action encoder up to its last (linear) layer
        rows = (inv[:, None] * n + ar).reshape(-1)
        h = torch.addmm(h_obj.index_select(0, rows), x, W_fused.T)  # (K N, H)
        out = _run_layers(list(self.decoder)[1:], h)  # (K N, 4)
        dT = planar_motion(out[:, :2], out[:, 2:])
        nxt = self.compose(g[:, 3], g[:, 1], g[:, 2], dT)
        if P_v is not None:
            nxt = nxt @ g[:, 4].transpose(-1, -2)
        return nxt.reshape(k, n, 4, 4)

    def _fused_action_head(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(W_a W_L, W_a b_L)``: the action encoder's last linear layer ``L`` followed by the
        decoder's first-layer block ``W_a`` (no nonlinearity between them), as one layer.

        Cached; the cache key holds the tensors' version counters, so optimiser steps,
        ``load_state_dict`` and ``.to()`` invalidate it.
        """
        last, lin0 = self.action_encoder[-1], self.decoder[0]
        tensors = (last.weight, last.bias, lin0.weight, lin0.bias)
        key = tuple((t.data_ptr(), t._version, t.dtype, t.device) for t in tensors)
        cache = self.__dict__.get("_fused_cache")
        if cache is None or cache[0] != key:
            with torch.no_grad():
                W_a = lin0.weight[:, : self.config.feature_dim]
                cache = (key, W_a @ last.weight, W_a @ last.bias)
            self.__dict__["_fused_cache"] = cache
        return cache[1], cache[2]


def _run_layers(layers: Sequence[nn.Module], x: torch.Tensor) -> torch.Tensor:
    """Run ``Linear`` / ``LeakyReLU`` layers on ``x (R, D)`` (inference only; in place)."""
    for layer in layers:
        if isinstance(layer, nn.Linear):
            x = torch.addmm(layer.bias, x, layer.weight.T)
        elif isinstance(layer, nn.LeakyReLU):
            x = torch.nn.functional.leaky_relu_(x, layer.negative_slope)
        else:
            x = layer(x)
    return x


def make_model(config: SQPDNetConfig) -> SQPDNet:
    """SQPD-Net for ``config.equivariant``, else the 4.7.1 baseline (imported lazily)."""
    if config.equivariant:
        return SQPDNet(config)
    from .baselines import WorldFrameNet

    return WorldFrameNet(config)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
