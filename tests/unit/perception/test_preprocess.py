"""Support-plane RANSAC, voxel down-sampling and tangent-plane up-sampling (3.5.3, B.2)."""

from __future__ import annotations

import numpy as np
from sqmanip.perception.preprocess import (
    crop_mask,
    fit_plane_ransac,
    resample,
    voxel_downsample,
)
from sqmanip.perception.types import Workspace


def _tilted_plane(n: int, rng, noise=0.001):
    normal = np.array([0.1, -0.2, 1.0])
    normal /= np.linalg.norm(normal)
    u = np.cross(normal, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    st = rng.uniform(-0.3, 0.3, (n, 2))
    pts = st[:, :1] * u + st[:, 1:] * v + 0.05 * normal + rng.normal(scale=noise, size=(n, 3))
    return pts, normal, -0.05


def test_ransac_finds_noisy_plane_among_clutter_and_orients_it_to_the_viewpoint():
    rng = np.random.default_rng(0)
    plane, normal, offset = _tilted_plane(5000, rng)
    clutter = rng.uniform(-0.3, 0.3, (1500, 3)) + np.array([0, 0, 0.2])
    pts = np.concatenate([plane, clutter])
    fit = fit_plane_ransac(pts, rng, threshold=0.004, viewpoint=np.array([0.0, 0.0, 1.0]))
    assert fit is not None
    assert abs(fit.normal @ normal) > 0.999
    assert fit.normal @ normal > 0  # the viewpoint is on the +normal side
    assert abs(fit.offset - offset) < 0.002
    assert fit.inliers[:5000].mean() > 0.95 and fit.inliers[5000:].mean() < 0.05
    # viewpoint below: the normal flips
    below = fit_plane_ransac(
        pts, np.random.default_rng(0), threshold=0.004, viewpoint=np.array([0.0, 0.0, -1.0])
    )
    assert below.normal @ normal < -0.999
    assert below.as_support().normal == tuple(below.normal)


def test_ransac_reports_none_without_enough_support():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1, 1, (2000, 3))
    assert fit_plane_ransac(pts, rng, threshold=0.001, min_fraction=0.2) is None


def test_crop_keeps_points_inside_the_box():
    pts = np.array([[0, 0, 0], [2, 0, 0], [0.5, 0.5, 0.5]])
    assert crop_mask(pts, Workspace((-1, -1, -1), (1, 1, 1))).tolist() == [True, False, True]
    assert crop_mask(pts, None).all()


def test_voxel_downsample_keeps_one_point_per_voxel():
    rng = np.random.default_rng(2)
    cells = rng.integers(0, 10, (50, 3))
    pts = np.repeat(cells, 5, axis=0) * 0.01 + 0.002 + rng.uniform(0, 0.005, (250, 3))
    idx, inverse = voxel_downsample(pts, 0.01)
    assert len(idx) == len(np.unique(cells, axis=0))
    assert np.all(np.floor(pts[idx[inverse]] / 0.01) == np.floor(pts / 0.01))


def test_resample_gives_exact_counts_and_upsampled_points_stay_on_the_surface():
    rng = np.random.default_rng(3)
    plane, normal, offset = _tilted_plane(120, rng, noise=0.0)
    for n in (50, 120, 300, 1000):
        out = resample(plane, n, rng)
        assert out.shape == (n, 3)
        assert np.abs(out @ normal + offset).max() < 1e-9  # tangent planes of a plane
    dense, _, _ = _tilted_plane(5000, rng, noise=0.0)
    down = resample(dense, 300, rng, voxel=0.01)
    assert down.shape == (300, 3)
    assert len(np.unique(down, axis=0)) == 300
    assert resample(plane[:1], 5, rng).shape == (5, 3)
