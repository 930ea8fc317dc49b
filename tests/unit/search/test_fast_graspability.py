"""Fast graspability (voxel correlation, C.3) against the exact afterimage point test, the
cached per-object existence path and the planner's execution filter."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sqmanip.geometry import Superquadric
from sqmanip.search import (
    ExistenceModel,
    GraspabilityModel,
    KinematicPushDynamics,
    Obstacles,
    SceneState,
    SearchConfig,
    SearchPlanner,
    ShelfSpec,
    TargetSpec,
    make_pose_grid,
)
from sqmanip.search.actions import Push
from sqmanip.search.objective import FGEvaluator

SHELF = ShelfSpec()
TARGET = TargetSpec.cylinder(0.025, 0.10)
CFG = SearchConfig(resolution=0.04)


def obj(x, y, sx, sy, h, e2=0.2, yaw=0.0):
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = (x, y, SHELF.bottom_z + h / 2)
    return Superquadric((sx / 2, sy / 2, h / 2), (0.2, e2), T)


@pytest.fixture(scope="module")
def gm():
    torch.set_num_threads(1)
    grid = make_pose_grid(SHELF, TARGET, CFG.resolution)
    return GraspabilityModel(SHELF, TARGET, grid, CFG)


SCENES = [
    [obj(0.60, 0.0, 0.06, 0.20, 0.18), obj(0.70, 0.22, 0.08, 0.08, 0.14, 1.0)],
    [obj(0.65, -0.2, 0.05, 0.09, 0.16, yaw=0.7), obj(0.78, 0.05, 0.07, 0.07, 0.12, 1.0)],
    [obj(0.56, 0.12, 0.04, 0.04, 0.11, 1.0), obj(0.62, -0.05, 0.09, 0.05, 0.17, yaw=-0.4)],
]


@pytest.mark.parametrize("objects", SCENES)
def test_voxel_hits_agree_with_exact_point_test_and_never_miss(gm, objects):
    scene = SceneState.from_objects(objects)
    P = len(gm.grid)
    valid = gm.local_valid[gm._theta_index]
    for i in range(len(scene)):
        single = Obstacles.from_tensors(
            scene.params[i : i + 1], scene.poses[i : i + 1], scene.kinds[i : i + 1]
        )
        exact = gm._counts(single, torch.arange(P)).bool()
        fast = gm.object_hits(scene, i)
        assert fast.shape == exact.shape
        assert exact[valid].any()  # the scene does block some grasps
        false_free = (exact & ~fast)[valid].sum()
        assert false_free == 0  # conservative: a colliding grasp is never called free
        agree = (exact == fast)[valid].float().mean()
        assert agree >= 0.95


def test_g_from_voxels_matches_exact_g_on_most_poses(gm):
    scene = SceneState.from_objects(SCENES[0])
    g, g_m, best = gm.evaluate(scene)
    idx = torch.arange(len(gm.grid))
    n = gm.exact_counts(scene, idx)
    valid = gm.local_valid[gm._theta_index]
    n = torch.where(valid, n, torch.full_like(n, 99))
    g_exact = (n.min(-1).values == 0).to(g.dtype)
    assert (g <= g_exact).all()  # fast g never says graspable where the exact g does not
    assert (g == g_exact).float().mean() >= 0.9
    assert g.sum() > 0 and (g_m <= 1).all()
    assert ((best >= 0) | (g == 0)).all()


def test_voxel_lattice_is_exact_under_grid_translation(gm):
    """Moving an object by one grid step moves its hit map by one grid row (integer offsets)."""
    a = SceneState.from_objects([obj(0.64, 0.0, 0.06, 0.10, 0.15)])
    b = SceneState.from_objects([obj(0.64 + CFG.resolution, 0.0, 0.06, 0.10, 0.15)])
    nx, ny = gm.grid.shape
    ha = gm.object_hits(a, 0).reshape(nx, ny, -1)
    hb = gm.object_hits(b, 0).reshape(nx, ny, -1)
    assert torch.equal(ha[:-1], hb[1:])


def test_evaluator_cached_existence_equals_model(gm):
    grid = gm.grid
    em = ExistenceModel(SHELF, TARGET, grid, SHELF.camera(), CFG)
    ev = FGEvaluator(em, gm, CFG)
    scene = SceneState.from_objects(SCENES[0])
    f_model = em.evaluate(scene)
    f_cached = ev.existence(scene)
    assert f_model.sum() > 0
    assert (f_model == f_cached).float().mean() >= 0.98
    m = ev.maps(scene)
    assert m.f.shape == (len(grid),) and np.isfinite(m.J)


def test_planner_drops_pushes_the_hand_cannot_make():
    planner = SearchPlanner(KinematicPushDynamics(), None, CFG)
    inside = Push(
        "push", 0, 1, 0.05, np.eye(4), np.array([0.65, 0.0, 0.27]), np.array([0, 0.05, 0])
    )
    wall = Push("push", 0, 1, 0.15, np.eye(4), np.array([0.65, 0.15, 0.27]), np.array([0, 0.15, 0]))
    assert planner.feasible(inside, SHELF)
    assert not planner.feasible(wall, SHELF)  # the palm would hit the side board


@pytest.mark.parametrize("objects", SCENES)
def test_fast_collision_free_matches_exact_point_test(gm, objects):
    em = ExistenceModel(SHELF, TARGET, gm.grid, SHELF.camera(), CFG)
    scene = SceneState.from_objects(objects)
    exact = em.collision_free(scene)
    fast = em.collision_free_fast(scene)
    assert (~exact).sum() > (~em.fc_shelf).sum()  # the objects do exclude poses
    assert (exact == fast).float().mean() >= 0.97  # exact up to half a 5 mm voxel
