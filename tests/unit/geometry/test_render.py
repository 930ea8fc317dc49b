"""Depth rendering (Appendix C.2): closed-form sphere/box depths, culling, batching, point clouds."""

import numpy as np
import pytest
import torch
from sqmanip.geometry import Superquadric, pack
from sqmanip.geometry.render import (
    TAU,
    PinholeCamera,
    depth_to_points,
    range_to_z,
    raycast_depth,
    render_depth,
    render_point_cloud,
)
from sqmanip.geometry.world import world_implicit

CAM = PinholeCamera.look_at([0.0, 0.0, 1.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0)).scaled(0.125)
SPHERE = torch.tensor([[0.1, 0.1, 0.1, 1.0, 1.0, 0, 0, 0, 0]], dtype=torch.float64)
BOX = torch.tensor([[0.1, 0.1, 0.05, 0.2, 0.2, 0, 0, 0, 0]], dtype=torch.float64)
EYE = torch.eye(4, dtype=torch.float64)[None]


def sphere_closed_form(cam):
    o, d = cam.rays(torch.float64)
    od = (o * d).sum(-1)
    disc = od**2 - ((o * o).sum() - 0.01)
    return torch.where(disc > 0, -od - disc.clamp_min(0).sqrt(), torch.tensor(np.inf)), disc


