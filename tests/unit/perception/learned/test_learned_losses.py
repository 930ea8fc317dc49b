"""Losses: DSQNet loss (3.3.6), the CPU preset's extra terms and the Hungarian-matched
segmentation loss (A.2)."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from sqmanip.geometry.sampling import sample_surface
from sqmanip.geometry.transforms import quat_normalize, quat_to_matrix
from sqmanip.perception.learned.losses import (
    dsq_loss,
    hungarian_match,
    segmentation_loss,
    shape_parameter_loss,
    surface_to_points,
)
from sqmanip.perception.learned.models import SQPrediction


def _prediction(requires_grad=False) -> SQPrediction:
    q = quat_normalize(torch.tensor([[0.2, -0.1, 0.3, 0.9]]))
    pred = SQPrediction(
        position=torch.tensor([[0.1, -0.05, 0.02]]),
        quaternion=q,
        size=torch.tensor([[0.1, 0.12, 0.3]], requires_grad=requires_grad),
        shape=torch.tensor([[0.4, 0.8]]),
        taper=torch.tensor([0.3]),
        bend=torch.tensor([0.5]),
        bend_direction=torch.tensor([[0.6, 0.8]]),
    )
    return pred


def test_dsq_loss_vanishes_on_the_predicted_surface():
    pred = _prediction()
    pts, _ = sample_surface(pred.params().double(), 400, generator=0)
    T = pred.pose().double()
    world = (pts @ T[:, :3, :3].transpose(1, 2) + T[:, None, :3, 3]).float()
    loss, logs = dsq_loss(pred, world, T[:, :3, 2].float())
    assert logs["dist"] < 1e-8 and logs["z_reg"] < 1e-10
    loss_far, _ = dsq_loss(pred, world * 1.3, -T[:, :3, 2].float())
    assert loss_far > 1e-4


def test_dsq_loss_weights_the_z_axis_term():
    pred = _prediction()
    pts = torch.zeros(1, 5, 3)
    z_perp = torch.linalg.cross(pred.pose()[:, :3, 2], torch.tensor([[1.0, 0.0, 0.0]]))
    z_perp = z_perp / z_perp.norm()
    l0, _ = dsq_loss(pred, pts, None)
    l1, logs = dsq_loss(pred, pts, z_perp, z_weight=0.01)
    torch.testing.assert_close(logs["z_reg"], 1.0, atol=1e-5, rtol=0)
    torch.testing.assert_close(float(l1 - l0), 0.01, atol=1e-6, rtol=0)


def test_dsq_loss_has_finite_gradients():
    pred = _prediction(requires_grad=True)
    loss, _ = dsq_loss(pred, torch.randn(1, 50, 3) * 0.3, torch.tensor([[0.0, 0.0, 1.0]]))
    loss.backward()
    assert torch.isfinite(pred.size.grad).all() and pred.size.grad.abs().sum() > 0


def _surface_points(pred: SQPrediction, n: int = 1500) -> torch.Tensor:
    pts, _ = sample_surface(pred.params().double(), n, generator=0)
    T = pred.pose().double()
    return (pts @ T[:, :3, :3].transpose(1, 2) + T[:, None, :3, 3]).float()


def test_surface_term_punishes_predicted_surface_far_from_the_points():
    """(3.3.5) cannot see a prediction that is too long; the surface term can."""
    pred = _prediction()
    gt = _surface_points(pred)
    assert float(surface_to_points(pred, gt)) < 1e-4
    longer = dataclasses.replace(pred, size=pred.size * torch.tensor([1.0, 1.0, 2.0]))
    assert float(surface_to_points(longer, gt)) > 30 * float(surface_to_points(pred, gt))


def test_shape_term_is_zero_for_the_truth_and_blind_to_a_flipped_z_axis():
    pred = _prediction()
    gt_params = pred.params().clone()
    R = pred.pose()[:, :3, :3]
    assert float(shape_parameter_loss(pred, gt_params, R)) < 1e-10
    # the same tapered, bent shape described upside down: z -> -z (a turn about x), taper -k,
    # bending direction mirrored in the new frame (y -> -y)
    flip = torch.diag(torch.tensor([1.0, -1.0, -1.0]))
    a = gt_params[:, 7]
    upside_down = gt_params.clone()
    upside_down[:, 5] = -gt_params[:, 5]
    upside_down[:, 7] = -a
    assert float(shape_parameter_loss(pred, upside_down, R @ flip)) < 1e-10
    wrong = gt_params.clone()
    wrong[:, 3] += 0.3
    assert float(shape_parameter_loss(pred, wrong, R)) > 0.05


def test_shape_term_penalises_the_wrong_bending_direction():
    pred = _prediction()
    gt_params = pred.params().clone()
    R = pred.pose()[:, :3, :3]
    gt_params[:, 7] += torch.pi
    assert float(shape_parameter_loss(pred, gt_params, R)) > 1.9
    assert float(shape_parameter_loss(pred, gt_params, R, deformable=False)) < 1e-10


def test_shape_term_ignores_exponents_when_the_z_axes_are_perpendicular():
    pred = _prediction()
    gt_params = pred.params().clone()
    gt_params[:, 3:5] = torch.tensor([1.5, 0.2])
    turn = quat_to_matrix(torch.tensor([0.7071068, 0.0, 0.0, 0.7071068]))  # 90 deg about x
    R = pred.pose()[:, :3, :3] @ turn
    assert float(shape_parameter_loss(pred, gt_params, R, deformable=False)) < 1e-10


def test_shape_term_sizes_ignore_a_quarter_turn_about_z_and_see_a_wrong_length():
    pred = _prediction()
    gt_params = pred.params().clone()
    R = pred.pose()[:, :3, :3]
    quarter = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    turned = gt_params.clone()
    turned[:, [0, 1]] = gt_params[:, [1, 0]]  # a1 <-> a2: the same shape turned by 90 degrees
    turned[:, 7] -= torch.pi / 2
    assert float(shape_parameter_loss(pred, turned, R @ quarter, size_weight=10.0)) < 1e-10
    longer = gt_params.clone()
    longer[:, 2] += 0.1
    assert float(shape_parameter_loss(pred, longer, R)) < 1e-10  # sizes off by default
    assert float(shape_parameter_loss(pred, longer, R, size_weight=10.0)) == pytest.approx(
        0.1, rel=1e-5
    )


def test_hungarian_loss_is_invariant_to_label_permutation():
    g = torch.Generator().manual_seed(0)
    logits = torch.randn(4, 100, 5, generator=g)
    labels = torch.randint(0, 3, (4, 100), generator=g)
    perm = torch.tensor([2, 0, 1])
    loss_a, _ = segmentation_loss(logits, labels)
    loss_b, _ = segmentation_loss(logits, perm[labels])
    torch.testing.assert_close(loss_a, loss_b, atol=1e-6, rtol=0)


def test_hungarian_match_finds_the_relabelling():
    labels = torch.tensor([[0, 0, 1, 1, 2, 2, -1]])
    predicted = torch.tensor([[3, 3, 0, 0, 1, 1, 1]])
    logits = torch.nn.functional.one_hot(predicted, 4).float() * 20
    matched = hungarian_match(torch.log_softmax(logits, -1), labels)
    assert matched.tolist() == [[3, 3, 0, 0, 1, 1, -1]]
    loss, logs = segmentation_loss(logits, labels)
    assert logs["acc"] == 1.0 and float(loss) < 1e-6
    plain = torch.nn.functional.cross_entropy(logits[0, :6], labels[0, :6])
    assert plain > 10  # the unmatched loss would punish a correct segmentation
