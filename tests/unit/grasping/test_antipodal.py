"""Antipodal pairs (3.4.1) and the approach directions about each pair (3.4.2)."""

import math

import numpy as np
import pytest
import torch
from grasp_helpers import box, lying_cylinder, pose
from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric, pack, world_implicit, world_normal
from sqmanip.grasping import poses_about_axis, sample_antipodal_pairs


def test_lying_cylinder_pairs_are_antipodal_and_on_the_surface():
    cyl = lying_cylinder()
    pairs = sample_antipodal_pairs([cyl], 200, generator=1)
    assert len(pairs) > 100
    packed = pack([cyl], dtype=torch.float64)
    for x in (pairs.x1, pairs.x2):
        S = world_implicit(x, packed.params, packed.poses, packed.kinds)[0]
        assert torch.allclose(S, torch.ones_like(S), atol=1e-5)  # both contacts on the surface
    # normals opposite within the relaxed test, recomputed independently of the planner
    n1 = world_normal(pairs.x1, packed.params, packed.poses, packed.kinds)[0]
    n2 = world_normal(pairs.x2, packed.params, packed.poses, packed.kinds)[0]
    assert ((n1 * n2).sum(-1) < -0.9).all()
    # (3.4.8): x2 lies on the line through x1 along its normal
    d = pairs.x2 - pairs.x1
    assert torch.linalg.cross(d, n1).norm(dim=-1).max() < 1e-6
    assert torch.allclose(d.norm(dim=-1), pairs.width)
    # the farthest valid root: across the diameter (5 cm) or along the axis (16 cm), nothing shorter
    w = pairs.width.numpy()
    near = np.minimum(np.abs(w - 0.05), np.abs(w - 0.16))
    assert (near < 2e-3).mean() > 0.9


def test_box_pairs_span_the_three_widths_only():
    b = box((0.02, 0.06, 0.05), pose(0.0, 0.0, 0.0, (0.1, 0.2, 0.3)))
    pairs = sample_antipodal_pairs([b], 300, generator=0)
    w = pairs.width.numpy()
    ok = np.min(np.abs(w[:, None] - np.array([0.04, 0.12, 0.10])[None]), -1) < 2e-3
    assert ok.mean() > 0.95


def test_threshold_one_rejects_what_zero_accepts():
    # a sphere: every line through x1 along -n passes the centre, normals exactly opposite
    s = Superquadric((0.03, 0.03, 0.03), (1.0, 1.0), np.eye(4))
    assert len(sample_antipodal_pairs([s], 50, threshold=0.999)) == 50
    # a strongly tapered cone-like shape: many lines exit through a slanted face
    cone = Superquadric((0.03, 0.03, 0.05), (0.2, 1.0), np.eye(4), taper=-0.9)
    strict = len(sample_antipodal_pairs([cone], 200, threshold=0.99))
    loose = len(sample_antipodal_pairs([cone], 200, threshold=0.0))
    assert strict < loose


def test_samples_buried_in_another_part_are_dropped():
    outer = Superquadric((0.04, 0.04, 0.04), (1.0, 1.0), np.eye(4))
    inner = Superquadric((0.01, 0.01, 0.06), (1.0, 1.0), np.eye(4))  # pokes out at the poles
    pairs = sample_antipodal_pairs([outer, inner], 300, generator=0)
    packed = pack([outer, inner], dtype=torch.float64)
    S = world_implicit(pairs.samples, packed.params, packed.poses, packed.kinds)
    assert (S.amin(0) > 1 - 1e-6).all()  # every kept sample is on the union's surface


def test_multi_part_farthest_point_crosses_parts():
    # two touching spheres on the x axis: lines along x from the far side of one exit the other
    a = Superquadric((0.02, 0.02, 0.02), (1.0, 1.0), pose(-0.019, 0, 0))
    b = Superquadric((0.02, 0.02, 0.02), (1.0, 1.0), pose(0.019, 0, 0))
    pairs = sample_antipodal_pairs([a, b], 400, generator=0)
    crossing = pairs.part1 != pairs.part2
    assert crossing.any()
    assert pairs.width[crossing].max() > 0.07


def test_empty_target_is_rejected():
    with pytest.raises(ValidationError, match="at least one part"):
        sample_antipodal_pairs([], 10)


def test_poses_about_axis_are_rotations_30_degrees_apart_starting_top_down():
    axis = torch.tensor([[1.0, 0.0, 0.0], [0.3, 0.2, 0.9], [0.0, 0.0, 1.0]], dtype=torch.float64)
    center = torch.zeros(3, 3, dtype=torch.float64)
    T = poses_about_axis(center, axis, np.array([0.0, 0.0, 1.0]), 12)
    assert T.shape == (3, 12, 4, 4)
    R = T[..., :3, :3]
    eye = torch.eye(3, dtype=torch.float64).expand_as(R)
    assert torch.allclose(R.transpose(-1, -2) @ R, eye, atol=1e-12)
    assert torch.allclose(torch.linalg.det(R), torch.ones(3, 12, dtype=torch.float64))
    # closing axis = normalised pair axis; approach perpendicular to it
    y = axis / axis.norm(dim=-1, keepdim=True)
    assert torch.allclose(R[..., 1], y.unsqueeze(1).expand(-1, 12, -1), atol=1e-12)
    z = R[..., 2]
    cos_next = (z * torch.roll(z, -1, dims=1)).sum(-1)
    assert torch.allclose(cos_next, torch.full_like(cos_next, math.cos(math.pi / 6)))
    # first pose: straight down for a horizontal axis; the most downward one in general
    assert torch.allclose(z[0, 0], torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64))
    assert (z[:, 0, 2] <= z[:, :, 2].amin(-1) + 1e-12).all()
    assert torch.isfinite(T).all()  # vertical axis (no unique top-down) still gives frames
