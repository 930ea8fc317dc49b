"""Occupancy and Monte-Carlo IoU of superquadric unions and meshes."""

import numpy as np
import pytest
import torch
import trimesh
from sqmanip.geometry import Superquadric
from sqmanip.geometry.iou import (
    mesh_contains,
    occupancy,
    shapes_bounds,
    volume_iou,
    volume_iou_estimate,
)
from sqmanip.geometry.mesh import superquadric_trimesh


def posed(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


SQ = Superquadric((0.1, 0.2, 0.3), (0.5, 1.2), taper=0.3, bend=1.0)


def test_iou_with_itself_is_one_and_disjoint_is_zero():
    est = volume_iou_estimate([SQ], [SQ], n=20_000)
    assert est.iou == 1.0 and est.stderr == 0.0 and est.n_union > 0
    far = [SQ.with_pose(posed(2.0))]
    assert volume_iou([SQ], far, n=20_000) == 0.0


def test_box_superquadric_vs_box_mesh():
    box = Superquadric((0.5, 0.5, 0.5), (0.2, 0.2))
    est = volume_iou_estimate([box], trimesh.creation.box(extents=(1, 1, 1)), n=30_000)
    assert est.iou > 0.95
    assert 0 < est.stderr < 0.005


def test_half_overlapping_spheres_match_closed_form_within_stderr():
    r, d = 0.1, 0.1  # two spheres, centres one radius apart
    a = [Superquadric((r, r, r), (1.0, 1.0))]
    b = [Superquadric((r, r, r), (1.0, 1.0), pose=posed(d))]
    lens = np.pi * (4 * r + d) * (2 * r - d) ** 2 / 12
    exact = lens / (2 * 4 / 3 * np.pi * r**3 - lens)
    est = volume_iou_estimate(a, b, n=50_000, generator=3)
    assert abs(est.iou - exact) < 4 * est.stderr
    assert est == volume_iou_estimate(a, b, n=50_000, generator=3)  # deterministic


def test_union_vs_its_own_mesh():
    est = volume_iou_estimate([SQ], superquadric_trimesh(SQ, 32), n=20_000)
    assert est.iou > 0.98


def test_mesh_contains_matches_sphere():
    sphere = trimesh.creation.icosphere(subdivisions=4)
    pts = np.random.default_rng(0).uniform(-1.2, 1.2, (20_000, 3))
    inside = mesh_contains(sphere.vertices, sphere.faces, pts)
    assert (inside != (np.linalg.norm(pts, axis=1) < 1)).mean() < 0.005
    assert mesh_contains(sphere.vertices, sphere.faces, np.zeros((0, 3))).shape == (0,)


def test_occupancy_numpy_and_torch_and_empty():
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    assert occupancy(pts, [SQ]).tolist() == [True, False]
    assert occupancy(torch.tensor(pts), [SQ]).tolist() == [True, False]
    assert occupancy(pts, []).tolist() == [False, False]
    with pytest.raises(ValueError, match="points"):
        occupancy(np.zeros(3), [SQ])


def test_bounds_contain_the_mesh():
    lo, hi = shapes_bounds([SQ, SQ.with_pose(posed(1.0))])
    v = np.concatenate(
        [superquadric_trimesh(s, 24).vertices for s in (SQ, SQ.with_pose(posed(1.0)))]
    )
    assert (v >= lo).all() and (v <= hi).all()
    assert shapes_bounds([]).shape == (2, 3)
