"""Training (A.2) and inference: a tiny overfit run, resume, checkpoints, NetworkRecognizer."""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest
import torch
from sqmanip.geometry.transforms import pose_from_pq, quat_normalize
from sqmanip.perception.learned.config import TrainConfig, model_config
from sqmanip.perception.learned.infer import NetworkRecognizer, NetworkSegmenter
from sqmanip.perception.learned.models import build_model
from sqmanip.perception.learned.train import (
    build_datasets,
    load_initial_weights,
    save_model_dir,
    train,
)

TINY = dict(k=6, edge_widths=(16, 16, 16, 32), global_dim=64, head_widths=(32, 16))
TCFG = TrainConfig(batch_size=4, n_gt=64, max_steps=24, eval_every=1000, eval_iou_items=2,
                   checkpoint_every=12, log_every=6, device="cpu", lr=3e-3)  # fmt: skip


def _losses(out):
    with (out / "log.csv").open() as fh:
        return [float(r["loss"]) for r in csv.DictReader(fh) if r["split"] == "train"]


@pytest.fixture(scope="module")
def dsqnet_run(tiny_data, tmp_path_factory):
    out = tmp_path_factory.mktemp("dsqnet")
    mcfg = model_config("dsqnet", n_points=300, **TINY)
    res = train("dsqnet", mcfg, TCFG, tiny_data, out, progress=False)
    return out, mcfg, res


def test_tiny_dsqnet_run_lowers_its_loss(dsqnet_run):
    out, _, res = dsqnet_run
    losses = _losses(out)
    assert res["steps"] == 24 and len(losses) == 4
    assert losses[-1] < losses[0]
    assert 0.0 <= res["test"]["iou"] <= 1.0
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] == 24 and "optimizer" in ckpt


def test_the_extra_loss_terms_are_logged_and_trained(tiny_data, tmp_path):
    """The cpu preset's surface, shape and size terms (learned/losses.py) go into the loss."""
    extra = dataclasses.replace(TCFG, surface_weight=1.0, shape_weight=0.1, size_weight=10.0)
    mcfg = model_config("dsqnet", n_points=300, **TINY)
    res = train("dsqnet", mcfg, extra, tiny_data, tmp_path, progress=False)
    with (tmp_path / "log.csv").open() as fh:
        rows = [r for r in csv.DictReader(fh) if r["split"] == "train"]
    first, last = rows[0], rows[-1]
    assert float(first["surface"]) > 0 and float(first["shape"]) > 0
    assert float(last["loss"]) < float(first["loss"])
    assert float(last["shape"]) < float(first["shape"])
    assert res["test"]["shape"] > 0


def test_dsqnet_plus_starts_as_the_dsqnet_it_is_initialised_from(tmp_path):
    """The segment channel's new weights start at zero: on a cloud that is all segment, the
    initialised DSQNet+ predicts what the DSQNet does."""
    torch.manual_seed(0)
    src = build_model("dsqnet", model_config("dsqnet", n_points=64, **TINY)).eval()
    save_model_dir(tmp_path / "src", src, src.config, TCFG, {})
    plus = build_model("dsqnet_plus", model_config("dsqnet_plus", n_points=64, **TINY)).eval()
    assert load_initial_weights(plus, tmp_path / "src") == ["encoder.edges.0.mlp.0.weight"]
    x = torch.randn(2, 64, 3)
    a, b = src(x), plus(torch.cat([x, torch.ones(2, 64, 1)], -1))
    torch.testing.assert_close(a.params(), b.params())
    torch.testing.assert_close(a.pose(), b.pose())
    wide = build_model("dsqnet", model_config("dsqnet", n_points=64, **{**TINY, "global_dim": 32}))
    with pytest.raises(ValueError, match="shape"):
        load_initial_weights(wide, tmp_path / "src")
    with pytest.raises(ValueError, match="does not fit"):
        load_initial_weights(build_model("sqnet", model_config("sqnet", **TINY)), tmp_path / "src")


def test_resume_reproduces_an_uninterrupted_run(tiny_data, tmp_path, dsqnet_run):
    out_ref, mcfg, _ = dsqnet_run
    half = dataclasses.replace(TCFG, max_steps=12)
    train("dsqnet", mcfg, half, tiny_data, tmp_path, progress=False)
    res = train("dsqnet", mcfg, TCFG, tiny_data, tmp_path, resume=True, progress=False)
    assert res["steps"] == 24
    a = torch.load(out_ref / "model.pt", weights_only=True)
    b = torch.load(tmp_path / "model.pt", weights_only=True)
    for k in a:
        torch.testing.assert_close(a[k], b[k], atol=1e-6, rtol=1e-5, msg=k)


