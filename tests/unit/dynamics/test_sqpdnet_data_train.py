"""Pushing-tuple format (write / read / resume), config validation, and a tiny training run."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch
from sqmanip.dynamics.config import SQPDNetConfig, cpu_config, get_config
from sqmanip.dynamics.data import (
    PushTuple,
    PushTupleWriter,
    finalize_split,
    iter_tuples,
    load_split,
    read_manifest,
    synthetic_tuples,
    tensors_from_tuples,
    write_shard,
)
from sqmanip.dynamics.model import make_model
from sqmanip.dynamics.train import load_model, train, train_step


def _with_cloud(t: PushTuple, seed: int) -> PushTuple:
    rng = np.random.default_rng(seed)
    p = int(rng.integers(5, 12))
    labels = rng.integers(-1, t.num_objects, p)
    return PushTuple(t.poses, t.params, t.kinds, t.action_p, t.action_v, t.next_poses,
                     object_ids=np.arange(t.num_objects), cloud=rng.normal(size=(p, 3)),
                     cloud_labels=labels, sequence=t.sequence, step=t.step)  # fmt: skip


def test_tuples_round_trip_through_shards_and_writer_resumes(tmp_path):
    tuples = [_with_cloud(t, k) for k, t in enumerate(synthetic_tuples(7, seed=1))]
    with PushTupleWriter(tmp_path, max_objects=4, shard_size=3, meta={"seed": 1}) as w:
        for t in tuples[:5]:
            w.write(t)
    # Resume: a new writer appends shards after the existing ones.
    with PushTupleWriter(tmp_path, max_objects=4, shard_size=3, meta={"seed": 1}) as w:
        for t in tuples[5:]:
            w.write(t)
    manifest = read_manifest(tmp_path)
    assert manifest["count"] == 7 and len(manifest["shards"]) == 3
    assert manifest["meta"] == {"seed": 1}
    back = list(iter_tuples(tmp_path))
    for a, b in zip(tuples, back, strict=True):
        np.testing.assert_array_equal(a.poses, b.poses)
        np.testing.assert_array_equal(a.next_poses, b.next_poses)
        np.testing.assert_array_equal(a.params, b.params)
        np.testing.assert_array_equal(a.cloud, b.cloud)
        np.testing.assert_array_equal(a.cloud_labels, b.cloud_labels)
        assert a.sequence == b.sequence
    data = load_split(tmp_path, with_cloud=True, dtype=torch.float64)
    assert data.batch.poses.shape == (7, 4, 4, 4)
    assert data.batch.mask.sum().item() == sum(t.num_objects for t in tuples)
    assert data.cloud is not None and data.cloud.shape[0] == 7


def test_parallel_shards_are_finalized_into_one_manifest(tmp_path):
    tuples = synthetic_tuples(4, seed=2)
    write_shard(tmp_path, 3, tuples[:2], 4)  # written by "worker 3"
    write_shard(tmp_path, 0, tuples[2:], 4)
    (tmp_path / "shard-00009.npz.tmp").write_bytes(b"partial")  # a crashed worker's leftover
    manifest = finalize_split(tmp_path, 4)
    assert [s["file"] for s in manifest["shards"]] == ["shard-00000.npz", "shard-00003.npz"]


def test_push_tuple_validation_names_the_field():
    t = synthetic_tuples(1, seed=0)[0]
    with pytest.raises(ValueError, match="next_poses must have shape"):
        PushTuple(t.poses, t.params, t.kinds, t.action_p, t.action_v, t.next_poses[:0])
    with pytest.raises(ValueError, match="action_v must have shape"):
        PushTuple(t.poses, t.params, t.kinds, t.action_p, t.action_v[:2], t.next_poses)
    bad = t.poses.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="poses must be finite"):
        PushTuple(bad, t.params, t.kinds, t.action_p, t.action_v, t.next_poses)


def test_config_validation_names_the_field():
    with pytest.raises(ValueError, match="`alpha`"):
        SQPDNetConfig(alpha=-1)
    with pytest.raises(ValueError, match="`decoder_hidden`"):
        SQPDNetConfig(decoder_hidden=(64, 0))
    with pytest.raises(ValueError, match="Available presets"):
        get_config("tpu")
    cfg = cpu_config()
    assert SQPDNetConfig.from_dict(cfg.to_dict()) == cfg
    full = get_config("gpu")
    assert full.decoder_hidden == (256, 256, 128, 128, 64, 64) and full.feature_dim == 256
    assert full.alpha == 0.1


def test_tiny_training_run_reduces_the_loss():
    """Overfitting 16 analytic tuples: the loss (4.3.3) falls well below its start."""
    torch.manual_seed(0)
    data = tensors_from_tuples(synthetic_tuples(16, seed=0), 4)
    small = {"feature_dim": 64, "action_hidden": (32,), "ego_hidden": (32,),
             "scene_hidden": (32,), "scene_post_hidden": (64,), "decoder_hidden": (64, 64)}  # fmt: skip
    model = make_model(cpu_config(batch_size=16, lr=3e-3, **small))
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    first = model.loss(data.batch)[0].item()
    for _ in range(60):
        train_step(model, data.batch, opt)
    last = model.loss(data.batch)[0].item()
    assert last < 0.3 * first


def test_train_writes_checkpoints_and_resumes(tmp_path):
    data = tensors_from_tuples(synthetic_tuples(16, seed=4), 4)
    cfg = cpu_config(epochs=2, batch_size=8, checkpoint_every=1, seed=3,
                     decoder_hidden=(32,), feature_dim=32)  # fmt: skip
    train(cfg, data, data, tmp_path, progress=False)
    assert {"checkpoint.pt", "model.pt", "model_best.pt", "config.json", "log.csv"} <= {
        p.name for p in tmp_path.iterdir()
    }
    longer = cpu_config(epochs=3, batch_size=8, checkpoint_every=1, seed=3,
                        decoder_hidden=(32,), feature_dim=32)  # fmt: skip
    result = train(longer, data, data, tmp_path, progress=False)
    assert [row["epoch"] for row in result["history"]] == [3]  # resumed after epoch 2
    rows = list(csv.DictReader((tmp_path / "log.csv").read_text().splitlines()))
    assert [int(r["epoch"]) for r in rows] == [1, 2, 3]
    model = load_model(tmp_path)
    for a, b in zip(
        model.state_dict().values(), result["model"].state_dict().values(), strict=True
    ):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_evaluate_reports_both_flow_definitions_of_the_same_points():
    from sqmanip.dynamics.evaluate import evaluate

    torch.manual_seed(0)
    data = tensors_from_tuples(synthetic_tuples(6, seed=3), 4)
    res = evaluate(make_model(cpu_config(device="cpu")).double(), data, n_points=32)
    assert res["full_flow_cm"] > 0.0
    assert res["full_flow_code"] == pytest.approx(res["full_flow_cm"] ** 2 / 3.0)
    assert "visible_flow_code" not in res  # synthetic tuples carry no observed cloud


def test_slow_metrics_use_evenly_spaced_tuples_not_the_first():
    from sqmanip.dynamics.evaluate import evenly_spaced

    assert evenly_spaced(5, None).tolist() == [0, 1, 2, 3, 4]
    idx = evenly_spaced(1200, 200)
    assert len(idx) == 200 and idx[0] == 0 and idx[-1] == 1199
    assert (idx.diff() >= 5).all()  # spread over the split, which is ordered by object count
