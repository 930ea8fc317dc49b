"""Losses: DSQNet loss (3.3.6) and the Hungarian-matched segmentation loss (A.2)."""

from __future__ import annotations

import torch
from sqmanip.geometry.sampling import sample_surface
from sqmanip.geometry.transforms import quat_normalize
from sqmanip.perception.learned.losses import dsq_loss, hungarian_match, segmentation_loss
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
