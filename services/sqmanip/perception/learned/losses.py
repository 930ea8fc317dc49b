"""Training losses: the DSQNet loss (3.3.5-3.3.6) and the Hungarian-matched segmentation loss (A.2).

Both return ``(loss, {name: float})`` (a scalar tensor and detached logging values).

Two optional terms that are not in the thesis speed up training on a CPU budget (the ``cpu``
preset turns them on, the ``gpu`` preset keeps the loss of 3.3.6 alone):

- :func:`surface_to_points`: (3.3.5) pulls the ground-truth points onto the predicted surface
  but leaves predicted surface that has no ground truth near it (a fat or overlong shape)
  unpunished; this term measures that other direction.
- :func:`shape_parameter_loss`: the dataset knows the exponents, taper and bending it drew, and
  those do not depend on where the shape's frame sits, so they can be supervised directly. Through
  (3.3.5) alone their gradients are weak: after 10,000 steps a network still predicted rounded
  boxes, untapered cones and tori bent the wrong way (models/dsqnet_cpu's card).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from scipy.optimize import linear_sum_assignment

from sqmanip.geometry.sampling import sample_surface_angles
from sqmanip.geometry.superquadric import radial_distance

from .models import SQPrediction

__all__ = [
    "dsq_loss",
    "hungarian_match",
    "matched_accuracy",
    "segmentation_loss",
    "shape_parameter_loss",
    "surface_to_points",
]

BENT = 0.05
"""Ground-truth ``b'`` above which a shape counts as bent and its bending direction is supervised."""


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


def surface_to_points(pred: SQPrediction, gt_points: torch.Tensor) -> torch.Tensor:
    """Mean squared distance from the predicted surface to its nearest ground-truth point.

    The surface is a 12 x 16 grid of the angles of (2.2.2), deformed (2.3.3) and posed; the
    nearest point is found without gradient, the distance to it carries one. ``gt_points
    (B, N_g, 3)`` in the prediction's frame; returns a scalar (mean over the batch).
    """
    T = pred.pose()
    surf = sample_surface_angles(pred.params(), 12, 16) @ T[:, :3, :3].transpose(1, 2)
    surf = surf + T[:, None, :3, 3]
    with torch.no_grad():
        nearest = torch.cdist(surf, gt_points).argmin(-1)  # cdist's backward is slow on a CPU
    target = torch.gather(gt_points, 1, nearest.unsqueeze(-1).expand(-1, -1, 3))
    return ((surf - target) ** 2).sum(-1).mean()


def shape_parameter_loss(
    pred: SQPrediction,
    gt_params: torch.Tensor,
    gt_rotation: torch.Tensor,
    *,
    deformable: bool = True,
    size_weight: float = 0.0,
    bend_bounds: tuple[float, float] = (0.01, 0.75),
) -> torch.Tensor:
    """Squared errors of the parameters that a choice of frame leaves unchanged (scalar).

    ``gt_params (B, 9)`` packed ground truth (lengths in the prediction's units) and
    ``gt_rotation (B, 3, 3)`` its rotation in the prediction's frame. Terms, averaged over the
    batch:

    - exponents ``e`` and taper ``k`` (its sign follows the predicted z axis: a cone upside down
      is the same cone with ``-k``), weighted by ``(z . z_g)^2`` since both are defined along
      the z axis;
    - ``b' = max(a1, a2) b`` against the ground truth's clamped to ``bend_bounds`` (the
      model's output bounds, Table 3.1);
    - for bent shapes (``b' > BENT``), ``1 - cos`` of the angle between the predicted and the
      true bending direction ``R (cos alpha, sin alpha, 0)`` (unchanged by the z flip);
    - ``size_weight`` times the squared errors of ``a3`` and of the sorted pair ``(a1, a2)``
      (a quarter turn about z swaps them), weighted like the exponents. The dataset's bent tori
      sit in a local minimum of (3.3.5) without it: a fat tube, barely bent, lies closer to the
      arc's points than anything on the way to the thin bent one.

    ``deformable=False`` (SQNet) keeps the exponents and sizes only.
    """
    R = pred.pose()[:, :3, :3]
    cz = (R[:, :, 2] * gt_rotation[:, :, 2]).sum(-1)
    along_z = (cz * cz).detach()
    err = ((pred.shape - gt_params[:, 3:5]) ** 2).sum(-1)
    if size_weight > 0:
        a, a_gt = pred.size, gt_params[:, :3]
        pair = (a[:, :2].sort(-1).values - a_gt[:, :2].sort(-1).values) ** 2
        err = err + size_weight * (pair.sum(-1) + (a[:, 2] - a_gt[:, 2]) ** 2)
    if deformable:
        err = err + (pred.taper - torch.sign(cz).detach() * gt_params[:, 5]) ** 2
    loss = along_z * err
    if deformable:
        b_gt = gt_params[:, :2].amax(-1) * gt_params[:, 6]
        b_pred = pred.size[:, :2].amax(-1) * pred.bend
        loss = loss + (b_pred - b_gt.clamp(*bend_bounds)) ** 2
        d_pred = (R[:, :, :2] @ pred.bend_direction.unsqueeze(-1)).squeeze(-1)
        c, s = torch.cos(gt_params[:, 7]), torch.sin(gt_params[:, 7])
        d_gt = gt_rotation[:, :, 0] * c[:, None] + gt_rotation[:, :, 1] * s[:, None]
        loss = loss + (b_gt > BENT) * (1.0 - (d_pred * d_gt).sum(-1))
    return loss.mean()


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