def test_cosine_schedule_is_a_function_of_the_step_and_decays_to_lr_final(tiny_data, tmp_path):
    cos = dataclasses.replace(TCFG, lr_schedule="cosine", lr_final=1e-5)
    assert cos.lr_at(0) == pytest.approx(3e-3)
    assert cos.lr_at(12) == pytest.approx((3e-3 + 1e-5) / 2)
    assert cos.lr_at(24) == pytest.approx(1e-5) and cos.lr_at(99) == pytest.approx(1e-5)
    assert TCFG.lr_at(20) == TCFG.lr  # constant (A.2) by default
    with pytest.raises(ValueError, match="lr_schedule"):
        TrainConfig(lr_schedule="step")
    mcfg = model_config("dsqnet", n_points=300, **TINY)
    train("dsqnet", mcfg, dataclasses.replace(cos, max_steps=12), tiny_data, tmp_path,
          progress=False)  # fmt: skip
    ckpt = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    # the last step of a 12-step cosine ran at its own schedule's rate for step 11
    lr_last = ckpt["optimizer"]["param_groups"][0]["lr"]
    assert lr_last == pytest.approx(dataclasses.replace(cos, max_steps=12).lr_at(11))


def test_segnet_loss_falls(tiny_data, tmp_path):
    mcfg = model_config("segnet", n_points=256, k=6, edge_widths=(16, 16), global_dim=32,
                        head_widths=(32,), dropout=0.0)  # fmt: skip
    res = train("segnet", mcfg, TCFG, tiny_data, tmp_path, progress=False)
    losses = _losses(tmp_path)
    assert losses[-1] < losses[0]
    assert 0.0 <= res["test"]["acc"] <= 1.0
    labels = NetworkSegmenter.load(tmp_path).segment(np.random.default_rng(0).normal(size=(700, 3)))
    assert labels.shape == (700,) and labels.min() == 0


def test_dsqnet_plus_trains_on_object_parts(tiny_data, tmp_path):
    mcfg = model_config("dsqnet_plus", n_points=256, **TINY)
    tcfg = dataclasses.replace(TCFG, max_steps=4)
    train_ds, _ = build_datasets("dsqnet_plus", tiny_data, mcfg, tcfg)
    assert len(train_ds) >= 2  # the mug contributes two parts per view
    res = train("dsqnet_plus", mcfg, tcfg, tiny_data, tmp_path, progress=False)
    assert np.isfinite(res["train"]["loss"])
    rec = NetworkRecognizer.load(tmp_path)
    rng = np.random.default_rng(0)
    segs = [rng.normal(size=(120, 3)) * 0.02, rng.normal(size=(40, 3)) * 0.01 + 0.05]
    parts = rec.predict(segs)
    assert len(parts) == 2 and all(np.isfinite(p.params()).all() for p in parts)


def test_recognizer_undoes_the_normalisation(dsqnet_run):
    """Predictions are equivariant: moving, turning and scaling a segment moves, turns and scales
    the predicted superquadric the same way (bending scales inversely)."""
    out, _, _ = dsqnet_run
    rec = NetworkRecognizer.load(out)
    rng = np.random.default_rng(1)
    seg = rng.normal(size=(400, 3)) * [0.03, 0.02, 0.08]  # >= 300: no up-sampling
    T = pose_from_pq(
        torch.tensor([0.4, -0.2, 0.7]), quat_normalize(torch.tensor([0.3, 0.1, -0.2, 0.9]))
    )
    T = T.double().numpy()
    s = 1.7
    moved = s * seg @ T[:3, :3].T + T[:3, 3]
    (a,), (b,) = rec.predict([seg]), rec.predict([moved])
    np.testing.assert_allclose(np.array(b.size), s * np.array(a.size), rtol=1e-4)
    np.testing.assert_allclose(b.shape, a.shape, atol=1e-4)
    np.testing.assert_allclose(b.bend, a.bend / s, rtol=1e-3)
    expect = T[:3, :3] @ a.pose[:3, :3]
    np.testing.assert_allclose(b.pose[:3, :3], expect, atol=1e-4)
    np.testing.assert_allclose(b.pose[:3, 3], s * T[:3, :3] @ a.pose[:3, 3] + T[:3, 3], atol=1e-4)
    assert rec.predict([]) == []
    with pytest.raises(ValueError, match=r"segments\[0\] must have shape"):
        rec.predict([np.zeros((5, 2))])
    with pytest.raises(ValueError, match="finite"):
        rec.predict([np.full((5, 3), np.nan)])
