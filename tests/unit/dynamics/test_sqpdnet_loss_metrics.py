"""Loss (4.3.3) with d = 1 - cos (B.3.11), and the test metrics of 4.6."""

from __future__ import annotations

import math

import pytest
import torch
from dynamics_helpers import random_scene
from sqmanip.dynamics.metrics import (
    coordinate_flow_mse,
    flow_rmse,
    mask_iou_3d,
    pose_errors,
    surface_points,
    volume_points,
)
from sqmanip.dynamics.model import sqpd_loss
from sqmanip.geometry.transforms import se2_matrix, transform_points

F64 = torch.float64


def _poses(seed=0, n=3):
    return random_scene(seed, n)[0].unsqueeze(0)  # (1, N, 4, 4)


def test_loss_is_zero_for_identical_poses():
    T = _poses()
    loss, stats = sqpd_loss(T, T.clone(), torch.ones(1, 3, dtype=torch.bool))
    assert loss.item() == pytest.approx(0.0, abs=1e-15)
    assert stats["translation"] == pytest.approx(0.0, abs=1e-15)


def test_loss_is_symmetric():
    A, B = _poses(1), _poses(2)
    mask = torch.ones(1, 3, dtype=torch.bool)
    assert sqpd_loss(A, B, mask)[0].item() == pytest.approx(
        sqpd_loss(B, A, mask)[0].item(), rel=1e-12
    )


def test_loss_terms_have_the_thesis_weights():
    """Translation by d gives d^2; rotation by theta gives alpha (1 - cos theta)^2, alpha = 0.1."""
    T = _poses(3, 1)
    mask = torch.ones(1, 1, dtype=torch.bool)
    shifted = T.clone()
    shifted[..., :3, 3] += torch.tensor([0.03, -0.04, 0.0], dtype=F64)
    assert sqpd_loss(shifted, T, mask)[0].item() == pytest.approx(0.05**2, rel=1e-12)
    theta = 0.7
    rotated = T @ se2_matrix(torch.tensor(theta, dtype=F64), 0.0, 0.0)
    expected = 0.1 * (1 - math.cos(theta)) ** 2
    assert sqpd_loss(rotated, T, mask)[0].item() == pytest.approx(expected, rel=1e-9)
    assert sqpd_loss(rotated, T, mask, alpha=0.5)[0].item() == pytest.approx(5 * expected, rel=1e-9)


def test_loss_ignores_padding_and_survives_empty_batches():
    A, B = _poses(4), _poses(5)
    mask = torch.tensor([[True, False, False]])
    full = sqpd_loss(A[:, :1], B[:, :1], torch.ones(1, 1, dtype=torch.bool))[0]
    assert sqpd_loss(A, B, mask)[0].item() == pytest.approx(full.item(), rel=1e-12)
    empty = sqpd_loss(A, B, torch.zeros(1, 3, dtype=torch.bool))[0]
    assert empty.item() == 0.0
    with pytest.raises(ValueError, match="mask must have shape"):
        sqpd_loss(A, B, torch.ones(3, dtype=torch.bool))


def test_pose_and_flow_errors_of_a_known_offset():
    T = _poses(6)
    mask = torch.ones(1, 3, dtype=torch.bool)
    pred = T.clone()
    pred[..., :3, 3] += torch.tensor([0.0, 0.02, 0.0], dtype=F64)  # 2 cm
    pts = torch.randn(1, 3, 40, 3, dtype=F64) * 0.03
    errs = pose_errors(pred, T, mask)
    assert errs["position_cm"] == pytest.approx(2.0, rel=1e-9)
    assert errs["orientation_deg"] == pytest.approx(0.0, abs=1e-6)
    assert flow_rmse(pred, T, pts, mask) == pytest.approx(2.0, rel=1e-9)
    turned = T @ se2_matrix(torch.tensor(math.pi / 2, dtype=F64), 0.0, 0.0)
    assert pose_errors(turned, T, mask)["orientation_deg"] == pytest.approx(90.0, rel=1e-9)


def test_code_flow_error_is_the_mean_squared_coordinate_difference_of_the_same_points():
    """The authors' FlowError: sum((f_gt - f_pred)^2) / f.size in cm^2, no square root."""
    T = _poses(7)
    pred = T @ se2_matrix(torch.tensor(0.3, dtype=F64), 0.01, -0.02)
    mask = torch.ones(1, 3, dtype=torch.bool)
    pts = torch.randn(1, 3, 50, 3, dtype=F64) * 0.04
    flow_gt = (transform_points(T, pts) - pts) * 100.0  # cm; the start pose is the identity
    flow_pred = (transform_points(pred, pts) - pts) * 100.0
    expected = float(((flow_gt - flow_pred) ** 2).sum() / flow_pred.numel())
    got = coordinate_flow_mse(flow_rmse(pred, T, pts, mask))
    assert got == pytest.approx(expected, rel=1e-9)
    assert coordinate_flow_mse(2.0) == pytest.approx(4.0 / 3.0)


def test_volume_points_lie_inside_and_iou_is_one_for_identical_poses():
    poses, params, kinds = random_scene(8, 2)
    pts, pmask = volume_points(params.unsqueeze(0), kinds.unsqueeze(0), 64)
    assert pts.shape == (1, 2, 64, 3) and pmask.all()
    half = params[:, :3].unsqueeze(1)
    assert (pts[0].abs() <= half * 1.02).all()
    mask = torch.ones(1, 2, dtype=torch.bool)
    P = poses.unsqueeze(0)
    assert mask_iou_3d(params.unsqueeze(0), kinds.unsqueeze(0), P, P, mask, 16) == 1.0
    moved = P.clone()
    moved[..., 0, 3] += 1.0  # disjoint
    assert mask_iou_3d(params.unsqueeze(0), kinds.unsqueeze(0), moved, P, mask, 16) == 0.0


def test_point_samplers_skip_padding_rows():
    _, params, kinds = random_scene(9, 2)
    padded = torch.cat([params, torch.zeros(1, 9, dtype=F64)]).unsqueeze(0)  # (1, 3, 9)
    k = torch.zeros(1, 3, dtype=torch.long)
    surf = surface_points(padded, k, 16)
    assert torch.isfinite(surf).all() and (surf[0, 2] == 0).all()
    vol, vmask = volume_points(padded, k, 16)
    assert vmask[0, :2].all() and not vmask[0, 2].any()
