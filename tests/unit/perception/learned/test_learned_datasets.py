"""Dataset generation (A.1): determinism, shapes, resumption, single-plane exclusion, frames."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree
from sqmanip.perception.learned import datasets as D


def _spec(out, **kw):
    base = dict(out=str(out), datasets=("primitive",), types=("B", "TT"), shapes=2, n_views=2,
                n_gt=64, resolution=48)  # fmt: skip
    base.update(kw)
    return D.GenerationSpec(**base)


def test_generation_is_deterministic_shaped_and_resumable(tmp_path):
    a = D.generate(_spec(tmp_path / "a"), workers=1, progress=False)
    D.generate(_spec(tmp_path / "b"), workers=1, progress=False)
    assert a["generated_shards"] == 2
    da, db = (
        D.load_dataset(tmp_path / "a", "primitive"),
        D.load_dataset(tmp_path / "b", "primitive"),
    )
    for k in da:
        np.testing.assert_array_equal(da[k], db[k], err_msg=k)
    m = len(da["shape_idx"])
    assert 1 <= m <= 8  # 2 types x 2 shapes x 2 views, minus single-plane views
    assert da["partial"].shape == (m, 300, 3) and da["partial"].dtype == np.float32
    assert da["gt"].shape == (4, D.MAX_PARTS, 64, 3)
    assert da["params"].shape == (4, D.MAX_PARTS, 9)
    assert set(da["type_id"].tolist()) == {D.OBJECT_TYPES.index("B"), D.OBJECT_TYPES.index("TT")}
    assert da["test"].sum() == 2  # the last of 2 shapes of each type
    # resuming writes nothing new and keeps the files
    again = D.generate(_spec(tmp_path / "a"), workers=1, progress=False)
    assert again["generated_shards"] == 0
    assert again["counts"] == a["counts"]


def test_partial_points_lie_on_the_ground_truth_surface(tiny_data):
    data = D.load_dataset(tiny_data, "object")
    for i in range(len(data["shape_idx"])):
        s = data["shape_idx"][i]
        pts, lab = data["partial"][i], data["labels"][i]
        assert pts.shape == (1000, 3)
        assert lab.max() < data["n_parts"][s]
        for p in np.unique(lab):
            # gt has only 128 points here: spacing up to ~1-2 cm for a mug body
            d, _ = cKDTree(data["gt"][s, p]).query(pts[lab == p])
            assert np.median(d) < 0.02


def test_object_dataset_has_part_labels(tiny_data):
    data = D.load_dataset(tiny_data, "object")
    mug = data["type_id"] == D.OBJECT_TYPES.index("mug")
    assert (data["n_parts"][mug] == 2).all()
    assert (data["n_parts"][~mug] == 1).all()


def test_single_plane_detection():
    rng = np.random.default_rng(0)
    plane = np.c_[rng.uniform(-0.1, 0.1, (500, 2)), np.zeros(500)]
    assert D.is_single_plane(plane)
    corner = np.concatenate([plane[:250], np.c_[plane[250:, 0], np.zeros(250), plane[250:, 1]]])
    assert not D.is_single_plane(corner)
    sphere = rng.normal(size=(500, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    assert not D.is_single_plane(0.05 * sphere)


def test_box_seen_face_on_is_excluded_and_at_a_corner_is_kept():
    box = [D.box(0.1, 0.08, 0.06)]
    rng = np.random.default_rng(0)
    face_on = D.render_view(box, np.array([0.0, 0.0, 1.0]), rng, 300)
    corner = D.render_view(box, np.ones(3) / np.sqrt(3), rng, 300)
    assert face_on.single_plane and face_on.n_hits > 300
    assert not corner.single_plane


def test_primitive_mappings_match_table_a1():
    cone = D.cone(0.05, 0.1)
    a1, k = cone.size[0], cone.taper
    assert a1 * (1 - k) == pytest.approx(0.05) and k == pytest.approx(-0.9)
    tc = D.truncated_cone(0.08, 0.03, 0.2)
    assert tc.size[0] * (1 - tc.taper) == pytest.approx(0.08)  # bottom radius R
    assert tc.size[0] * (1 + tc.taper) == pytest.approx(0.03)  # top radius r
    tt = D.truncated_torus(0.01, 0.05, 1.0)
    assert tt.bend == pytest.approx(20.0) and tt.size[2] == pytest.approx(0.05)


@pytest.mark.parametrize("type_name", D.OBJECT_TYPES)
def test_every_type_builds_valid_parts(type_name):
    parts = D.object_parts(type_name, np.random.default_rng(3))
    assert 1 <= len(parts) <= D.MAX_PARTS
    for p in parts:
        R = p.pose[:3, :3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        assert -0.9 - 1e-9 <= p.taper <= 0.9 + 1e-9
        assert p.bend * max(p.size[:2]) <= 0.75 + 1e-9  # b' within Table 3.1's bound


def test_unknown_type_lists_choices():
    with pytest.raises(ValueError, match="Available"):
        D.object_parts("teapot", np.random.default_rng(0))


def test_batches_are_normalised_and_reproducible(tiny_data):
    ds = D.PrimitiveDataset(tiny_data, "all", n_points=300, n_gt=100)
    b1 = ds.batch([0, 1], torch.Generator().manual_seed(5))
    b2 = ds.batch([0, 1], torch.Generator().manual_seed(5))
    torch.testing.assert_close(b1.x, b2.x, atol=0, rtol=0)
    assert b1.x.shape == (2, 300, 3) and b1.gt.shape == (2, 100, 3)
    diam = torch.cdist(b1.x, b1.x).flatten(1).amax(1)
    torch.testing.assert_close(diam, torch.ones(2), atol=1e-5, rtol=0)
    torch.testing.assert_close(b1.gt_z.norm(dim=-1), torch.ones(2), atol=1e-5, rtol=0)
    plus = D.ObjectPartDataset(tiny_data, "all", n_points=200, n_gt=50).batch([0, 1])
    assert plus.x.shape == (2, 200, 4)
    assert set(plus.x[..., 3].unique().tolist()) <= {0.0, 1.0} and plus.x[..., 3].sum() > 0
    seg = D.SegmentationDataset(tiny_data, "all", n_points=256).batch([0])
    assert seg.x.shape == (1, 256, 3) and seg.labels.shape == (1, 256)
