"""SQPDNet.predict's shared-scene fast path equals the reference (broadcast forward) path."""

from __future__ import annotations

import math

import pytest
import torch
from dynamics_helpers import random_actions, random_scene
from sqmanip.dynamics.config import cpu_config
from sqmanip.dynamics.model import SQPDNet, make_model

VARIANTS = {
    "object": {},
    "table": {"composition": "table"},
    "no_alignment": {"shape_alignment": False},
    "baseline": {"equivariant": False},
}


def _model(dtype: torch.dtype, **overrides) -> SQPDNet:
    """A model whose output is far from identity (the init damps the last layer by 0.01), so
    that differences between the paths would show."""
    torch.manual_seed(3)
    model = make_model(cpu_config(**overrides)).to(dtype).eval()
    with torch.no_grad():
        for p in model.parameters():
            p.mul_(1.5)
        model.decoder[-1].weight.mul_(100.0)
    return model


def _scene(seed: int, n: int, dtype: torch.dtype):
    poses, params, kinds = random_scene(seed, n, dtype=dtype)
    if seed % 2:  # e1 = e2 on some objects: alignment may choose any axis as z
        params[::2, 4] = params[::2, 3]
    return poses, params, kinds


@pytest.mark.parametrize("variant", sorted(VARIANTS))
@pytest.mark.parametrize(("dtype", "atol"), [(torch.float32, 1e-6), (torch.float64, 1e-12)])
def test_fast_predict_equals_reference_path(variant, dtype, atol):
    model = _model(dtype, **VARIANTS[variant])
    moved = 0.0
    for seed in range(4):
        n = 1 + seed % 4
        poses, params, kinds = _scene(seed, n, dtype)
        actions = random_actions(seed, 100, dtype=dtype)
        fast = model.predict(poses, params, actions, kinds)
        ref = model.predict(poses, params, actions, kinds, fast=False)
        assert fast.shape == ref.shape == (100, n, 4, 4)
        torch.testing.assert_close(fast, ref, rtol=0, atol=atol)
        moved = max(moved, (ref - poses).abs().max().item())
    assert moved > 1e-3  # the comparison is not between two no-op outputs


def test_fast_predict_handles_many_distinct_alignment_variants():
    """Push directions all around the circle make every object take all four x-axis variants;
    the fast path still matches, and a deformed object (never aligned) does too."""
    model = _model(torch.float64)
    poses, params, kinds = _scene(5, 4, torch.float64)
    params[3, 5] = 0.3  # tapered: not aligned
    k = 64
    ang = torch.arange(k, dtype=torch.float64) * (2 * math.pi / k)
    actions = torch.zeros(k, 6, dtype=torch.float64)
    actions[:, :2] = 0.05 * torch.randn(k, 2, generator=torch.Generator().manual_seed(0))
    actions[:, 2] = 0.04
    actions[:, 3], actions[:, 4] = 0.1 * torch.cos(ang), 0.1 * torch.sin(ang)
    fast = model.predict(poses, params, actions, kinds)
    ref = model.predict(poses, params, actions, kinds, fast=False)
    torch.testing.assert_close(fast, ref, rtol=0, atol=1e-12)


def test_fused_action_head_cache_follows_weight_updates():
    """After an optimiser-style in-place update, predict uses the new weights (no stale cache)."""
    model = _model(torch.float64)
    poses, params, kinds = _scene(2, 3, torch.float64)
    actions = random_actions(2, 10)
    before = model.predict(poses, params, actions, kinds)
    with torch.no_grad():
        model.action_encoder[-1].weight.add_(0.5)
        model.decoder[0].weight.mul_(1.1)
    after = model.predict(poses, params, actions, kinds)
    ref = model.predict(poses, params, actions, kinds, fast=False)
    assert (after - before).abs().max().item() > 1e-6
    torch.testing.assert_close(after, ref, rtol=0, atol=1e-12)


def test_predict_batch_pushes_each_scene_like_predict_on_that_scene():
    """K different scenes in one pass (MPC horizon steps) = ``predict`` on each scene alone."""
    model = _model(torch.float64)
    poses, params, kinds = _scene(5, 3, torch.float64)
    actions = random_actions(6, 4, dtype=torch.float64)
    scenes = torch.stack(
        [model.predict(poses, params, actions[k : k + 1], kinds)[0] for k in range(4)]
    )  # four different scenes: each the outcome of one push
    batch = model.predict_batch(scenes, params, actions, kinds)
    alone = torch.stack(
        [model.predict(scenes[k], params, actions[k : k + 1], kinds)[0] for k in range(4)]
    )
    assert batch.shape == (4, 3, 4, 4)
    torch.testing.assert_close(batch, alone, atol=1e-10, rtol=0)
    with pytest.raises(ValueError, match="actions must have shape"):
        model.predict_batch(scenes, params, actions[:2], kinds)
