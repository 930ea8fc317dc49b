"""Pushing data generation (4.5, 4.6.2): action sampler, catalogue, and a tiny simulator run."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sqmanip.dynamics.data import iter_tuples, load_split, read_manifest
from sqmanip.dynamics.generate import (
    GenerationConfig,
    generate_dataset,
    make_catalogue,
    plan_shards,
)
from sqmanip.dynamics.sampler import push_candidates, sample_push_actions

BIG = np.array([[-5.0, -5.0, 0.0], [5.0, 5.0, 0.192]])


def _scene():
    def pose(x, y, z, yaw):
        T = np.eye(4)
        T[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        T[:3, 3] = (x, y, z)
        return T

    poses = np.stack([pose(0.0, 0.0, 0.07, 0.3), pose(0.25, 0.1, 0.03, -1.0)])
    params = np.array([[0.03, 0.04, 0.07, 0.2, 0.2, 0, 0, 0, 0],
                       [0.03, 0.03, 0.03, 0.2, 1.0, 0, 0, 0, 0]])  # fmt: skip
    return poses, params


def test_sampler_has_at_most_160_candidates_per_object_below_the_top():
    poses, params = _scene()
    cand = push_candidates((poses, params), BIG)
    counts = np.bincount(cand.target)
    # Tall box (top 0.14 m): heights 0.032..0.128 -> 4 of 5; short cylinder (top 0.06): 1.
    assert counts[0] == 8 * 4 * 4 and counts[1] == 8 * 1 * 4
    assert counts.max() <= 160
    tops = poses[cand.target, 2, 3] + params[cand.target, 2]
    assert np.all(cand.actions[:, 2] < tops)
    np.testing.assert_allclose(np.linalg.norm(cand.actions[:, 3:5], axis=1), 0.10)
    # Every push points at the centre of its object.
    to_center = poses[cand.target, :2, 3] - cand.actions[:, :2]
    cross = to_center[:, 0] * cand.actions[:, 4] - to_center[:, 1] * cand.actions[:, 3]
    np.testing.assert_allclose(cross, 0.0, atol=1e-12)
    assert np.all((to_center * cand.actions[:, 3:5]).sum(1) > 0)


def test_sampler_candidates_are_se2_equivariant_and_filtered_by_the_workspace():
    poses, params = _scene()
    th, t = 0.9, np.array([0.3, -0.2])
    C = np.eye(4)
    C[:2, :2] = [[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]]
    C[:2, 3] = t
    a = push_candidates((poses, params), BIG).actions
    b = push_candidates((C @ poses, params), BIG).actions
    p = a[:, :3] @ C[:3, :3].T + C[:3, 3]
    v = a[:, 3:] @ C[:3, :3].T
    np.testing.assert_allclose(np.concatenate([p, v], 1), b, atol=1e-12)
    small = np.array([[-0.1, -0.1, 0.0], [0.1, 0.1, 0.192]])
    c = push_candidates((poses, params), small).actions
    assert 0 < len(c) < len(a)
    for x in (c[:, :3], c[:, :3] + c[:, 3:]):
        assert np.all((x >= small[0] - 1e-9) & (x <= small[1] + 1e-9))


def test_min_travel_drops_pushes_that_barely_touch_a_long_box_along_its_diagonal():
    """A 34 x 13 x 5 cm box: a push at 45 degrees starts its support-function extent (16.6 cm)
    away but meets the box on its line at 9.2 cm, so the tip travels 1.6 cm or less in contact
    and the MPC drops it; along the axes it travels 6-9 cm and is kept. A round can loses
    nothing, and ``None`` (data generation) keeps every push."""
    box = np.eye(4)
    box[:3, 3] = (0.0, 0.0, 0.025)
    params = np.array([[0.065, 0.17, 0.025, 0.2, 0.2, 0, 0, 0, 0]])
    every = push_candidates((box[None], params), BIG)
    kept = push_candidates((box[None], params), BIG, min_travel=0.03)
    assert len(every) == 8 * 4 and len(kept) == 4 * 4
    angles = np.degrees(np.arctan2(kept.actions[:, 4], kept.actions[:, 3])) % 90
    np.testing.assert_allclose(np.minimum(angles, 90 - angles), 0.0, atol=1e-9)
    poses, params = _scene()
    assert len(push_candidates((poses[1:], params[1:]), BIG, min_travel=0.03)) == 8 * 4


def test_sample_push_actions_is_seeded_and_respects_n():
    poses, params = _scene()
    a = sample_push_actions((poses, params), BIG, np.random.default_rng(4), n=100)
    b = sample_push_actions((poses, params), BIG, np.random.default_rng(4), n=100)
    assert a.shape == (100, 6)
    np.testing.assert_array_equal(a, b)
    assert len(np.unique(a, axis=0)) == 100
    assert sample_push_actions((poses, params), BIG, np.random.default_rng(0), n=None).shape == (
        160,
        6,
    )
    with pytest.raises(ValueError, match="params must have shape"):
        sample_push_actions((poses, params[:, :5]), BIG, np.random.default_rng(0))


def test_catalogue_has_18_boxes_and_18_cylinders_split_9_9():
    cat = make_catalogue(0)
    assert len(cat) == 36
    for kind in ("box", "cylinder"):
        objs = [o for o in cat if o.kind == kind]
        assert len(objs) == 18 and sum(o.known for o in objs) == 9
    assert make_catalogue(0) == cat and make_catalogue(1) != cat


def test_large_boxes_extend_the_catalogue_without_changing_it():
    base = make_catalogue(0)
    cat = make_catalogue(0, large_boxes=5)
    assert cat[:36] == base
    extra = cat[36:]
    assert [o.id for o in extra] == list(range(36, 41))
    for o in extra:
        assert o.kind == "box" and o.known
        sx, sy, sz = o.size
        assert 0.08 <= sx <= 0.16 and 0.12 <= sy <= 0.36 and 0.025 <= sz <= 0.07
    with pytest.raises(ValueError, match="large_boxes must be >= 0"):
        GenerationConfig(large_boxes=-1)


def test_unknown_split_plans_equal_groups_per_object_count(tmp_path):
    tasks = plan_shards(tmp_path, "unknown", 1200, GenerationConfig(shard_size=100))
    per_count = {k: sum(t.count for t in tasks if t.n_objects == k) for k in range(1, 5)}
    assert per_count == {1: 300, 2: 300, 3: 300, 4: 300}
    assert [t.index for t in tasks] == list(range(len(tasks)))


def test_tiny_generation_writes_valid_deterministic_shards(tmp_path):
    """One sequence of up to 2 pushes in the simulator, twice: same shards, readable by data.py."""
    config = GenerationConfig(seed=3, shard_size=2, max_pushes=2, cloud_points=64)
    outs = []
    for name in ("a", "b"):
        m = generate_dataset(tmp_path / name, config, splits=["train"], counts={"train": 2},
                             progress=False)  # fmt: skip
        assert m["train"]["count"] == 2
        outs.append(list(iter_tuples(tmp_path / name / "train")))
    for ta, tb in zip(*outs, strict=True):
        np.testing.assert_array_equal(ta.poses, tb.poses)
        np.testing.assert_array_equal(ta.next_poses, tb.next_poses)
        np.testing.assert_array_equal(ta.action_p, tb.action_p)
        np.testing.assert_array_equal(ta.cloud, tb.cloud)
    manifest = read_manifest(tmp_path / "a" / "train")
    assert manifest["meta"]["camera"]["width"] == 320
    data = load_split(tmp_path / "a" / "train", with_cloud=True)
    b = data.batch
    assert len(data) == 2 and data.cloud is not None and data.cloud.shape[1] <= 64
    moved = (b.next_poses - b.poses)[..., :3, 3].norm(dim=-1)[b.mask]
    assert moved.max() > 0.005  # the pushes moved something
    assert (b.params[b.mask][:, 3:5] > 0).all()
    labels = data.cloud_labels[data.cloud_labels >= 0]
    assert labels.max() < b.mask.sum(1).max()
    # Resume: a second call finds the shard and builds nothing new.
    before = (tmp_path / "a" / "train" / "shard-00000.npz").stat().st_mtime_ns
    generate_dataset(tmp_path / "a", config, splits=["train"], counts={"train": 2},
                     progress=False)  # fmt: skip
    assert (tmp_path / "a" / "train" / "shard-00000.npz").stat().st_mtime_ns == before
