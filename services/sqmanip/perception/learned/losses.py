"""Training losses: the DSQNet loss (3.3.5-3.3.6) and the Hungarian-matched segmentation loss (A.2).

Both return ``(loss, {name: float})`` (a scalar tensor and detached logging values).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from scipy.optimize import linear_sum_assignment

from sqmanip.geometry.superquadric import radial_distance

from .models import SQPrediction

__all__ = ["dsq_loss", "hungarian_match", "matched_accuracy", "segmentation_loss"]


def dsq_loss(
    pred: SQPrediction,
    gt_points: torch.Tensor,
    gt_z: torch.Tensor | None = None,
    *,
    z_weight: float = 0.01,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Loss (3.3.6): ``mean_i delta^2(T^-1 x_g,i, f_D) + w ||z x z_g||^2``, averaged over the batch.

    ``gt_points (B, N_g, 3)`` are ground-truth surface points and ``gt_z (B, 3)`` the ground-truth
    object z axis, both in the normalised frame of the prediction. ``delta`` is the radial
    distance (3.3.4) of :func:`sqmanip.geometry.superquadric.radial_distance`. ``gt_z=None`` or
    ``z_weight=0`` drops the regulariser (3.3.5).
    """
    if gt_points.ndim != 3 or gt_points.shape[-1] != 3:
        raise ValueError(f"gt_points must have shape (B, N_g, 3), got {tuple(gt_points.shape)}")
    b = pred.position.shape[0]
    if gt_points.shape[0] != b:
        raise ValueError(f"gt_points must have batch size {b}, got {gt_points.shape[0]}")
    T = pred.pose()  # (B, 4, 4)
    R, p = T[:, :3, :3], T[:, :3, 3]
    local = (gt_points - p[:, None]) @ R  # R^T (x - p), row vectors: (B, N_g, 3)
    delta = radial_distance(local, pred.params())  # (B, N_g)
    dist = (delta**2).mean(-1).mean()
    logs = {"dist": float(dist.detach())}
    loss = dist
    if gt_z is not None and z_weight > 0:
        if gt_z.shape != (b, 3):
            raise ValueError(f"gt_z must have shape ({b}, 3), got {tuple(gt_z.shape)}")
        cross = torch.linalg.cross(R[:, :, 2], gt_z)
        reg = (cross**2).sum(-1).mean()
        loss = loss + z_weight * reg
        logs["z_reg"] = float(reg.detach())
    logs["loss"] = float(loss.detach())
    return loss, logs


def hungarian_match(log_probs: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Relabel ``labels (B, N)`` to the predicted labels that fit them best (A.2, Fig. A.3).

    For each cloud, ground-truth label ``g`` is matched one-to-one to the predicted label ``k``
    minimising the summed cross-entropy ``C[g, k] = -sum_{i: y_i = g} log p_ik`` (Hungarian
    algorithm, ``scipy.optimize.linear_sum_assignment``). Labels ``< 0`` are ignored and kept.
    Returns the matched targets ``(B, N)`` (long). ``log_probs (B, N, K)`` needs ``K`` at least
    the number of distinct labels per cloud.
    """
    if log_probs.ndim != 3 or labels.shape != log_probs.shape[:2]:
        raise ValueError(
            f"log_probs must be (B, N, K) and labels (B, N), got {tuple(log_probs.shape)} and "
            f"{tuple(labels.shape)}"
        )
    K = log_probs.shape[-1]
    labels = labels.long()
    G = int(labels.max()) + 1 if labels.numel() else 0
    if G > K:
        raise ValueError(f"labels must be < the number of predicted labels {K}, got label {G - 1}")
    if G <= 0:
        return labels.clone()
    onehot = F.one_hot(labels.clamp_min(0), G).to(log_probs.dtype) * (labels >= 0)[..., None]
    cost = -(onehot.transpose(1, 2) @ log_probs.detach())  # (B, G, K)
    present = onehot.sum(1) > 0  # (B, G)
    cost_np, present_np = cost.cpu().double().numpy(), present.cpu().numpy()
    lut = np.tile(np.arange(G), (labels.shape[0], 1))
    for i in range(labels.shape[0]):
        g = np.nonzero(present_np[i])[0]
        if len(g) == 0:
            continue
        rows, cols = linear_sum_assignment(cost_np[i][g])
        lut[i, g[rows]] = cols
    lut_t = torch.as_tensor(lut, device=labels.device)
    matched = torch.gather(lut_t, 1, labels.clamp_min(0))
    return torch.where(labels >= 0, matched, labels)


def segmentation_loss(
    logits: torch.Tensor, labels: torch.Tensor
) -> tuple[torch.Tensor, dict[str, float]]:
    """Permutation-invariant segmentation loss (A.2): cross-entropy after Hungarian matching.

    ``logits (B, N, K)``, ``labels (B, N)`` (``-1`` = ignore). Renaming the ground-truth labels of
    any cloud (a permutation of its label ids) leaves the loss unchanged.
    """
    logp = F.log_softmax(logits, -1)
    target = hungarian_match(logp, labels)
    valid = target >= 0
    nll = -torch.gather(logp, -1, target.clamp_min(0).unsqueeze(-1)).squeeze(-1)
    loss = (nll * valid).sum() / valid.sum().clamp_min(1)
    acc = ((logp.argmax(-1) == target) & valid).sum() / valid.sum().clamp_min(1)
    return loss, {"loss": float(loss.detach()), "acc": float(acc)}


@torch.no_grad()
def matched_accuracy(logits: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Per-cloud fraction of points whose predicted label equals the matched ground truth ``(B,)``."""
    logp = F.log_softmax(logits, -1)
    target = hungarian_match(logp, labels)
    valid = target >= 0
    return ((logp.argmax(-1) == target) & valid).sum(1) / valid.sum(1).clamp_min(1)
