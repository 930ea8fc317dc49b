"""Learned baselines for SQPD-Net (Ch. 4.7.1).

:class:`WorldFrameNet` is "SQPD-Net" without the SE(2)-equivariant module: the same encoders,
pooling and decoder (same widths, loss and schedule), but every input stays in the world frame
(``C_i = I``: the action is ``(p, cos, sin)`` of the world push, the ego input is ``(T_i, q_i)``
and the scene inputs are ``(T_j, q_j)``), and the predicted planar motion is applied in the world
frame about the object's origin: ``R' = dR R``, ``t' = t + (dx, dy, 0)``. It is trained with
random SE(2) augmentation (:func:`se2_augment`, ``config.augment_se2``), so it can only learn
equivariance approximately, from data (Figure 4.19, Table 4.4).

The shape-alignment switch (``config.shape_alignment``) is independent, giving the four rows
of Table 4.4. The physics baseline of 4.7.4 (re-simulating the superquadrics in PyBullet) lives
with the simulator.
"""

from __future__ import annotations

import math

import torch

from sqmanip.geometry.transforms import se2_matrix

from .data import PushBatch
from .model import SQPDNet

__all__ = ["WorldFrameNet", "se2_augment"]


class WorldFrameNet(SQPDNet):
    """SQPD-Net's network on raw world-frame inputs (no equivariant transform), 4.7.1."""

    def input_frames(self, poses: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        eye = torch.eye(4, dtype=poses.dtype, device=poses.device).expand_as(poses)
        return eye, poses

    def compose(
        self, poses: torch.Tensor, C: torch.Tensor, U: torch.Tensor, dT: torch.Tensor
    ) -> torch.Tensor:
        out = poses.clone()
        out[..., :3, :3] = dT[..., :3, :3] @ poses[..., :3, :3]
        out[..., :3, 3] = poses[..., :3, 3] + dT[..., :3, 3]
        return out


def se2_augment(
    batch: PushBatch, generator: torch.Generator | None = None, translation: float = 0.25
) -> PushBatch:
    """Apply one random ``C`` of the form (4.3.2) per tuple to scene, action and next scene.

    ``theta ~ U[-pi, pi)``, ``(tx, ty) ~ U[-translation, translation]^2``; ``T -> C T``,
    ``T' -> C T'``, ``p -> Rot(z) p + t_xy``, ``v -> Rot(z) v`` (Definition 4.1), so the
    augmented tuple is what an SE(2)-equivariant world would produce.
    """
    b = len(batch)
    dtype, device = batch.poses.dtype, batch.poses.device
    u = torch.rand(b, 3, generator=generator, dtype=torch.float64)
    theta = (u[:, 0] * 2 - 1) * math.pi
    t = (u[:, 1:] * 2 - 1) * translation
    C = se2_matrix(theta, t[:, 0], t[:, 1]).to(dtype=dtype, device=device)  # (B, 4, 4)
    R, tr = C[:, :3, :3], C[:, :3, 3]
    return PushBatch(
        poses=C[:, None] @ batch.poses,
        params=batch.params,
        kinds=batch.kinds,
        mask=batch.mask,
        action_p=(R @ batch.action_p.unsqueeze(-1)).squeeze(-1) + tr,
        action_v=(R @ batch.action_v.unsqueeze(-1)).squeeze(-1),
        next_poses=C[:, None] @ batch.next_poses,
    )