def test_camera_look_at_convention():
    cam = PinholeCamera.look_at([1.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    R = cam.pose[:3, :3]
    assert np.allclose(R[:, 2], [-1, 0, 0])  # looks along +z
    assert np.allclose(R[:, 1], [0, 0, -1])  # image y is down
    assert np.allclose(np.linalg.det(R), 1.0)
    o, d = cam.rays(torch.float64)
    assert d.shape == (576, 640, 3)
    centre = d[287:289, 319:321].mean((0, 1))
    assert torch.allclose(
        centre / centre.norm(), torch.tensor([-1.0, 0, 0], dtype=torch.float64), atol=1e-6
    )
    with pytest.raises(ValueError, match="pose"):
        PinholeCamera(pose=np.eye(3))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_soft_depth_of_sphere_matches_closed_form_plus_absorption_length(dtype):
    exact, disc = sphere_closed_form(CAM)
    D = render_depth(SPHERE.to(dtype), EYE.to(dtype), CAM, n_samples=128).double()
    thick = disc > 0.0025  # chord > 0.1 m, so light is absorbed within it
    # the soft renderer stops ~1/tau inside the surface (C.2.7, C.2.8)
    err = (D - exact - 1.0 / TAU)[thick]
    assert err.abs().max() < 3e-3
    miss = disc < -0.01  # clearly outside the sphere: exactly t_far
    assert torch.allclose(D[miss], torch.full_like(D[miss], 1.5), atol=1e-6, rtol=0)


def test_exact_raycast_depth_of_sphere_and_box():
    exact, disc = sphere_closed_form(CAM)
    t, ids = raycast_depth(SPHERE, EYE, CAM)
    hit = disc > 1e-4
    assert torch.allclose(t[hit], exact[hit], atol=1e-8)
    assert (ids[hit] == 0).all() and (ids[disc < -1e-4] == -1).all()
    # box top face z = 0.05 seen from z = 1: t = 0.95 / cos; e = 0.2 is flat to 0.2 mm inside 70 %
    o, d = CAM.rays(torch.float64)
    tb, _ = raycast_depth(BOX, EYE, CAM)
    t_face = 0.95 / (-d[..., 2])
    xy = (o + t_face.unsqueeze(-1) * d)[..., :2]
    inner = (xy.abs() < 0.07).all(-1)
    assert inner.sum() > 20
    assert torch.allclose(tb[inner], t_face[inner], atol=3e-4)
    Db = render_depth(BOX, EYE, CAM, n_samples=256)
    assert ((Db - t_face - 1.0 / TAU)[inner]).abs().max() < 3e-3


def test_culling_does_not_change_the_depth():
    scene = torch.tensor(
        [[0.1, 0.1, 0.1, 1.0, 1.0, 0, 0, 0, 0], [0.05, 0.08, 0.1, 0.3, 0.6, 0.4, 2.0, 0.5, 0]],
        dtype=torch.float64,
    )
    poses = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    poses[1, :3, 3] = torch.tensor([0.15, 0.1, 0.05], dtype=torch.float64)
    # same quadrature accuracy, samples on the ellipsoid chords vs on all of [t_n, t_f]
    cam = PinholeCamera.look_at(
        [0.0, 0.0, 1.0], [0.0, 0.0, 0.0], width=32, height=32, fx=40.0, fy=40.0, cx=15.5, cy=15.5
    )
    culled = render_depth(scene, poses, cam, n_samples=1024)
    full = render_depth(scene, poses, cam, n_samples=4096, cull=False)
    assert (culled < 1.4).sum() > 50
    assert (culled - full).abs().max() < 2e-3
    assert torch.isfinite(culled).all()


def test_batched_scenes_equal_single_renders_and_mixed_kinds():
    g = torch.Generator().manual_seed(0)
    B, M = 3, 3
    params = torch.tensor([0.06, 0.05, 0.08, 0.5, 0.8, 0.1, 0.5, 0.0, 2.0]).repeat(B, M, 1)
    poses = torch.eye(4).repeat(B, M, 1, 1)
    poses[..., :2, 3] = torch.rand(B, M, 2, generator=g) * 0.4 - 0.2
    kinds = torch.tensor([0, 1, 2])
    batched = render_depth(params, poses, CAM, kinds, n_samples=16)
    assert batched.shape == (B, CAM.height, CAM.width)
    for b in range(B):
        single = render_depth(params[b], poses[b], CAM, kinds, n_samples=16)
        assert torch.allclose(batched[b], single, atol=1e-6)
    assert (batched < 1.5).any()


def test_empty_scene_and_bad_inputs():
    D = render_depth(torch.zeros(2, 0, 9), torch.zeros(2, 0, 4, 4), CAM)
    assert D.shape == (2, CAM.height, CAM.width) and (D == 1.5).all()
    with pytest.raises(ValueError, match="poses"):
        render_depth(SPHERE, torch.eye(4), CAM)
    with pytest.raises(ValueError, match="kinds"):
        render_depth(SPHERE, EYE, CAM, kinds=torch.tensor([0, 1]))
    pts, ids = render_point_cloud([], CAM)
    assert pts.shape == (0, 3) and ids.shape == (0,)


def test_point_cloud_of_object_on_table_is_labelled_and_on_surfaces():
    table_pose = np.eye(4)
    table_pose[2, 3] = -0.02
    obj_pose = np.eye(4)
    obj_pose[:3, 3] = [0.05, 0.0, 0.08]
    parts = [
        Superquadric((0.04, 0.04, 0.08), (0.2, 1.0), pose=obj_pose),
        Superquadric((0.5, 0.5, 0.02), (0.2, 0.2), pose=table_pose),
    ]
    cam = PinholeCamera.look_at([0.5, 0.0, 0.5], [0.0, 0.0, 0.0]).scaled(0.25)
    pts, ids, pix = render_point_cloud(parts, cam, return_pixels=True, dtype=torch.float64)
    assert pts.shape[0] == ids.shape[0] == pix.shape[0] > 0
    assert set(np.unique(ids).tolist()) == {0, 1}
    t = pack(parts, dtype=torch.float64)
    S = world_implicit(torch.tensor(pts), t.params, t.poses)
    own = S[torch.tensor(ids), torch.arange(len(ids))]
    assert (own - 1).abs().max() < 1e-6
    # visible points are not inside any other part
    assert (S.amin(0) > 1 - 1e-6).all()
    # depth_to_points round trip
    depth, _ = raycast_depth(t.params, t.poses, cam, t.kinds)
    back, pix2 = depth_to_points(depth, cam)
    assert np.allclose(back, pts) and np.array_equal(pix, pix2)
    z = range_to_z(depth, cam)
    assert (z[torch.isfinite(depth)] <= depth[torch.isfinite(depth)]).all()
