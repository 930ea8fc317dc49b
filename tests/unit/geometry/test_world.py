"""Posed superquadrics in the world frame (C.2.5, C.2.6, C.2.10)."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from sq_strategies import deformed_params, seeds
from sqmanip.geometry import (
    SUPERELLIPSOID,
    SUPERPARABOLOID,
    SUPERTOROID,
    Superquadric,
    implicit_homogeneous,
    normal,
    occupied,
    pack,
    pose_from_pq,
    se3_inverse,
    soft_occupancy,
    to_object_frames,
    transform_points,
    union_implicit,
    world_implicit,
    world_normal,
)

HYP = settings(max_examples=20, deadline=None)


def _poses(seed: int, m: int, dtype=torch.float64) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return pose_from_pq(
        torch.randn(m, 3, generator=g, dtype=dtype) * 0.3,
        torch.randn(m, 4, generator=g, dtype=dtype),
    )


def _scene(dtype=torch.float64):
    params = torch.tensor(
        [
            [0.10, 0.10, 0.10, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0],
            [0.05, 0.08, 0.12, 0.3, 0.6, 0.2, 1.0, 0.5, 0.0],
            [0.04, 0.04, 0.03, 1.0, 1.0, 0.0, 0.0, 0.0, 2.0],
        ],
        dtype=dtype,
    )
    poses = torch.eye(4, dtype=dtype).repeat(3, 1, 1)
    poses[0, :3, 3] = torch.tensor([0.0, 0.0, 0.0])
    poses[1, :3, 3] = torch.tensor([0.5, 0.0, 0.0])
    poses[2, :3, 3] = torch.tensor([0.0, 0.5, 0.0])
    kinds = torch.tensor([SUPERELLIPSOID, SUPERELLIPSOID, SUPERTOROID])
    return params, poses, kinds


@HYP
@given(params=deformed_params(), seed=seeds())
def test_world_implicit_is_invariant_to_moving_points_and_shape_together(params, seed):
    T = _poses(seed, 1)
    x = torch.randn(40, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(seed)) * 0.3
    local = implicit_homogeneous(x, params)
    moved = world_implicit(transform_points(T[0], x), params[None], T)
    assert moved.shape == (1, 40)
    torch.testing.assert_close(moved[0], local)


def test_to_object_frames_applies_inverse_poses(dtype, tol):
    poses = _poses(1, 4, dtype)
    x = torch.randn(7, 3, dtype=dtype)
    local = to_object_frames(x, poses)
    assert local.shape == (4, 7, 3)
    torch.testing.assert_close(
        local[2], transform_points(se3_inverse(poses[2]), x), **tol(dtype, 10)
    )


def test_mixed_kinds_use_each_shape_s_own_function(dtype):
    params, poses, kinds = _scene(dtype)
    x = torch.tensor(
        [[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.5, 0.0], [0.08, 0.5, 0.0]], dtype=dtype
    )
    S = world_implicit(x, params, poses, kinds)
    N = world_normal(x, params, poses, kinds)  # regression: the kind mask was (M, 1) for (M, N, 3)
    assert S.shape == (3, 4) and N.shape == (3, 4, 3)
    for i, kind in enumerate(kinds.tolist()):
        local = to_object_frames(x, poses[i : i + 1])[0]
        torch.testing.assert_close(S[i], implicit_homogeneous(local, params[i], kind))
        torch.testing.assert_close(N[i], normal(local, params[i], kind) @ poses[i, :3, :3].T)
    # The torus centre (0, 0.5, 0) lies in its hole: outside; its tube at radius 0.08 is inside.
    assert S[2, 2] > 1 and S[2, 3] < 1


def test_union_occupancy_and_soft_occupancy(dtype):
    params, poses, kinds = _scene(dtype)
    x = torch.tensor(
        [[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.08, 0.5, 0.0], [0.0, 0.5, 0.0], [2.0, 2.0, 2.0]],
        dtype=dtype,
    )
    F = union_implicit(x, params, poses, kinds)
    torch.testing.assert_close(F, world_implicit(x, params, poses, kinds).amin(0))
    assert occupied(x, params, poses, kinds).tolist() == [True, True, True, False, False]
    V = soft_occupancy(x, params, poses, kinds)
    assert ((V > 0.99) == torch.tensor([True, True, True, False, False])).all()
    assert ((V >= 0) & (V <= 1)).all()


def test_empty_scene_is_unoccupied(dtype):
    x = torch.rand(6, 3, dtype=dtype)
    params, poses = torch.zeros(0, 9, dtype=dtype), torch.zeros(0, 4, 4, dtype=dtype)
    assert torch.isinf(union_implicit(x, params, poses)).all()
    assert not occupied(x, params, poses).any()
    assert (soft_occupancy(x, params, poses) == 0).all()


def test_world_normal_is_rotated_local_normal(dtype, tol):
    params = torch.tensor([[0.1, 0.2, 0.15, 0.5, 1.2, 0.3, 1.0, 0.2, 0.0]], dtype=dtype)
    poses = _poses(2, 1, dtype)
    x = torch.randn(9, 3, dtype=dtype) * 0.2
    n = world_normal(x, params, poses, SUPERELLIPSOID)
    assert n.shape == (1, 9, 3)
    local = normal(to_object_frames(x, poses)[0], params[0])
    torch.testing.assert_close(n[0], local @ poses[0, :3, :3].T, **tol(dtype, 10))


@pytest.mark.parametrize("batch", [(), (1,), (3, 1)])
def test_batched_scenes(batch, dtype):
    params, poses, kinds = _scene(dtype)
    params = params.expand(*batch, 3, 9)
    poses = poses.expand(*batch, 3, 4, 4)
    x = torch.rand(*batch, 5, 3, dtype=dtype)
    assert world_implicit(x, params, poses, kinds).shape == (*batch, 3, 5)
    assert union_implicit(x, params, poses, kinds).shape == (*batch, 5)
    assert world_normal(x, params, poses, kinds).shape == (*batch, 3, 5, 3)


def test_pack_round_trips_superquadrics():
    sq = Superquadric(
        (0.1, 0.2, 0.3),
        (0.5, 1.0),
        pose=_poses(3, 1)[0].numpy(),
        kind="supertoroid",
        a4=2.0,
        taper=0.1,
    )
    packed = pack([sq, sq.with_pose(torch.eye(4).numpy())], dtype=torch.float64)
    assert packed.params.shape == (2, 9) and packed.kinds.tolist() == [SUPERTOROID, SUPERTOROID]
    torch.testing.assert_close(packed.poses[0], torch.as_tensor(sq.pose))
    assert packed.params[0, 8] == 2.0 and packed.params[0, 5] == 0.1
    assert len(pack([])) == 0
    assert (
        Superquadric((0.1, 0.1, 0.1), (1.0, 1.0), kind="superparaboloid").kind_index
        == SUPERPARABOLOID
    )


def test_bad_shapes_raise():
    params, poses, kinds = _scene()
    with pytest.raises(ValueError, match="points"):
        world_implicit(torch.zeros(5, 2, dtype=torch.float64), params, poses, kinds)
    with pytest.raises(ValueError, match=r"\(\.\.\., 4, 4\)"):
        world_implicit(torch.zeros(5, 3, dtype=torch.float64), params, poses[..., :3, :], kinds)
    with pytest.raises(ValueError, match="pose"):
        Superquadric((0.1, 0.1, 0.1), (1.0, 1.0), pose=torch.eye(3).numpy())
