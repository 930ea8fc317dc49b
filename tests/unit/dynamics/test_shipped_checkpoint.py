"""The shipped GT-SQPD-Net checkpoint (models/sqpdnet, issue 7 item 4).

It must load as the dynamics service loads it (``torch.load(weights_only=True)``), stay small,
predict finite poses for a small tabletop scene, be SE(2)-equivariant (Definition 4.1: transform
objects and action together by any planar ``C`` of (4.3.2) and the prediction moves by ``C``),
and have learned the basic push: an object pushed through its centre moves along the push.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
from sqmanip.dynamics.config import SQPDNetConfig
from sqmanip.dynamics.model import SQPDNet
from sqmanip.dynamics.server import load_checkpoint
from sqmanip.geometry.transforms import se2_matrix

REPO = Path(__file__).resolve().parents[3]
MODEL_DIR = REPO / "models" / "sqpdnet"


@pytest.fixture(scope="module")
def model() -> SQPDNet:
    return load_checkpoint(MODEL_DIR)


def _scene() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Two upright objects (a box and a cylinder-like superellipsoid) and 6 pushes, float64."""
    poses = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    yaw = 0.4
    poses[0, :2, :2] = torch.tensor(
        [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]], dtype=torch.float64
    )
    poses[0, :3, 3] = torch.tensor([0.45, 0.0, 0.03])
    poses[1, :3, 3] = torch.tensor([0.55, 0.12, 0.04])
    params = torch.zeros(2, 9, dtype=torch.float64)
    params[0, :5] = torch.tensor([0.03, 0.025, 0.03, 0.2, 0.2])
    params[1, :5] = torch.tensor([0.025, 0.025, 0.04, 0.2, 1.0])
    # Pushes of 10 cm toward the first object's centre from 8 cm away, 1 cm above the table.
    angles = torch.linspace(0, 2 * math.pi, 7, dtype=torch.float64)[:-1]
    v = 0.1 * torch.stack([torch.cos(angles), torch.sin(angles), 0 * angles], -1)
    p = poses[0, :3, 3] - 0.8 * v
    p[:, 2] = 0.01
    return poses, params, torch.cat([p, v], -1)


def test_checkpoint_loads_weights_only_and_is_small() -> None:
    weights = MODEL_DIR / "model.pt"
    assert weights.stat().st_size < 5 * 2**20
    state = torch.load(weights, map_location="cpu", weights_only=True)
    assert state and all(isinstance(t, torch.Tensor) for t in state.values())
    assert all(torch.isfinite(t).all() for t in state.values())
    config = SQPDNetConfig.load(MODEL_DIR / "config.json")
    assert config.equivariant and config.shape_alignment


def test_predicts_finite_rigid_poses(model: SQPDNet) -> None:
    poses, params, actions = _scene()
    out = model.predict(poses.float(), params.float(), actions.float())
    assert out.shape == (6, 2, 4, 4)
    assert torch.isfinite(out).all()
    R = out[..., :3, :3].double()
    eye = torch.eye(3, dtype=torch.float64).expand_as(R)
    torch.testing.assert_close(R.transpose(-1, -2) @ R, eye, atol=1e-5, rtol=0)
    # A push is planar: heights stay put and no object jumps more than the push length.
    torch.testing.assert_close(out[..., 2, 3], poses[:, 2, 3].float().expand(6, 2), atol=1e-5,
                               rtol=0)  # fmt: skip
    assert (out[..., :2, 3] - poses[:, :2, 3].float()).norm(dim=-1).max() < 0.15


def test_pushed_object_moves_along_the_push(model: SQPDNet) -> None:
    poses, params, actions = _scene()
    out = model.predict(poses.float(), params.float(), actions.float()).double()
    disp = out[:, 0, :2, 3] - poses[0, :2, 3]  # (6, 2)
    along = (disp * actions[:, 3:5]).sum(-1) / actions[:, 3:5].norm(dim=-1)
    assert (along > 0.005).all(), along


def test_se2_equivariant(model: SQPDNet) -> None:
    net = load_checkpoint(MODEL_DIR).double()
    poses, params, actions = _scene()
    base = net.predict(poses, params, actions)
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        th, tx, ty = (torch.rand(3, generator=gen, dtype=torch.float64) * 2 - 1) * torch.tensor(
            [math.pi, 0.2, 0.2], dtype=torch.float64
        )
        C = se2_matrix(th, tx, ty).to(torch.float64)
        acts = torch.cat([actions[:, :3] @ C[:3, :3].T + C[:3, 3], actions[:, 3:] @ C[:3, :3].T], 1)
        moved = net.predict(C @ poses, params, acts)
        torch.testing.assert_close(moved, C @ base, atol=1e-9, rtol=0)
