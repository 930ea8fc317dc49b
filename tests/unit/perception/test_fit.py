"""Superquadric fitting: the fused radial distance, full-surface recovery, amodal single views."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sqmanip.geometry import Superquadric, radial_distance, sample_surface, so3_exp, volume_iou
from sqmanip.perception.config import PerceptionSettings
from sqmanip.perception.fit import fit_segments, rests_on_support, tapered_radial_distance
from sqmanip.perception.mvbb import mvbb_fit
from sqmanip.perception.pipeline import Recognizer
from sqmanip.perception.preprocess import PlaneFit
from sqmanip.perception.synthetic import make_single_view
from sqmanip.perception.types import RecognizeOptions, RecognizeRequest


def test_tapered_radial_distance_matches_the_geometry_core():
    g = torch.Generator().manual_seed(0)
    B = 6
    a = 0.02 + 0.1 * torch.rand(B, 3, generator=g)
    e = 0.2 + 1.5 * torch.rand(B, 2, generator=g)
    k = -0.9 + 1.8 * torch.rand(B, 1, generator=g)
    params = torch.cat([a, e, k, torch.zeros(B, 3)], -1).double()
    x = 0.2 * torch.randn(B, 200, 3, generator=g).double()
    mine, scale = tapered_radial_distance(x.numpy(), params.numpy())
    np.testing.assert_allclose(mine, radial_distance(x, params).numpy(), rtol=1e-6, atol=1e-9)
    assert scale.shape == (B, 200)


def test_full_surface_fit_recovers_the_superellipsoid():
    truth = torch.tensor([0.06, 0.04, 0.09, 0.5, 0.8, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    pts, _ = sample_surface(truth, 300, generator=1)
    pose = np.eye(4)
    pose[:3, :3] = so3_exp(torch.tensor([0.3, -0.5, 0.8], dtype=torch.float64)).numpy()
    pose[:3, 3] = [0.2, -0.1, 0.3]
    world = pts.numpy() @ pose[:3, :3].T + pose[:3, 3]
    (fit,) = fit_segments(
        [world],
        amodal=False,
        deformable=False,
        settings=PerceptionSettings(fit_iterations=40, refine_iterations=80),
    )
    gt = Superquadric((0.06, 0.04, 0.09), (0.5, 0.8), pose=pose)
    assert volume_iou([fit.part], [gt], n=20000) > 0.9
    assert np.allclose(sorted(fit.part.size), sorted(gt.size), rtol=0.08)
    assert fit.residual < 1e-6  # rms radial distance below 1 mm


@pytest.mark.parametrize(
    ("kind", "seed"), [("box", 100), ("cylinder", 100), ("ellipsoid", 100), ("cone", 100)]
)
def test_amodal_fit_of_a_single_view_reaches_iou_0_7(kind, seed):
    scene = make_single_view(kind, seed, camera_scale=0.35)
    request = RecognizeRequest(scene.points, labels=scene.object_ids, viewpoint=scene.viewpoint)
    out = Recognizer().recognize(request)
    assert len(out.objects) == 1
    assert volume_iou(out.objects[0].parts, scene.objects[0], n=10000) >= 0.7


def test_amodal_terms_complete_a_cone_that_the_plain_fit_leaves_open():
    scene = make_single_view("cone", 101, camera_scale=0.35)
    ious = {}
    for amodal in (True, False):
        req = RecognizeRequest(
            scene.points,
            labels=scene.object_ids,
            viewpoint=scene.viewpoint,
            options=RecognizeOptions(amodal=amodal),
        )
        out = Recognizer().recognize(req)
        ious[amodal] = volume_iou(out.objects[0].parts, scene.objects[0], n=10000)
    assert ious[True] > ious[False] + 0.2


def test_mvbb_contains_the_points_and_reaches_the_plane():
    rng = np.random.default_rng(0)
    pts = rng.uniform([-0.05, -0.02, 0.03], [0.05, 0.02, 0.1], (500, 3))
    box = mvbb_fit(pts)
    local = (pts - box.pose[:3, 3]) @ box.pose[:3, :3]
    assert np.all(np.abs(local) <= np.array(box.size) + 1e-9)
    from sqmanip.perception.preprocess import PlaneFit

    plane = PlaneFit(np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(0, dtype=bool))
    upright = mvbb_fit(pts, plane)
    assert abs(upright.pose[2, 3] - upright.size[2]) < 1e-9  # bottom face on z = 0
    assert abs(upright.size[2] - 0.05) < 1e-3


@pytest.mark.parametrize("kind", ["cone", "box"])
def test_hand_written_gradient_matches_finite_differences(kind):
    """The optimiser's chain rule (radial distance, free space, support, taper, rotation) is
    the gradient of its loss (central differences), at the initial guesses (w = 0) and away."""
    from sqmanip.perception.fit import _initial_problems, _Problem
    from sqmanip.perception.preprocess import fit_plane_ransac, resample

    scene = make_single_view(kind, 102, camera_scale=0.35)
    rng = np.random.default_rng(0)
    plane = fit_plane_ransac(scene.points, rng, viewpoint=scene.viewpoint)
    table = scene.points[scene.object_ids < 0]
    segment = resample(scene.points[scene.object_ids == 0], 300, rng)
    settings = PerceptionSettings()
    batch, data, _, _ = _initial_problems(
        [segment], plane, scene.viewpoint, table, settings, True, True, 0
    )
    problem = _Problem(batch, data, settings, amodal=True)
    assert problem.use_free and problem.use_support
    rng = np.random.default_rng(1)
    h = 1e-6
    for spread in (0.0, 0.4):
        u = batch.u + spread * rng.standard_normal(batch.u.shape)
        _, _, mine = problem(u, grad=True)
        numeric = np.zeros_like(u)
        for j in range(u.shape[1]):  # rows are independent problems: one column at a time
            step = np.zeros_like(u)
            step[:, j] = h
            numeric[:, j] = (problem(u + step)[0] - problem(u - step)[0]) / (2 * h)
        scale = np.abs(numeric).max(1, keepdims=True)
        np.testing.assert_allclose(mine / scale, numeric / scale, rtol=0, atol=1e-7)


def _flat_box_top_and_table(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """What a camera 0.7 m above sees of a 13 x 34 x 5 cm box (yawed 10 deg) lying on the table:
    its top face 5 cm up, and the table around it (none under it)."""
    c, s = np.cos(0.17), np.sin(0.17)
    R = np.array([[c, s], [-s, c]])
    top = rng.uniform([-0.065, -0.17], [0.065, 0.17], (512, 2)) @ R + [0.5, 0.15]
    top = np.column_stack([top, 0.05 + rng.normal(0, 0.001, len(top))])
    table = rng.uniform([0.2, -0.2, 0.0], [0.8, 0.5, 0.0], (4000, 3))
    uv = (table[:, :2] - [0.5, 0.15]) @ R.T
    table = table[(np.abs(uv[:, 0]) > 0.07) | (np.abs(uv[:, 1]) > 0.175)]
    return top, table


def test_a_segment_rests_on_the_support_unless_something_was_seen_under_it():
    top, table = _flat_box_top_and_table(np.random.default_rng(0))
    assert rests_on_support(top, table, contact=0.03)  # 5 cm up, nothing seen under it
    under = np.column_stack([top[:20, :2], np.zeros(20)])
    assert not rests_on_support(top, np.concatenate([table, under]), contact=0.03)  # table
    neck = top + [0.0, 0.0, 0.10]
    assert not rests_on_support(neck, top, contact=0.03)  # a body seen under it
    assert rests_on_support(top, under, contact=0.06)  # within contact of the plane


def test_flat_box_seen_only_from_above_is_fitted_down_to_the_table():
    """Before, a segment 5 cm up counted as floating and its top face was fitted as a thin
    plate (or a wall standing on its edge), which made the box ungraspable and unpushable."""
    top, table = _flat_box_top_and_table(np.random.default_rng(1))
    plane = PlaneFit(np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(0, dtype=bool))
    fit = fit_segments(
        [top], plane=plane, viewpoint=np.array([0.45, 0.0, 0.72]), table_points=table,
        deformable=False,
    )[0].part  # fmt: skip
    R, size = fit.pose[:3, :3], np.asarray(fit.size)
    vertical = int(np.argmax(np.abs(R[2])))
    assert abs(size[vertical] - 0.025) < 0.005
    assert abs(fit.pose[2, 3] - 0.025) < 0.005
    assert sorted(np.delete(size, vertical)) == pytest.approx([0.065, 0.17], abs=0.02)
