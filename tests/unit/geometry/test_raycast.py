"""Line/superquadric intersection (3.4.1): closed-form sphere roots, f = 1 at roots, batching."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from sqmanip.geometry.raycast import (
    farthest_intersection,
    first_hits,
    line_intersections,
    world_line_intersections,
)
from sqmanip.geometry.superquadric import implicit

SPHERE = [0.1, 0.1, 0.1, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_sphere_entry_and_exit_match_closed_form(dtype):
    o = torch.tensor([[-1.0, 0.05, 0.0], [-1.0, 0.0, 0.0], [-1.0, 0.2, 0.0]], dtype=dtype)
    d = torch.tensor([[1.0, 0.0, 0.0]] * 3, dtype=dtype)
    hits = line_intersections(o, d, torch.tensor(SPHERE, dtype=dtype))
    assert hits.t.shape == (3, 2)
    h = np.sqrt(0.01 - 0.0025)
    tol = 1e-5 if dtype == torch.float32 else 1e-10
    assert hits.valid[0].all() and hits.valid[1].all() and not hits.valid[2].any()
    assert torch.allclose(hits.t[0], torch.tensor([1 - h, 1 + h], dtype=dtype), atol=tol)
    assert torch.allclose(hits.t[1], torch.tensor([0.9, 1.1], dtype=dtype), atol=tol)


def test_origin_inside_gives_only_the_exit_and_t_on_surface_start_is_dropped():
    p = torch.tensor(SPHERE, dtype=torch.float64)
    o = torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]], dtype=torch.float64)
    d = torch.tensor([[0.0, 0.0, 2.0], [-1.0, 0.0, 0.0]], dtype=torch.float64)
    hits = line_intersections(o, d, p)
    assert hits.valid.sum(-1).tolist() == [1, 1]
    assert torch.allclose(hits.t[0, 0], torch.tensor(0.05, dtype=torch.float64))  # t in |d| units
    assert torch.allclose(hits.t[1, 0], torch.tensor(0.2, dtype=torch.float64))  # the far side
    far, ok = farthest_intersection(hits)
    assert ok.all() and torch.allclose(far, torch.tensor([0.05, 0.2], dtype=torch.float64))


def test_posed_box_roots_match_slab_closed_form():
    # a3 = 0.05 box-like superquadric, rotated 90 deg about z and moved to (1, 0, 0)
    p = torch.tensor([0.1, 0.2, 0.05, 0.2, 0.2, 0, 0, 0, 0], dtype=torch.float64)
    T = torch.eye(4, dtype=torch.float64)
    T[:3, :3] = torch.tensor([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]], dtype=torch.float64)
    T[0, 3] = 1.0
    o = torch.tensor([[0.0, 0.0, 0.0]], dtype=torch.float64)
    d = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)
    hits = line_intersections(o, d, p, T)
    # world x extent is the object's y extent 0.2 (e = 0.2 is flat at face centres)
    assert torch.allclose(hits.t[0], torch.tensor([0.8, 1.2], dtype=torch.float64), atol=1e-6)


DEFORMED = [
    (0, [0.1, 0.2, 0.3, 0.2, 0.2, 0.0, 0.0, 0.0, 0.0]),
    (0, [0.1, 0.2, 0.3, 1.7, 1.0, 0.5, 1.0, 0.3, 0.0]),
    (0, [0.02, 0.02, 0.3, 0.5, 1.0, 0.9, 2.5, 1.0, 0.0]),
    (1, [0.1, 0.1, 0.2, 0.5, 1.0, 0.0, 0.0, 0.0, 0.0]),
    (2, [0.05, 0.05, 0.05, 0.3, 0.2, 0.2, 1.0, 0.0, 2.0]),
]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize(("kind", "p"), DEFORMED)
def test_roots_satisfy_implicit_and_are_sorted(kind, p, dtype):
    g = torch.Generator().manual_seed(0)
    o = (torch.randn(2000, 3, generator=g, dtype=torch.float64) * 0.3).to(dtype)
    d = torch.randn(2000, 3, generator=g, dtype=torch.float64).to(dtype)
    params = torch.tensor(p, dtype=dtype)
    hits = line_intersections(o, d, params, kind=kind)
    assert hits.valid.any()
    x = o.unsqueeze(1) + hits.t.unsqueeze(-1) * d.unsqueeze(1)
    f = implicit(x.reshape(-1, 3), params, kind).reshape(hits.t.shape)
    tol = 1e-3 if dtype == torch.float32 else 1e-7
    assert ((f - 1).abs()[hits.valid] < tol).all()
    assert (hits.t[hits.valid] > 0).all()
    t = torch.where(hits.valid, hits.t, torch.full_like(hits.t, float("inf")))
    assert (t[:, 1:] >= t[:, :-1]).all()
    # lines starting outside the shape cross it an even number of times
    outside = implicit(o, params, kind) > 1.01
    assert (hits.valid.sum(-1)[outside] % 2 == 0).float().mean() > 0.99


def test_batched_equals_unbatched():
    g = torch.Generator().manual_seed(1)
    params = torch.tensor([SPHERE, DEFORMED[1][1]], dtype=torch.float64)
    o = torch.randn(2, 50, 3, generator=g, dtype=torch.float64) * 0.3
    d = torch.randn(2, 50, 3, generator=g, dtype=torch.float64)
    batched = line_intersections(o, d, params)
    for i in range(2):
        single = line_intersections(o[i], d[i], params[i])
        k = single.t.shape[-1]
        assert torch.equal(batched.valid[i, :, :k], single.valid)
        assert not batched.valid[i, :, k:].any()
        assert torch.allclose(batched.t[i, :, :k][single.valid], single.t[single.valid])


def test_world_intersections_with_mixed_kinds_and_first_hits():
    params = torch.tensor([SPHERE, DEFORMED[4][1]], dtype=torch.float64)
    poses = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    poses[1, 0, 3] = 1.0
    o = torch.tensor([[-1.0, 0.0, 0.0], [1.0, 0.0, -1.0]], dtype=torch.float64)
    d = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    hits = world_line_intersections(o, d, params, poses, torch.tensor([0, 2]))
    assert hits.t.shape[:2] == (2, 2)
    # line 0 along x hits the sphere (2 roots) and the torus (4 roots: through both tubes)
    assert hits.valid[0, 0].sum() == 2 and hits.valid[1, 0].sum() == 4
    # line 1 goes up through the torus hole
    assert hits.valid[1, 1].sum() == 0
    t, ids = first_hits(o, d, params, poses, torch.tensor([0, 2]))
    assert ids.tolist() == [0, -1] and torch.isinf(t[1])
    assert torch.allclose(t[0], torch.tensor(0.9, dtype=torch.float64))


def test_empty_inputs_return_early():
    p = torch.tensor(SPHERE)
    hits = line_intersections(torch.zeros(0, 3), torch.zeros(0, 3), p)
    assert hits.t.shape == (0, 0)
    miss = line_intersections(torch.tensor([[5.0, 5, 5]]), torch.tensor([[1.0, 0, 0]]), p)
    assert miss.t.shape == (1, 0)
    t, ids = first_hits(
        torch.zeros(3, 3), torch.ones(3, 3), torch.zeros(0, 9), torch.zeros(0, 4, 4)
    )
    assert t.shape == (3,) and (ids == -1).all()


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match="origins"):
        line_intersections(torch.zeros(3), torch.zeros(3), torch.tensor(SPHERE))
    with pytest.raises(ValueError, match="poses"):
        line_intersections(torch.zeros(1, 3), torch.ones(1, 3), torch.tensor(SPHERE), torch.eye(3))


@settings(max_examples=20, deadline=None)
@given(
    e1=st.floats(0.2, 1.7),
    e2=st.floats(0.2, 1.7),
    k=st.floats(-0.9, 0.9),
    bp=st.floats(0.01, 0.75),
    alpha=st.floats(-np.pi, np.pi),
)
def test_lines_through_the_centre_cross_every_deformed_shape(e1, e2, k, bp, alpha):
    a1, a2, a3 = 0.08, 0.05, 0.15
    p = torch.tensor([a1, a2, a3, e1, e2, k, bp / max(a1, a2), alpha, 0.0], dtype=torch.float64)
    d = torch.nn.functional.normalize(
        torch.randn(64, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64), dim=-1
    )
    o = -d  # from 1 m away, through the object origin (inside the shape for these params)
    hits = line_intersections(o, d, p)
    assert torch.isfinite(hits.t).all()
    assert (hits.valid.sum(-1) >= 2).all()
    x = o.unsqueeze(1) + hits.t.unsqueeze(-1) * d.unsqueeze(1)
    f = implicit(x.reshape(-1, 3), p).reshape(hits.t.shape)
    assert ((f - 1).abs()[hits.valid] < 1e-7).all()
