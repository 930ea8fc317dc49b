"""Grasp candidates from a grasp planner (the grasp service's ``plan`` when search runs as a
service) against the in-process C.3 rule: same candidates, same ``g``, one call per shape."""

from __future__ import annotations

import numpy as np
import torch
from sqmanip.geometry import Superquadric
from sqmanip.grasping import GraspPlanner
from sqmanip.grasping.config import always_reachable
from sqmanip.search import (
    KinematicPushDynamics,
    SceneState,
    SearchConfig,
    SearchPlanner,
    ShelfSpec,
    TargetSpec,
)
from sqmanip.search.actions import GraspSource

SHELF = ShelfSpec()
TARGET = TargetSpec.cylinder(0.025, 0.10)
CFG = SearchConfig(resolution=0.04)


def obj(x, y, sx, sy, h, e2=0.2, yaw=0.3):
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = (x, y, SHELF.bottom_z + h / 2)
    return Superquadric((sx / 2, sy / 2, h / 2), (0.2, e2), T)


class Counting:
    """A GraspPlanner that counts its ``plan`` calls (stands in for the remote client)."""

    def __init__(self) -> None:
        self.inner = GraspPlanner(always_reachable)
        self.calls = 0

    def plan(self, *args, **kwargs):
        self.calls += 1
        return self.inner.plan(*args, **kwargs)


def _sorted(poses: torch.Tensor) -> np.ndarray:
    a = poses.double().reshape(len(poses), -1).numpy().round(5)
    return a[np.lexsort(a.T[::-1])]


def test_planner_source_gives_the_in_process_candidates():
    rule = (
        SearchPlanner(KinematicPushDynamics(), None, CFG)
        .models(SHELF, TARGET, SHELF.camera())[2]
        .rule
    )
    for o in (obj(0.0, 0.0, 0.05, 0.07, 0.15), obj(0.0, 0.0, 0.06, 0.06, 0.12, e2=1.0)):
        local = GraspSource()(o, rule)
        remote = GraspSource(Counting())(o, rule)
        assert local.shape[0] > 0 and local.shape == remote.shape
        np.testing.assert_allclose(_sorted(local), _sorted(remote), atol=1e-4)


def test_search_with_a_grasp_planner_matches_in_process_and_asks_once_per_shape():
    torch.set_num_threads(1)
    counting = Counting()
    remote = SearchPlanner(KinematicPushDynamics(), None, CFG, grasp_planner=counting)
    local = SearchPlanner(KinematicPushDynamics(), None, CFG)
    objs = [obj(0.60, 0.0, 0.05, 0.07, 0.15), obj(0.66, 0.2, 0.06, 0.06, 0.12, e2=1.0)]
    maps = []
    for p in (local, remote):
        _, ev, sampler = p.models(SHELF, TARGET, SHELF.camera())
        m = ev.maps(SceneState.from_objects(objs))
        maps.append(m)
        for i in range(len(objs)):
            sampler.grasps(SceneState.from_objects(objs), i)
    assert torch.equal(maps[0].f, maps[1].f) and torch.equal(maps[0].g, maps[1].g)
    n_target = len(CFG.grasp_yaws_deg)  # the target's templates: one call per yaw
    assert counting.calls == n_target + len(objs)
    _, _, sampler = remote.models(SHELF, TARGET, SHELF.camera())
    moved = [obj(0.70, -0.1, 0.05, 0.07, 0.15), objs[1]]  # translated: reused, no call
    sampler.grasps(SceneState.from_objects(moved), 0)
    assert counting.calls == n_target + len(objs)
