"""Surface sampling: on the surface, outward normals, evenly spaced (unlike angle sampling)."""

import numpy as np
import pytest
import torch
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree
from sqmanip.geometry import Superquadric
from sqmanip.geometry.sampling import (
    farthest_point_sampling,
    sample_parts,
    sample_surface,
    sample_surface_angles,
)
from sqmanip.geometry.superquadric import implicit

SHAPES = [
    (0, [0.1, 0.2, 0.3, 0.2, 0.2, 0.0, 0.0, 0.0, 0.0]),  # box-like
    (0, [0.05, 0.05, 0.05, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0]),  # sphere
    (0, [0.1, 0.2, 0.3, 1.7, 1.0, 0.5, 1.0, 0.3, 0.0]),  # pinched, tapered, bent
    (1, [0.1, 0.1, 0.2, 0.5, 1.0, 0.2, 0.5, 0.0, 0.0]),  # superparaboloid
    (2, [0.05, 0.05, 0.05, 0.3, 0.2, 0.2, 1.0, 0.0, 2.0]),  # supertoroid
]


def nn_cv(points: np.ndarray) -> float:
    d, _ = cKDTree(points).query(points, k=2)
    return float(d[:, 1].std() / d[:, 1].mean())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize(("kind", "p"), SHAPES)
def test_samples_lie_on_surface_with_outward_normals(kind, p, dtype):
    params = torch.tensor(p, dtype=dtype)
    pts, nrm = sample_surface(params, 300, kind=kind, generator=0)
    assert pts.shape == (300, 3) and nrm.shape == (300, 3) and pts.dtype == dtype
    tol = 1e-4 if dtype == torch.float32 else 1e-9
    assert torch.allclose(implicit(pts, params, kind), torch.ones(300, dtype=dtype), atol=tol)
    assert torch.allclose(nrm.norm(dim=-1), torch.ones(300, dtype=dtype), atol=1e-5)
    eps = 1e-3
    outside = implicit(pts + eps * nrm, params, kind) > 1
    inside = implicit(pts - eps * nrm, params, kind) < 1
    # the superparaboloid's cap meets its wall in a sharp rim: a point within eps of it may step
    # through the wall; everywhere else the normal must point out
    need = 1.0 if kind != 1 else 0.98
    assert outside.double().mean() >= need and inside.double().mean() >= need


@pytest.mark.parametrize(("kind", "p"), SHAPES)
def test_samples_are_evenly_spaced(kind, p):
    pts, _ = sample_surface(torch.tensor(p, dtype=torch.float64), 800, kind=kind, generator=1)
    # blue noise: i.i.d. uniform sampling gives a nearest-neighbour CV of ~0.5
    assert nn_cv(pts.numpy()) < 0.25


def test_angle_sampling_bunches_where_ours_does_not():
    p = torch.tensor([0.1, 0.2, 0.3, 0.2, 0.2, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    ours, _ = sample_surface(p, 1000, generator=0)
    naive = sample_surface_angles(p, 25, 40)
    assert nn_cv(ours.numpy()) < 0.5 * nn_cv(naive.numpy())

    # the naive grid puts >30 % of its points within 2 mm of the box edges; ours ~ area share
    def near_edges(x):
        a = np.array([0.1, 0.2, 0.3])
        close = (a - np.abs(x)) < 0.02
        return float((close.sum(-1) >= 2).mean())

    assert near_edges(naive.numpy()) > 2 * near_edges(ours.numpy())


def test_deterministic_given_seed_and_batched_shapes():
    params = torch.rand(2, 3, 9, generator=torch.Generator().manual_seed(0)) * 0.2 + 0.05
    a, _ = sample_surface(params, 50, generator=7)
    b, _ = sample_surface(params, 50, generator=7)
    assert a.shape == (2, 3, 50, 3)
    assert torch.equal(a, b)
    c, _ = sample_surface(params, 50, generator=8)
    assert not torch.equal(a, c)


def test_numpy_in_numpy_out_and_empty():
    pts, nrm = sample_surface(np.array([0.1, 0.1, 0.1, 1, 1, 0, 0, 0, 0.0]), 10)
    assert isinstance(pts, np.ndarray) and pts.shape == (10, 3)
    pts, nrm = sample_surface(torch.ones(9), 0)
    assert pts.shape == (0, 3)
    pts, nrm = sample_surface(torch.ones(0, 9), 5)
    assert pts.shape == (0, 5, 3)


def test_sample_surface_rejects_bad_params():
    with pytest.raises(ValueError, match="params"):
        sample_surface(torch.ones(8), 10)
    with pytest.raises(ValueError, match="n must"):
        sample_surface(torch.ones(9), -1)


def test_area_method_is_iid_and_on_surface():
    p = torch.tensor([0.1, 0.2, 0.3, 0.5, 0.8, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    pts, _ = sample_surface(p, 5000, method="area", generator=0)
    assert torch.allclose(implicit(pts, p), torch.ones(5000, dtype=torch.float64), atol=1e-9)


def test_sample_parts_splits_by_area_and_poses_points():
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 0.0, 0.0]
    parts = [
        Superquadric((0.1, 0.1, 0.1), (1.0, 1.0)),
        Superquadric((0.2, 0.2, 0.2), (1.0, 1.0), pose=pose),
    ]
    pts, nrm, ids = sample_parts(parts, 500, generator=0)
    assert pts.shape == (500, 3) and nrm.shape == (500, 3)
    counts = np.bincount(ids)
    assert abs(counts[1] / counts[0] - 4.0) < 0.1  # area ratio of the spheres
    r = np.linalg.norm(pts[ids == 1] - [1.0, 0, 0], axis=-1)
    assert np.allclose(r, 0.2, atol=1e-9)
    assert np.allclose(nrm[ids == 1], (pts[ids == 1] - [1.0, 0, 0]) / 0.2, atol=1e-6)
    assert sample_parts([], 10)[0].shape == (0, 3)


def test_fps_spreads_points():
    pts = torch.rand(1000, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    idx = farthest_point_sampling(pts, 50, generator=0)
    assert idx.shape == (50,) and len(set(idx.tolist())) == 50
    chosen = pts[idx]
    d = torch.cdist(chosen, chosen) + torch.eye(50, dtype=torch.float64) * 10
    assert float(d.min()) > 0.1


@settings(max_examples=15, deadline=None)
@given(
    e1=st.floats(0.2, 1.7),
    e2=st.floats(0.2, 1.7),
    k=st.floats(-0.9, 0.9),
    bp=st.floats(0.01, 0.75),
    alpha=st.floats(-np.pi, np.pi),
)
def test_deformed_superellipsoid_samples_satisfy_implicit(e1, e2, k, bp, alpha):
    a1, a2, a3 = 0.08, 0.05, 0.15
    # b' t_k(z) > 1 folds the bent shape over itself (D^{-1} D != id there); stay off the fold.
    assume(bp * (1 + abs(k)) < 0.95)
    p = torch.tensor([a1, a2, a3, e1, e2, k, bp / max(a1, a2), alpha, 0.0], dtype=torch.float64)
    pts, nrm = sample_surface(p, 100, generator=0)
    assert torch.isfinite(pts).all() and torch.isfinite(nrm).all()
    assert torch.allclose(implicit(pts, p), torch.ones(100, dtype=torch.float64), atol=1e-6)
