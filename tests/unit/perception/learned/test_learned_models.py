"""Networks (3.3.1, 3.6.2, A.2): PCA pre-processing, output bounds, invariance, factory, save/load."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
from sqmanip.geometry.transforms import pose_from_pq, quat_normalize
from sqmanip.perception.learned.config import load_preset, model_config
from sqmanip.perception.learned.models import (
    EdgeConv,
    PCANormalizer,
    build_model,
    count_parameters,
    graph_features,
)

TINY = dict(k=6, edge_widths=(16, 16, 16, 32), global_dim=64, head_widths=(32, 16))


def _cloud(b=3, n=200, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(b, n, 3, generator=g) * torch.tensor([0.05, 0.02, 0.1]) + 0.3


def _rand_pose(b, seed):
    g = torch.Generator().manual_seed(seed)
    return pose_from_pq(
        torch.randn(b, 3, generator=g), quat_normalize(torch.randn(b, 4, generator=g))
    )


def test_pca_frame_matches_3_3_1_and_round_trips():
    x = _cloud().double()
    xn, fr = PCANormalizer()(x)
    torch.testing.assert_close(xn.mean(1), torch.zeros(3, 3, dtype=x.dtype), atol=1e-12, rtol=0)
    diam = torch.cdist(xn, xn).flatten(1).amax(1)
    torch.testing.assert_close(diam, torch.ones(3, dtype=x.dtype))
    var = xn.var(1)  # axes [v2, v1, v3]: y has the least variance, z the most
    assert (var[:, 1] < var[:, 0]).all() and (var[:, 0] < var[:, 2]).all()
    R = fr.rotation
    torch.testing.assert_close(R.transpose(1, 2) @ R, torch.eye(3, dtype=x.dtype).expand(3, 3, 3))
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(3, dtype=x.dtype))
    torch.testing.assert_close(fr.invert(xn), x)
    T = _rand_pose(3, 1).double()
    torch.testing.assert_close(fr.pose_to_world(fr.pose_to_normalized(T)), T)
    p = torch.rand(3, 9, dtype=x.dtype)
    torch.testing.assert_close(fr.params_to_world(fr.params_to_normalized(p)), p)


def test_pca_normalisation_is_invariant_to_similarity_transforms():
    x = _cloud().double()
    T = _rand_pose(3, 2).double()
    y = 2.5 * (x @ T[:, :3, :3].transpose(1, 2)) + T[:, None, :3, 3]
    xn, _ = PCANormalizer()(x)
    yn, _ = PCANormalizer()(y)
    torch.testing.assert_close(xn, yn, atol=1e-6, rtol=0)  # T is float32-orthonormal


def test_pca_mask_uses_only_the_segment():
    x = _cloud(1).double()
    mask = torch.zeros(1, 200, dtype=torch.bool)
    mask[0, :80] = True
    xn, fr = PCANormalizer()(x, mask)
    seg_n, _ = PCANormalizer()(x[:, :80])
    torch.testing.assert_close(xn[:, :80], seg_n, atol=1e-9, rtol=0)


@pytest.mark.parametrize("name", ["dsqnet", "sqnet", "dsqnet_plus"])
def test_superquadric_outputs_respect_table_3_1(name):
    cfg = model_config(name, n_points=64, **TINY)
    net = build_model(name, cfg)
    for p in net.parameters():  # large weights push every sigmoid toward its bound
        torch.nn.init.normal_(p, std=3.0)
    net.eval()
    x = torch.randn(8, 64, cfg.in_dim) * 3
    out = net(x)
    assert out.params().shape == (8, 9) and out.pose().shape == (8, 4, 4)
    assert torch.isfinite(out.params()).all()
    assert ((out.size >= 0.03) & (out.size <= 0.53)).all()
    assert ((out.shape >= 0.2) & (out.shape <= 1.7)).all()
    torch.testing.assert_close(out.quaternion.norm(dim=-1), torch.ones(8))
    torch.testing.assert_close(out.bend_direction.norm(dim=-1), torch.ones(8))
    if name == "sqnet":
        assert (out.taper == 0).all() and (out.bend == 0).all()
    else:
        assert ((out.taper >= -0.9) & (out.taper <= 0.9)).all()
        b_prime = out.bend * out.size[:, :2].amax(-1)
        assert ((b_prime >= 0.01 - 1e-6) & (b_prime <= 0.75 + 1e-6)).all()


def test_segnet_outputs_per_point_logits():
    cfg = model_config("segnet", n_points=64, k=6, edge_widths=(16, 16), global_dim=32,
                       head_widths=(32,), max_labels=5)  # fmt: skip
    out = build_model("segnet", cfg).eval()(torch.randn(2, 64, 3))
    assert out.shape == (2, 64, 5)


def test_dsqnet_is_permutation_invariant():
    cfg = model_config("dsqnet", n_points=128, **TINY)
    torch.manual_seed(0)
    net = build_model("dsqnet", cfg).eval()
    x = torch.randn(2, 128, 3)
    perm = torch.randperm(128)
    a, b = net(x), net(x[:, perm])
    torch.testing.assert_close(a.params(), b.params(), atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(a.pose(), b.pose(), atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("c_in,c_out", [(3, 8), (8, 16)])
def test_edgeconv_matches_the_edge_tensor_form(c_in, c_out):
    """The fused EdgeConv gives the values, gradients and running statistics of
    ``max_j lrelu(bn(conv([x_j - x_i, x_i])))`` built on the whole edge tensor, for batch-norm
    scales of both signs, in training and in eval mode."""
    torch.manual_seed(0)
    layer = EdgeConv(c_in, c_out, k=5, slope=0.2)
    with torch.no_grad():
        layer.mlp[1].weight.uniform_(-1.0, 1.0)
        layer.mlp[1].bias.uniform_(-0.5, 0.5)
    ref = copy.deepcopy(layer)
    x = torch.randn(3, c_in, 40, dtype=torch.float64, requires_grad=True)
    layer.double(), ref.double()
    y = layer(x)
    y_ref = ref.mlp(graph_features(x, 5)).amax(-1)
    torch.testing.assert_close(y, y_ref)
    g = torch.autograd.grad((y * y).sum(), [x, *layer.parameters()])
    g_ref = torch.autograd.grad((y_ref * y_ref).sum(), [x, *ref.parameters()])
    for a, b in zip(g, g_ref, strict=True):
        torch.testing.assert_close(a, b)
    torch.testing.assert_close(layer.mlp[1].running_mean, ref.mlp[1].running_mean)
    torch.testing.assert_close(layer.mlp[1].running_var, ref.mlp[1].running_var)
    layer.eval(), ref.eval()
    torch.testing.assert_close(layer(x), ref.mlp(graph_features(x, 5)).amax(-1))


def test_factory_errors_list_the_models():
    with pytest.raises(
        ValueError, match=r"Available models: \['dsqnet', 'sqnet', 'dsqnet_plus', 'segnet'\]"
    ):
        build_model("pointnet")
    with pytest.raises(ValueError, match="Available presets"):
        load_preset("dsqnet", "tpu")
    with pytest.raises(ValueError, match="`k` must be in"):
        model_config("dsqnet", k=500, n_points=300)


def test_model_sizes_full_near_thesis_and_cpu_much_smaller():
    full, _ = load_preset("dsqnet", "gpu")
    cpu, _ = load_preset("dsqnet", "cpu")
    n_full = count_parameters(build_model("dsqnet", full))
    n_cpu = count_parameters(build_model("dsqnet", cpu))
    assert 4.5e6 < n_full < 7e6  # thesis: about 6 M
    assert n_cpu < n_full / 10


def test_save_load_round_trip_is_exact(tmp_path):
    from sqmanip.perception.learned.config import TrainConfig
    from sqmanip.perception.learned.infer import load_model
    from sqmanip.perception.learned.train import save_model_dir

    cfg = model_config("dsqnet_plus", n_points=64, **TINY)
    torch.manual_seed(1)
    net = build_model("dsqnet_plus", cfg)
    net.train()(torch.randn(4, 64, 4))  # move the BatchNorm running statistics
    net.eval()
    save_model_dir(tmp_path, net, cfg, TrainConfig(), {"note": "test"})
    sd = torch.load(tmp_path / "model.pt", weights_only=True)
    assert set(sd) == set(net.state_dict())
    loaded, cfg2 = load_model(tmp_path)
    assert cfg2 == cfg
    x = torch.randn(3, 64, 4)
    torch.testing.assert_close(loaded(x).params(), net(x).params(), atol=0, rtol=0)
    for k, v in net.state_dict().items():
        torch.testing.assert_close(sd[k], v, atol=0, rtol=0)
    assert np.isfinite(loaded(x).pose().detach().numpy()).all()
