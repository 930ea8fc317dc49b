"""Search domain core (Ch. 5, C.2, C.3): f, g, objective and one MPC decision on toy scenes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric
from sqmanip.search import (
    ExistenceModel,
    GraspabilityModel,
    KinematicPushDynamics,
    SceneState,
    SearchConfig,
    SearchPlanner,
    ShelfSpec,
    TargetSpec,
    existence_reference,
    make_pose_grid,
    sequence_cost,
)

SHELF = ShelfSpec()
TARGET = TargetSpec.cylinder(0.03, 0.12)
CFG = SearchConfig(resolution=0.04)


def box(x, y, sx, sy, h):
    T = np.eye(4)
    T[:3, 3] = (x, y, SHELF.bottom_z + h / 2)
    return Superquadric((sx / 2, sy / 2, h / 2), (0.2, 0.2), T)


@pytest.fixture(scope="module")
def models():
    torch.set_num_threads(1)
    grid = make_pose_grid(SHELF, TARGET, CFG.resolution)
    em = ExistenceModel(SHELF, TARGET, grid, SHELF.camera(), CFG)
    gm = GraspabilityModel(SHELF, TARGET, grid, CFG)
    return grid, em, gm


def idx_near(grid, x, y):
    return int(((grid.xy - torch.tensor([x, y])) ** 2).sum(-1).argmin())


class BlockedBy:
    """A robot grasp check that passes every grasp without the objects and none with them,
    naming object ``i`` as what each refused grasp hits."""

    def __init__(self, i: int) -> None:
        self.i, self.last_blockers = i, []

    def __call__(self, poses, objects):
        self.last_blockers = [frozenset({self.i})] * len(poses) if objects else []
        return np.full(len(poses), not objects)


def test_f_is_one_behind_a_box_and_zero_in_seen_space_and_inside(models):
    grid, em, _ = models
    scene = SceneState.from_objects([box(0.60, 0.0, 0.08, 0.26, 0.25)])
    f = em.evaluate(scene)
    assert f[idx_near(grid, 0.78, 0.0)] == 1  # hidden behind the box
    assert f[idx_near(grid, 0.78, 0.28)] == 0  # seen free space
    assert f[idx_near(grid, 0.60, 0.0)] == 0  # inside the box (f_c)
    empty = em.evaluate(SceneState.from_objects([]))
    assert empty.sum() == 0  # nothing hides the target anywhere


def test_f_tolerates_a_recognized_back_that_reaches_into_the_target(models):
    """A recognized occluder's hidden back is an estimate: one 12 mm too deep reaches into the
    target standing behind it. f_c ignores overlaps up to ``fc_shrink + object_tolerance``
    with the objects, and only ``fc_shrink`` with the shelf, whose boards are known."""
    grid, em, _ = models
    i = idx_near(grid, 0.72, 0.0)
    x = float(grid.xy[i, 0])
    back = x - TARGET.size[0] + 0.012  # 12 mm into the target at grid pose i
    scene = SceneState.from_objects([box(back - 0.04, 0.0, 0.08, 0.26, 0.25)])
    strict = ExistenceModel(
        SHELF, TARGET, grid, SHELF.camera(), dataclasses.replace(CFG, object_tolerance=0.0)
    )
    assert strict.evaluate(scene)[i] == 0
    assert em.evaluate(scene)[i] == 1  # the default tolerance (10 mm more)
    assert torch.equal(strict.fc_shelf, em.fc_shelf)


def test_f_rejects_a_target_that_would_be_partly_seen(models):
    """f_d compares depth on the target's own pixels (C.2 MSE over the footprint, plus the
    5.5.1 found-pixels criterion): the top of a target peeking over a 15 cm box would have
    been seen (about 1,000 camera pixels), though the MSE over the whole image is below the
    0.001 threshold (the reason the test is on the target's pixels); a 17 cm box hides it."""
    grid, em, _ = models
    i = idx_near(grid, 0.78, 0.0)
    low = SceneState.from_objects([box(0.60, 0.0, 0.08, 0.40, 0.15)])
    high = SceneState.from_objects([box(0.60, 0.0, 0.08, 0.40, 0.17)])
    assert em.evaluate(low)[i] == 0 and em.evaluate(high)[i] == 1
    fp = em._foot
    sel = fp.pose == i
    e = (em.object_depth(low, fp.pixel[sel]) - fp.depth[sel]).clamp_min(0)
    assert float((e * e).sum()) / em.n_pixels < em.config.mse_threshold  # whole-image MSE
    assert int((e > em.config.seen_margin).sum()) * em.pixel_area > 500


def test_visible_target_gives_one_hot_f(models):
    grid, em, _ = models
    scene = SceneState.from_objects([box(0.60, 0.0, 0.08, 0.26, 0.25)])
    i = idx_near(grid, 0.70, 0.2)
    f = em.evaluate(scene, visible=True, target_pose=grid.poses[i].numpy())
    assert f.sum() == 1 and f[i] == 1


def z_depth(em, objects):
    """Camera z-depth image of superquadrics at the model's render resolution."""
    from sqmanip.geometry.render import render_depth

    scene = SceneState.from_objects(objects)
    t = render_depth(scene.params, scene.poses, em.camera)
    _, dirs = em.camera.rays(t.dtype)
    return (t * (dirs @ torch.as_tensor(em.camera.pose[:3, 2], dtype=t.dtype))).numpy()


def test_seen_empty_is_measured_on_the_depth_image_and_never_where_the_target_stands(models):
    """The episode's memory of poses seen empty comes from the camera's own depth image: in
    plain view in front of the back wall yes, behind a box no; and where the target actually
    stands the image shows the target, so its pose is never remembered as empty."""
    grid, em, _ = models
    wall = box(0.87, 0.0, 0.02, 0.7, 0.4)
    front = box(0.60, -0.1, 0.08, 0.2, 0.25)
    seen = em.seen_empty(z_depth(em, [wall, front]))
    assert seen[idx_near(grid, 0.78, -0.1)] == 0  # behind the box
    i = idx_near(grid, 0.72, 0.2)
    assert seen[i] == 1  # in plain view
    target = Superquadric(TARGET.size, TARGET.shape, grid.poses[i].double().numpy())
    assert em.seen_empty(z_depth(em, [wall, front, target]))[i] == 0
    assert em.seen_empty(np.zeros((em.camera.height, em.camera.width)))[i] == 1  # nothing hit


def test_fast_existence_matches_reference_render(models):
    grid, em, _ = models
    scene = SceneState.from_objects(
        [box(0.60, 0.05, 0.08, 0.22, 0.25), box(0.66, -0.2, 0.06, 0.06, 0.2)]
    )
    f = em.evaluate(scene).bool()
    sel = torch.arange(0, len(grid), max(1, len(grid) // 12))
    fd_ref, fc_ref = existence_reference(em, scene, sel)
    fc = em.collision_free(scene, torch.ones(len(grid), dtype=torch.bool))
    assert torch.equal(fc[sel], fc_ref)
    agree = (f[sel] == (fd_ref & fc_ref)).float().mean()
    assert agree >= 0.9


def test_g_drops_when_boxes_block_every_approach(models):
    grid, _, gm = models
    i = idx_near(grid, 0.78, 0.0)
    mask = torch.zeros(len(grid), dtype=torch.bool)
    mask[i] = True
    g0, gm0, best0 = gm.evaluate(SceneState.from_objects([]), mask)
    assert g0[i] == 1 and best0[i] >= 0
    wall = [box(0.66, y, 0.06, 0.08, 0.3) for y in (-0.24, -0.16, -0.08, 0.0, 0.08, 0.16, 0.24)]
    g1, gm1, _ = gm.evaluate(SceneState.from_objects(wall), mask)
    assert g1[i] == 0 and gm1[i] <= 0
    assert g0.shape == (len(grid),) and gm1.dtype == gm0.dtype


def test_visible_target_is_grasped_when_the_robot_check_passes_what_the_afterimage_blocks():
    """The afterimage of the recognized shapes (inflated) rules out every grasp of a target
    behind a wall; the robot's own check (``grasp_check``, with the objects as they stand)
    decides: it passes a grasp -> grasp now; it passes none -> rearrange first."""
    torch.set_num_threads(1)
    cfg = SearchConfig(resolution=0.04, n_sequences=4, horizon=1)
    planner = SearchPlanner(KinematicPushDynamics(), None, cfg)
    wall = [box(0.66, y, 0.06, 0.08, 0.3) for y in (-0.24, -0.16, -0.08, 0.0, 0.08, 0.16, 0.24)]
    pose = np.eye(4)
    pose[:3, 3] = (0.78, 0.0, SHELF.bottom_z + TARGET.size[2])
    asked = []

    def robot(passes_with_objects):
        def check(poses, objects):
            asked.append(objects)
            return np.full(len(poses), passes_with_objects or not objects)

        return check

    kw = dict(target_pose=pose, rng=0)
    d = planner.decide(wall, TARGET, SHELF, SHELF.camera(), True, **kw, grasp_check=robot(True))
    assert d.kind == "grasp" and d.fg_map.max() == 0  # g (afterimage) says no, the robot yes
    assert d.params["executable"] and True in asked
    d = planner.decide(wall, TARGET, SHELF, SHELF.camera(), True, **kw, grasp_check=robot(False))
    assert d.kind != "grasp"


def test_sequence_cost_is_discounted_sum_of_differences():
    assert sequence_cost([10.0, 8.0, 8.0, 5.0], 0.5) == pytest.approx(-2.0 + 0.0 + 0.25 * -3.0)


def test_decision_on_toy_scene_reduces_objective():
    torch.set_num_threads(1)
    cfg = SearchConfig(resolution=0.04, n_sequences=8, horizon=2)
    planner = SearchPlanner(KinematicPushDynamics(), None, cfg)
    objs = [box(0.60, 0.0, 0.06, 0.14, 0.22)]
    d = planner.decide(objs, TARGET, SHELF, SHELF.camera(), False, rng=0)
    assert d.kind in ("push", "pick_and_place")
    assert d.f_map.sum() > 0 and d.f_map.shape == d.fg_map.shape
    assert d.objective < 0  # the chosen sequence lowers J (reveals part of the hidden area)
    assert set(d.timings_ms) >= {"f_g", "rollout", "total"}


def test_pushes_stop_short_of_where_the_target_may_stand():
    """A push may not sweep the object into a disc where f = 1 (the target there would be
    shoved along): only the lengths that end before it remain; other directions, and discs
    beside the swept strip, are unaffected."""
    from sqmanip.search import ActionSampler

    sampler = ActionSampler(SHELF, CFG)
    scene = SceneState.from_objects([box(0.60, 0.0, 0.06, 0.06, 0.15)])
    ahead = torch.tensor([[0.60, 0.12, 0.025]])  # first contact after 0.12 - 0.03 - 0.025 m
    assert sampler.push_distances(scene, 0, 1, ahead) == [0.05]
    assert sampler.push_distances(scene, 0, -1, ahead) == [0.05, 0.10, 0.15]
    beside = torch.tensor([[0.70, 0.10, 0.025]])  # behind the strip the box sweeps
    assert sampler.push_distances(scene, 0, 1, beside) == [0.05, 0.10, 0.15]
    assert sampler.push_distances(scene, 0, 1, None) == [0.05, 0.10, 0.15]


def test_pusher_path_keeps_out_of_where_the_target_may_stand():
    """The closed hand moves in from the shelf front to the push start beside the object: a
    pose whose path crosses a disc where f = 1 (below the target's top) is dropped, the other
    direction and discs off the path are not, and a target lower than the hand is passed over."""
    from sqmanip.search import ActionSampler

    scene = SceneState.from_objects([box(0.60, 0.0, 0.06, 0.06, 0.15)])
    sampler = ActionSampler(SHELF, CFG, target_height=0.12)
    both = [p[0] for p in sampler.push_poses(scene, 0)]
    assert both == [1, -1]
    beside = torch.tensor([[0.62, 0.07, 0.025]])  # where the pusher of a push to -y goes
    assert [p[0] for p in sampler.push_poses(scene, 0, beside)] == [1]
    far = torch.tensor([[0.70, 0.30, 0.025]])
    assert [p[0] for p in sampler.push_poses(scene, 0, far)] == [1, -1]
    low = ActionSampler(SHELF, CFG, target_height=0.01)
    assert [p[0] for p in low.push_poses(scene, 0, beside)] == [1, -1]


def test_the_hand_turns_upright_where_the_level_one_has_no_room():
    """Beside a box 9.5 cm from the left board the level hand (20 cm across the push) meets the
    board, so the push to -y starts with the hand upright: its palm clear of the floor, its
    6.3 cm thickness between box and board. The push ends no nearer the board than a level one
    could (:meth:`SearchPlanner.feasible`), and with ``upright_push`` off there is no such push.
    Where the level hand fits, it is used."""
    from sqmanip.search import ActionSampler
    from sqmanip.search.actions import Push

    half_w = SHELF.inner_width / 2
    scene = SceneState.from_objects([box(0.65, half_w - 0.095 - 0.03, 0.06, 0.06, 0.15)])
    sampler = ActionSampler(SHELF, CFG)
    poses = {d: (T, tcp) for d, T, tcp in sampler.push_poses(scene, 0)}
    assert set(poses) == {1, -1}
    T, tcp = poses[-1]
    push = Push.sideways(0, -1, 0.10, T, tcp)
    assert push.upright and not Push.sideways(0, 1, 0.10, *poses[1]).upright
    assert tcp[2] - SHELF.bottom_z > sampler.gripper.palm_size[1] / 2
    assert tcp[1] + sampler.gripper.palm_size[0] / 2 < half_w
    planner = SearchPlanner(KinematicPushDynamics(), None, CFG)
    assert planner.feasible(push, SHELF)
    assert not planner.feasible(Push.sideways(0, 1, 0.05, T, tcp), SHELF)  # to the board
    off = ActionSampler(SHELF, dataclasses.replace(CFG, upright_push=False))
    assert [d for d, *_ in off.push_poses(scene, 0)] == [1]


def test_action_tolerance_opens_a_gap_the_hand_just_misses():
    """A neighbour 1.75 cm from the pushed box blocks the hand at both push starts with exact
    shapes; with the other objects' level half sizes 5 mm smaller (recognized boxes run wide)
    the push to -y is free, and a neighbour 1 cm away still blocks it (the hand of 5.4.4; the
    upright one is tested below)."""
    from sqmanip.search import ActionSampler

    level = dataclasses.replace(CFG, upright_push=False)
    exact = ActionSampler(SHELF, dataclasses.replace(level, action_tolerance=0.0))
    tolerant = ActionSampler(SHELF, dataclasses.replace(level, action_tolerance=0.005))
    pushed = box(0.60, 0.0, 0.06, 0.06, 0.15)
    near = SceneState.from_objects([pushed, box(0.60, -0.0775, 0.06, 0.06, 0.15)])
    assert exact.push_poses(near, 0) == []
    assert [p[0] for p in tolerant.push_poses(near, 0)] == [-1]
    nearer = SceneState.from_objects([pushed, box(0.60, -0.07, 0.06, 0.06, 0.15)])
    assert tolerant.push_poses(nearer, 0) == []
    for bad in (-0.001, float("nan")):
        with pytest.raises(ValidationError, match="action_tolerance"):
            SearchConfig(action_tolerance=bad)


def test_keep_out_contacts_agree_with_every_point_tested():
    """The cluster culling of the keep-out test changes no answer: random hand poses and discs,
    the afterimage and the closed hand, plain and swept, against a test of every point."""
    from sqmanip.search import ActionSampler
    from sqmanip.search.actions import _disc_contacts

    sampler = ActionSampler(SHELF, CFG, target_height=0.12)
    top = SHELF.bottom_z + 0.12
    g = torch.Generator().manual_seed(0)
    touched = []
    for _ in range(40):
        P, Q = 12, 30
        yaw = (torch.rand(P, generator=g) - 0.5) * 3.0
        c, s = torch.cos(yaw), torch.sin(yaw)
        poses = torch.eye(4).repeat(P, 1, 1)
        poses[:, :3, :3] = torch.stack(  # gripper z level along yaw, x down
            [torch.stack([0 * c, 0 * c, -torch.ones(P)], -1),
             torch.stack([-s, c, 0 * c], -1),
             torch.stack([c, s, 0 * c], -1)], -1)  # fmt: skip
        poses[:, :3, 3] = torch.stack(
            [0.5 + 0.35 * torch.rand(P, generator=g), 0.6 * torch.rand(P, generator=g) - 0.3,
             SHELF.bottom_z + 0.15 * torch.rand(P, generator=g)], -1)  # fmt: skip
        discs = torch.stack(
            [0.5 + 0.35 * torch.rand(Q, generator=g), 0.6 * torch.rand(Q, generator=g) - 0.3,
             torch.full((Q,), 0.04)], -1)  # fmt: skip
        for pts in (sampler.after, sampler.closed):
            world = pts[0].reshape(-1, 3).double() @ poses[:, :3, :3].double().mT
            world = world + poses[:, None, :3, 3].double()
            for sweep in (False, True):
                every = (_disc_contacts(world[..., :2], discs.double(), sweep)
                         & (world[..., 2:] < top)).any(1)  # fmt: skip
                got = sampler._keep_out_contacts(pts, poses, discs, sweep)
                assert torch.equal(got, every)
                touched.append(got.float().mean())
    assert 0.01 < float(torch.stack(touched).mean()) < 0.9  # both answers are exercised


def test_push_risk_is_the_share_of_keep_out_discs_a_push_may_touch():
    """The risk of a push is the share of the discs where the target may stand that the
    pushed object's slide or the hand's way in meets: 1/2 for a long push towards one of two
    discs, 0 for a push short of it, away from it, or with no disc at all."""
    from sqmanip.search import ActionSampler
    from sqmanip.search.actions import Push

    sampler = ActionSampler(SHELF, CFG, target_height=0.12)
    scene = SceneState.from_objects([box(0.60, 0.0, 0.06, 0.06, 0.15)])
    poses = {d: (T, tcp) for d, T, tcp in sampler.push_poses(scene, 0)}

    def push(direction, dist):
        T, tcp = poses[direction]
        return Push("push", 0, direction, dist, T, tcp, np.array([0.0, direction * dist, 0.0]))

    discs = torch.tensor([[0.60, 0.12, 0.025], [0.60, -0.40, 0.025]])  # ahead in +y; far away
    assert sampler.push_risk(scene, push(1, 0.15), discs) == pytest.approx(0.5)
    assert sampler.push_risk(scene, push(1, 0.05), discs) == 0.0  # stops 1.5 cm short
    assert sampler.push_risk(scene, push(-1, 0.15), discs) == 0.0
    assert sampler.push_risk(scene, push(1, 0.15), None) == 0.0


def test_fallback_pushes_are_priced_by_the_risk_of_shoving_the_target():
    """Behind the two boxes every push sweeps where the target may stand (the fallback pass):
    the chosen push reports the share it may touch (``target_risk``), and with risk_weight w
    its cost is the objective's plus ``w * target_risk * J_0``."""
    torch.set_num_threads(1)
    objs = [box(0.64, 0.0, 0.05, 0.12, 0.22), box(0.66, 0.2, 0.05, 0.12, 0.22)]
    out = {}
    for weight in (0.0, 1000.0):
        cfg = SearchConfig(
            resolution=0.04,
            n_sequences=16,
            horizon=1,
            actions="push",
            risk_weight=weight,
            object_tolerance=0.0,  # with wide discs, the slides sweep the poses behind
            keep_out_margin=0.03,
        )
        planner = SearchPlanner(KinematicPushDynamics(), None, cfg)
        out[weight] = planner.decide(objs, TARGET, SHELF, SHELF.camera(), False, rng=0)
    _, ev, _ = planner.models(SHELF, TARGET, SHELF.camera())
    J0 = ev.maps(SceneState.from_objects(objs)).J
    free, priced = out[0.0], out[1000.0]
    assert free.kind == priced.kind == "push"
    assert priced.params["target_risk"] > 0  # no push keeps out: the fallback pass
    assert priced.params["target_risk"] <= free.params["target_risk"]
    if priced.params["start"].tolist() == free.params["start"].tolist():
        expected = free.objective + 1000.0 * priced.params["target_risk"] * max(J0, 1.0)
        assert priced.objective == pytest.approx(expected)


def test_sqpdnet_dynamics_in_a_scene_larger_than_the_net_takes():
    """The shipped SQPD-Net takes 4 objects: in a 6-object shelf scene each push moves only
    the 4 objects nearest its start, exactly as the net predicts them alone; the rest stay."""
    from pathlib import Path

    from sqmanip.dynamics.server import load_checkpoint
    from sqmanip.search import SQPDNetDynamics

    torch.set_num_threads(1)
    net = load_checkpoint(Path(__file__).parents[3] / "models" / "sqpdnet")
    objs = [box(0.60, y, 0.05, 0.05, 0.10) for y in (-0.24, -0.15, -0.06, 0.03, 0.12, 0.21)]
    scene = SceneState.from_objects(objs)
    z = SHELF.bottom_z + 0.05
    push = torch.tensor([[0.60, -0.30, z, 0.0, 0.10, 0.0]], dtype=scene.poses.dtype)
    dyn = SQPDNetDynamics(net, SHELF.bottom_z)
    out = dyn.predict(scene.poses, scene.params, push, scene.kinds)
    assert out.shape == (1, 6, 4, 4)
    assert torch.equal(out[0, 4:], scene.poses[4:])  # beyond the 4 nearest: unchanged
    alone = SQPDNetDynamics(net, SHELF.bottom_z).predict(
        scene.poses[:4], scene.params[:4], push, scene.kinds[:4]
    )
    assert torch.allclose(out[0, :4], alone[0], atol=1e-6)
    assert float((out[0, 0, :3, 3] - scene.poses[0, :3, 3]).norm()) > 0.01  # the pushed box moved


def test_pick_grasps_keep_the_fingers_out_of_where_the_target_may_stand():
    """A grasp whose fingers (or their 30 cm approach) come into a disc where f = 1 would drag
    the target along: it is dropped; a disc away from the hand drops none."""
    from sqmanip.search import ActionSampler

    scene = SceneState.from_objects([box(0.60, 0.0, 0.04, 0.06, 0.15)])
    sampler = ActionSampler(SHELF, CFG, target_height=0.12)
    n_all = sampler.grasps(scene, 0).shape[0]
    assert n_all >= 4
    beside = torch.tensor([[0.60, 0.07, 0.035]])  # where a finger closes on the box's side
    assert sampler.grasps(scene, 0, beside).shape[0] < n_all / 2
    far = torch.tensor([[0.70, 0.30, 0.035]])
    assert sampler.grasps(scene, 0, far).shape[0] == n_all


def test_predicted_grasps_count_the_blockers_the_robot_named_until_they_move():
    """A candidate the robot refused on objects 0 and 1 counts both as obstacles in a predicted
    scene until each moved 2 cm; an object the planner does not know (-1) never moves."""
    from sqmanip.search.mpc import _unblocked

    scene = SceneState.from_objects(
        [box(0.6, 0.0, 0.05, 0.05, 0.1), box(0.7, 0.1, 0.05, 0.05, 0.1)]
    )
    moved = SceneState.from_objects(
        [box(0.6, 0.0, 0.05, 0.05, 0.1), box(0.7, 0.15, 0.05, 0.05, 0.1)]
    )
    ok = torch.tensor([True, True, True, False])
    blockers = {0: frozenset({0, 1}), 1: frozenset({-1}), 2: frozenset()}
    i, ok0, extra = _unblocked((5, ok), blockers, scene, None, scene)
    assert i == 5 and torch.equal(ok0, ok) and extra.tolist() == [2, 1, 0, 0]
    _, _, extra = _unblocked((5, ok), blockers, scene, None, moved)
    assert extra.tolist() == [1, 1, 0, 0]


def test_a_moved_object_blocks_the_grasps_whose_arm_sweep_it_enters():
    """With the arm's swept points (``SweptArm``) a blocker that moved counts only while its
    predicted shape still meets the sweep of that grasp, and any object moved into a sweep
    blocks that grasp: object 1 slid 5 cm along candidate 0's sweep still blocks it and now
    also enters candidate 2's; object 0 did not move and blocks nothing new."""
    from sqmanip.search.mpc import SweptArm, _unblocked

    scene = SceneState.from_objects(
        [box(0.6, 0.0, 0.05, 0.05, 0.1), box(0.7, 0.1, 0.05, 0.05, 0.1)]
    )
    moved = SceneState.from_objects(
        [box(0.6, 0.0, 0.05, 0.05, 0.1), box(0.7, 0.15, 0.05, 0.05, 0.1)]
    )
    z = SHELF.bottom_z + 0.05
    along_y = np.stack([np.full(30, 0.7), np.linspace(0.05, 0.25, 30), np.full(30, z)], -1)
    ahead = np.array([[0.7, 0.17, z]])
    far = np.array([[0.55, -0.25, z]])
    arm = SweptArm.pack(np.array([0, 1, 2]), [along_y, far, ahead])
    ok = torch.tensor([True, True, True, False])
    blockers = {0: frozenset({1}), 1: frozenset(), 2: frozenset()}
    _, _, extra = _unblocked((5, ok), blockers, scene, arm, moved)
    assert extra.tolist() == [1, 0, 1, 0]
    gone = SceneState.from_objects(
        [box(0.6, 0.0, 0.05, 0.05, 0.1), box(0.7, -0.25, 0.05, 0.05, 0.1)]
    )
    _, _, extra = _unblocked((5, ok), blockers, scene, arm, gone)
    assert extra.tolist() == [0, 0, 0, 0]


def test_an_object_the_robots_plan_passed_is_no_new_blocker_where_it_stays_in_the_sweep():
    """The swept points are tested against the grown, recognized shapes, so an object can
    enter them where the robot's own plan passed it (it named no blocker). Moved 5 cm and still
    in those points, it is no new obstacle of that grasp (before, every such push raised ``J``
    and none looked better than another, seed 8701); moved into the points of another grasp it
    is."""
    from sqmanip.search.mpc import SweptArm, _unblocked

    scene = SceneState.from_objects([box(0.7, 0.1, 0.05, 0.05, 0.1)])
    moved = SceneState.from_objects([box(0.7, 0.15, 0.05, 0.05, 0.1)])
    z = SHELF.bottom_z + 0.05
    both = np.array([[0.7, 0.13, z]])  # inside the box before and after
    ahead = np.array([[0.7, 0.18, z]])  # inside it after only
    arm = SweptArm.pack(np.array([0, 1]), [both, ahead])
    ok = torch.tensor([True, True])
    _, _, extra = _unblocked((3, ok), {0: frozenset(), 1: frozenset()}, scene, arm, moved)
    assert extra.tolist() == [0, 1]
    _, _, extra = _unblocked((3, ok), {0: frozenset({0}), 1: frozenset()}, scene, arm, moved)
    assert extra.tolist() == [1, 1]  # named by the plan: still in its way


def test_a_blocker_beside_the_seen_target_is_pushed_even_where_the_pusher_sweeps_it():
    """The robot names a wide box beside the seen target as what blocks its every grasp. No
    push of it keeps the hand off the target's disc and it is too wide to pick, so every
    sequence that keeps off the target leaves the target ungraspable: the planner then also
    weighs the pushes beside the target and pushes the box away (the only move that helps),
    instead of shuffling the other box."""
    torch.set_num_threads(1)
    cfg = SearchConfig(resolution=0.04, n_sequences=16, horizon=1)
    planner = SearchPlanner(KinematicPushDynamics(), None, cfg)
    objs = [box(0.76, 0.09, 0.09, 0.09, 0.15), box(0.60, -0.20, 0.05, 0.05, 0.10)]
    pose = np.eye(4)
    pose[:3, 3] = (0.78, 0.0, SHELF.bottom_z + TARGET.size[2])

    d = planner.decide(objs, TARGET, SHELF, SHELF.camera(), True, target_pose=pose, rng=0,
                       grasp_check=BlockedBy(0))  # fmt: skip
    assert d.kind == "push" and d.params["object"] == 0 and d.params["direction"] == 1
    assert d.params["target_risk"] > 0  # its hand sweeps the target's disc


def test_a_seen_target_is_never_in_the_way_of_a_pushed_object():
    """The wide blocker, now on the target's right, and its push away from the target refused
    (``reject``, as after the robot refused it): the only push of it left would slide it into
    the seen target and shove the target along, which the push model (the pushed object only)
    cannot predict. The planner pushes the other box instead of the blocker into the target."""
    torch.set_num_threads(1)
    cfg = SearchConfig(resolution=0.04, n_sequences=16, horizon=1)
    planner = SearchPlanner(KinematicPushDynamics(), None, cfg)
    objs = [box(0.76, -0.09, 0.09, 0.09, 0.15), box(0.60, 0.20, 0.05, 0.05, 0.10)]
    pose = np.eye(4)
    pose[:3, 3] = (0.78, 0.0, SHELF.bottom_z + TARGET.size[2])

    def refused(a):
        return getattr(a, "obj", -1) == 0 and getattr(a, "direction", 0) == -1

    for seed in range(4):
        d = planner.decide(objs, TARGET, SHELF, SHELF.camera(), True, target_pose=pose,
                           rng=seed, grasp_check=BlockedBy(0), reject=refused)  # fmt: skip
        assert d.kind == "push" and d.params["object"] == 1, (seed, d.kind, d.params)
        # pushing the bystander leaves the blocker where it stands: no gain is claimed (the
        # cost once started from J with the grasps executable now, none, and read -5 here)
        assert d.objective == 0.0, (seed, d.objective)


def test_a_push_forgets_only_where_it_may_have_shoved_the_target(models):
    """After a push the runner forgets what it saw empty where the pushed object slid, but
    only when the slide crossed a pose where the target may have stood (f = 1): a slide over
    space seen empty met no target."""
    from types import SimpleNamespace

    from sqmanip.search.episode import _shoved_to

    grid, em, _ = models
    objs = [box(0.62, -0.10, 0.05, 0.05, 0.12)]
    push = {"object": 0, "displacement": [0.0, 0.16, 0.0]}
    on_path, ahead = idx_near(grid, 0.62, -0.02), idx_near(grid, 0.62, 0.06)
    away, behind = idx_near(grid, 0.62, 0.18), idx_near(grid, 0.78, -0.02)
    f = np.zeros(len(grid))
    f[[away, behind]] = 1.0  # the target may stand off the slide only
    d = SimpleNamespace(params=push, f_map=f)
    assert not _shoved_to(em, objs, d, 0.01).any()
    f[on_path] = 1.0  # ... and on it: the slide may have carried it to its end
    forgotten = _shoved_to(em, objs, SimpleNamespace(params=push, f_map=f), 0.01)
    assert forgotten[[on_path, ahead]].all()
    assert not forgotten[[away, behind]].any()


def test_a_target_seen_then_hidden_again_is_looked_for_only_where_it_stood(models):
    """``TargetMemory``: what images showed empty stays out of the prior; once the target was
    seen, a moved object that hides it again leaves the search only the poses within 3 cm of
    where it stood (the target stands still), until a push may have shoved it elsewhere."""
    from sqmanip.search.episode import TargetMemory

    grid, _, _ = models
    memory = TargetMemory(grid, 0.03)
    assert memory.prior() is None
    empty = torch.zeros(len(grid), dtype=torch.bool)
    empty[idx_near(grid, 0.62, -0.10)] = True
    memory.observe(empty)
    assert memory.prior().sum() == len(grid) - 1
    pose = np.eye(4)
    pose[:3, 3] = (0.713, 0.118, SHELF.bottom_z + TARGET.size[2])
    memory.observe(torch.zeros(len(grid), dtype=torch.bool), pose)
    left = memory.prior()
    near = (grid.xy - torch.tensor([0.713, 0.118], dtype=grid.xy.dtype)).norm(dim=-1) <= 0.03
    assert left[grid.nearest(pose)] and torch.equal(left, near)
    assert 1 < int(left.sum()) < 10
    shoved = torch.zeros(len(grid), dtype=torch.bool)
    shoved[idx_near(grid, 0.62, -0.10)] = True
    memory.forget(shoved)
    assert torch.equal(memory.prior(), near | shoved)


def test_a_seen_targets_keep_out_disc_stands_where_the_target_stands(models):
    """Once seen, the target is kept clear of at its observed pose, not at its nearest grid
    pose (up to half a cell's diagonal off, more than the keep-out margin)."""
    grid, _, _ = models
    planner = SearchPlanner(KinematicPushDynamics(), None, CFG)
    pose = np.eye(4)
    pose[:3, 3] = (0.713, 0.118, SHELF.bottom_z + TARGET.size[2])
    f = torch.zeros(len(grid))
    f[grid.nearest(pose)] = 1.0
    disc = planner._keep_out(grid.xy, f, TARGET, pose)
    r = TARGET.horizontal_radius + CFG.keep_out_margin
    assert torch.allclose(disc, torch.tensor([[0.713, 0.118, r]], dtype=disc.dtype))
    assert planner._keep_out(grid.xy, f, TARGET).shape == (1, 3)  # hidden: the grid pose


def test_a_fallback_push_lets_the_hand_pass_where_the_target_may_stand_before_the_slide():
    """No push of the two boxes keeps both the hand and the pushed box out of where the
    target may stand. Pushes whose box stops short of those poses (only the hand passes them)
    come first: the chosen one is among them; a box slid through a hidden target shoves it."""
    torch.set_num_threads(1)
    objs = [box(0.608, -0.155, 0.057, 0.071, 0.2), box(0.713, 0.202, 0.062, 0.088, 0.15)]
    cfg = SearchConfig(
        resolution=0.04,
        n_sequences=16,
        horizon=1,
        actions="push",
        object_tolerance=0.0,  # with wide discs, the slides sweep the poses behind
        keep_out_margin=0.03,
    )
    planner = SearchPlanner(KinematicPushDynamics(), None, cfg)
    d = planner.decide(objs, TARGET, SHELF, SHELF.camera(), False, rng=0)
    grid, ev, sampler = planner.models(SHELF, TARGET, SHELF.camera())
    scene = SceneState.from_objects(objs)
    keep_out = planner._keep_out(grid.xy, ev.maps(scene).f, TARGET)
    hand_only = {
        (i, p[0], dist)
        for i in range(len(scene))
        for p in sampler.push_poses(scene, i, None)
        for dist in sampler.push_distances(scene, i, p[0], keep_out)
    }
    assert hand_only and not sampler.candidates(scene, keep_out)[0]  # the hand-only stage
    slides = sampler.candidates(scene, keep_out, False, None, False)[0]
    assert sum(len(p[3]) for v in slides.values() for p in v) > len(hand_only)
    assert d.kind == "push" and d.params["target_risk"] > 0
    assert (d.params["object"], d.params["direction"], d.params["distance"]) in hand_only


def test_an_escalated_push_hand_passes_by_a_seen_target_not_through_it():
    """A seen target 10 cm in front of a box: with the hand's keep-out lifted (the escalation
    of :meth:`SearchPlanner.decide`) a push of the box whose hand comes in across the middle
    third of the target (``seen_target``, as the planner passes it) is still dropped, one whose
    hand passes within the keep-out margin beside it is kept."""
    from sqmanip.search import ActionSampler

    sampler = ActionSampler(SHELF, dataclasses.replace(CFG, upright_push=False))
    scene = SceneState.from_objects([box(0.76, 0.0, 0.06, 0.06, 0.15)])
    r = TARGET.horizontal_radius

    def pushes(y, seen):
        keep_out = torch.tensor([[0.64, y, r + 0.03]])
        disc = keep_out.clone()
        disc[:, 2] = r / 3
        return sampler.candidates(scene, keep_out, False, None, True, disc if seen else None)[0]

    assert pushes(0.0, seen=False) and not pushes(0.0, seen=True)  # through its centre
    # 10 cm to the side: the push to +y passes 2.5 cm from it (the level palm is 20 cm
    # across), inside the keep-out margin; the push to -y comes in through it
    kept = pushes(0.10, seen=True)
    assert kept and [p[0] for p in kept[0]] == [1]
    keep_out = torch.tensor([[0.64, 0.10, r + 0.03]])
    assert not sampler.candidates(scene, keep_out)[0]


def test_refused_actions_match_within_a_tolerance_and_unreachable_ones_last():
    """The same push on the next observation starts a few mm off: it is still refused. An
    unreachable push stays refused after something moved; a colliding pick and a push that
    moved nothing are forgotten then. A pick refused at its grasp bans every place spot."""
    from sqmanip.search.actions import PickAndPlace, Push
    from sqmanip.search.episode import RefusedActions

    def push(y, direction=1):
        start = np.array([0.70, y, 0.26])
        return Push("push", 0, direction, 0.1, np.eye(4), start, np.array([0, 0.1 * direction, 0]))

    def pick(x, place_y):
        grasp, place = np.eye(4), np.eye(4)
        grasp[:3, 3] = (x, 0.0, 0.26)
        place[:3, 3] = (0.6, place_y, 0.26)
        return PickAndPlace("pick_and_place", 1, grasp, place)

    refused = RefusedActions()
    assert not refused and not refused(push(-0.21))
    refused.add(push(-0.21), "refused: push unreachable: push path needs a joint flip")
    refused.add(pick(0.65, 0.2), "refused: grasp configuration collides with object 2")
    refused.add(push(0.10), "")
    assert refused(push(-0.2)) and refused(push(-0.222))
    assert not refused(push(-0.24)) and not refused(push(-0.21, -1))
    assert refused(pick(0.655, -0.1)) and not refused(pick(0.70, 0.2))
    assert refused(push(0.10))
    refused.something_moved()
    assert refused(push(-0.2)) and not refused(pick(0.65, 0.2)) and not refused(push(0.10))


def test_predicted_actions_skip_the_ones_the_robot_refused():
    """The later actions of a sampled sequence are drawn in predicted scenes; where the object
    has not moved they are the same as the refused ones, and are skipped too."""
    from sqmanip.search import ActionSampler
    from sqmanip.search.actions import Push

    planner = SearchPlanner(KinematicPushDynamics(), None, CFG)
    planner._shelf = SHELF
    sampler = ActionSampler(SHELF, CFG, target_height=0.12)
    state = SceneState.from_objects([box(0.62, 0.0, 0.04, 0.06, 0.15)])
    rng = np.random.default_rng(0)
    drawn = [planner._one_action(state, sampler, rng, None) for _ in range(40)]
    assert any(isinstance(a, Push) for a in drawn)
    drawn = [
        planner._one_action(state, sampler, rng, None, lambda a: isinstance(a, Push))
        for _ in range(40)
    ]
    assert not any(isinstance(a, Push) for a in drawn)


def test_a_decision_weighs_n_sequences_valid_first_actions_when_most_draws_are_refused():
    """5.4.4 samples the 30 sequences from valid actions: draws the robot refused before (or
    cannot execute) are replaced by new draws, not dropped, so a decision still weighs
    ``n_sequences`` of them (one draw left as few as 4) and none of the refused ones."""
    torch.set_num_threads(1)
    cfg = SearchConfig(resolution=0.04, n_sequences=12, horizon=1)
    planner = SearchPlanner(KinematicPushDynamics(), None, cfg)
    objs = [box(0.60, 0.0, 0.06, 0.14, 0.22), box(0.62, -0.2, 0.05, 0.05, 0.12)]

    def refused(a):  # everything but the pushes of object 0 to the left
        return not (a.kind == "push" and a.obj == 0 and a.direction == 1)

    for seed in range(3):
        d = planner.decide(objs, TARGET, SHELF, SHELF.camera(), False, rng=seed, reject=refused)
        assert d.reason == "best of 12 sequences", (seed, d.reason)
        assert not refused(d.action)


def test_predicted_picks_use_the_first_grasp_that_has_a_place_spot():
    """A later action of a sampled sequence picks an object the way a first action does
    (:meth:`ActionSampler.pick`): when the first collision-free grasp has no free place spot,
    the next grasp that has one is used, not no pick at all."""
    from sqmanip.search import ActionSampler

    cfg = dataclasses.replace(CFG, actions="pick_and_place")
    planner = SearchPlanner(KinematicPushDynamics(), None, cfg)
    planner._shelf = SHELF
    sampler = ActionSampler(SHELF, cfg, target_height=0.12)
    state = SceneState.from_objects([box(0.62, 0.0, 0.04, 0.06, 0.15)])
    grasps = sampler.grasps(state, 0)
    assert grasps.shape[0] >= 2
    all_spots = sampler.place_spots

    def place_spots(scene, i, grasp, keep_out):  # no free spot for the first grasp's hand
        if torch.equal(grasp, grasps[0]):
            return torch.zeros(0, 2, dtype=grasps.dtype)
        return all_spots(scene, i, grasp, keep_out)

    sampler.place_spots = place_spots
    rng = np.random.default_rng(0)
    drawn = [planner._one_action(state, sampler, rng, None) for _ in range(10)]
    assert drawn and all(a is not None for a in drawn)
    assert all(np.allclose(a.grasp_pose, grasps[1].double().numpy()) for a in drawn)


def test_a_pick_whose_first_grasp_is_too_low_uses_a_higher_one_before_no_valid_action():
    """An object's pick is its first collision-free grasp, and the floor is checked after
    that choice (:meth:`ActionSampler.pick`): a 10 cm box's first grasp is too low, so it had
    no pick. Before a decision gives up ("no valid action") it picks with the first grasp
    that clears the floor."""
    torch.set_num_threads(1)
    cfg = SearchConfig(resolution=0.04, n_sequences=6, horizon=1, actions="pick_and_place")
    planner = SearchPlanner(KinematicPushDynamics(), None, cfg)
    objs = [box(0.62, 0.0, 0.05, 0.05, 0.10)]
    _, _, sampler = planner.models(SHELF, TARGET, SHELF.camera())
    low, _ = sampler.pick(SceneState.from_objects(objs), 0, None)
    assert not planner.clears_floor(low.double().numpy(), SHELF)
    d = planner.decide(objs, TARGET, SHELF, SHELF.camera(), False, rng=0)
    assert d.kind == "pick_and_place", d.reason
    assert planner.clears_floor(d.action.grasp_pose, SHELF)
    assert planner.clears_floor(d.action.place_pose, SHELF)


def test_a_decision_loosens_the_clearances_before_it_finds_no_valid_action():
    """Two boxes 1 cm apart block each other's pusher at every start (the palm reaches 10 cm
    along the push; the upright hand is off here). Rather than end the episode with "no valid
    action", a decision tries again with :attr:`SearchConfig.last_resort_tolerances` (the
    robot still checks the action against the objects as they are); with none it gives up as
    before."""
    torch.set_num_threads(1)
    cfg = SearchConfig(
        resolution=0.04, n_sequences=6, horizon=1, actions="push", upright_push=False
    )
    objs = [box(0.60, 0.0, 0.06, 0.06, 0.15), box(0.60, -0.07, 0.06, 0.06, 0.15)]
    strict = SearchPlanner(
        KinematicPushDynamics(), None, dataclasses.replace(cfg, last_resort_tolerances=())
    )
    d = strict.decide(objs, TARGET, SHELF, SHELF.camera(), False, rng=0)
    assert d.kind == "none" and d.reason == "no valid action"
    d = SearchPlanner(KinematicPushDynamics(), None, cfg).decide(
        objs, TARGET, SHELF, SHELF.camera(), False, rng=0
    )
    assert d.kind == "push", d.reason
    assert abs(d.action.start[1] - objs[d.action.obj].pose[1, 3]) < 0.03 + 0.01 + 0.012
    for bad in ((-0.01,), (float("nan"),)):
        with pytest.raises(ValidationError, match="last_resort_tolerances"):
            SearchConfig(last_resort_tolerances=bad)
    with pytest.raises(ValidationError, match="last_resort_push_gap"):
        SearchConfig(last_resort_push_gap=-0.001)


def test_an_occluder_slides_aside_past_where_the_target_may_stand_right_behind_it():
    """f = 1 right behind an object: the target may stand there with the object's estimated
    back up to fc_shrink + object_tolerance into it. Pushing the object aside does not sweep
    such a pose (it blocked every push of the occluder, seed 5905); a pose whose target the
    back reaches farther into, and one ahead of the slide, still stop it."""
    from sqmanip.search import ActionSampler

    sampler = ActionSampler(SHELF, CFG, target_height=0.12)
    scene = SceneState.from_objects([box(0.60, 0.0, 0.06, 0.06, 0.15)])
    r = TARGET.horizontal_radius + CFG.keep_out_margin
    behind = 0.60 + 0.03 + TARGET.horizontal_radius  # a target touching the box's back
    for side in (1, -1):
        touching = torch.tensor([[behind, 0.01 * side, r]])
        assert sampler.push_distances(scene, 0, side, touching) == [0.05, 0.1, 0.15]
        deeper = torch.tensor([[behind - 0.01, 0.01 * side, r]])  # 1 cm into the box
        assert sampler.push_distances(scene, 0, side, deeper) == []
        ahead = torch.tensor([[0.60, 0.12 * side, r]])  # in the slide's way: 5 cm left
        assert sampler.push_distances(scene, 0, side, ahead) == [0.05]


def test_a_decision_that_gains_nothing_safely_weighs_the_pushes_that_may_sweep_the_target():
    """The two boxes hide the target, and every push of theirs sweeps where it may stand; a
    third box near the back wall hides nothing, so its pushes keep out and gain nothing. Such
    a decision used to push that box, step after step (scenario seeds 3925, 5923); with
    ``escalate_when_stuck`` the pushes of the occluders compete too, and one is chosen for
    what it reveals."""
    from sqmanip.search.mpc import STUCK

    torch.set_num_threads(1)
    objs = [
        box(0.608, -0.155, 0.057, 0.071, 0.2),
        box(0.713, 0.202, 0.062, 0.088, 0.15),
        box(0.80, 0.0, 0.06, 0.06, 0.15),
    ]
    cfg = SearchConfig(
        resolution=0.04,
        n_sequences=16,
        horizon=1,
        actions="push",
        object_tolerance=0.0,
        keep_out_margin=0.03,
    )
    out = {}
    for on in (False, True):
        planner = SearchPlanner(
            KinematicPushDynamics(), None, dataclasses.replace(cfg, escalate_when_stuck=on)
        )
        out[on] = planner.decide(objs, TARGET, SHELF, SHELF.camera(), False, rng=0)
    safe, escalated = out[False], out[True]
    assert safe.kind == "push" and safe.params["object"] == 2, safe.reason
    assert safe.objective == 0.0 and STUCK not in safe.reason
    assert escalated.kind == "push" and escalated.params["object"] in (0, 1), escalated.reason
    assert escalated.objective < 0 and STUCK in escalated.reason
    assert escalated.params["target_risk"] > 0
