"""The sampling-based MPC (B.4): batched rollouts, sampler, constraints and one-step behaviour.

The behaviour tests use :class:`PusherDynamics`, an analytic stand-in with SQPD-Net's signature
(no trained SQPD-Net checkpoint ships yet); the rollout equivalence uses the real SQPD-Net with
random weights.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from planning_helpers import PredictOnly, PusherDynamics, box
from sqmanip.dynamics import SQPDNet, cpu_config
from sqmanip.geometry import Superquadric
from sqmanip.geometry.transforms import decompose_pose, se2_matrix
from sqmanip.grasping import always_reachable
from sqmanip.planning import (
    CandidateSampler,
    GraspingTask,
    InteractiveMovingTask,
    MovingTask,
    MPCConfig,
    PackedScene,
    PushMPC,
    SingulationTask,
    draw_uniform_per_object,
    map_actions,
    predict_scenes,
    rollout,
)


@pytest.fixture(autouse=True)
def _one_torch_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


WIDE = CandidateSampler(np.array([[-5.0, -5.0, 0.0], [5.0, 5.0, 0.192]]))


def sample(poses, params, n, rng):
    """``n`` 4.5 pushes (with replacement) and their objects on a scene."""
    a, o = WIDE(np.asarray(poses), np.asarray(params), np.ones(len(poses), bool))
    j = draw_uniform_per_object(o, n, rng, replace=True)
    return a[j], o[j]


def four_boxes():
    return [
        ([box(0.45, 0.0)], 0),
        ([box(0.52, 0.02, (0.04, 0.08, 0.10), yaw=0.3)], 1),
        ([box(0.40, 0.09, (0.06, 0.06, 0.04))], 2),
        ([box(0.60, -0.10, (0.05, 0.05, 0.12), e=0.9)], 3),
    ]


def test_batched_rollout_equals_sequence_by_sequence():
    torch.manual_seed(0)
    net = SQPDNet(cpu_config()).double()
    scene = PackedScene.from_objects(four_boxes())
    rng = np.random.default_rng(0)
    S, H = 12, 3
    a, _ = sample(scene.poses, scene.params, S * H, rng)
    actions = torch.as_tensor(a).reshape(S, H, 6)
    active = torch.ones(S, H, dtype=torch.bool)
    active[3, 1] = False  # a skipped push leaves the state as it is
    batched = rollout(net, scene.poses, scene.params, scene.kinds, actions, active)
    for s in range(S):
        state = scene.poses
        for h in range(H):
            if active[s, h]:
                state = net.predict(state, scene.params, actions[s, h : h + 1], scene.kinds)[0]
            torch.testing.assert_close(batched[s, h + 1], state.double(), atol=1e-9, rtol=0)
    assert not torch.allclose(batched[:, 1], batched[:, 0])  # the pushes did move something


def test_predict_scenes_fallback_matches_predict_batch():
    scene = PackedScene.from_objects(four_boxes())
    rng = np.random.default_rng(1)
    a, _ = sample(scene.poses, scene.params, 8, rng)
    states = scene.poses[None].repeat(8, 1, 1, 1)
    states[:, :, 0, 3] += torch.linspace(0, 0.05, 8)[:, None]
    args = (states, scene.params, scene.kinds, torch.as_tensor(a))
    torch.testing.assert_close(
        predict_scenes(PredictOnly(), *args), predict_scenes(PusherDynamics(), *args)
    )


def test_sampler_is_equivariant_so_mapped_actions_match_resampling():
    scene = PackedScene.from_objects(four_boxes())
    C = se2_matrix(torch.tensor(0.7), torch.tensor(0.05), torch.tensor(-0.03)).double()
    moved = C @ scene.poses
    a0, o0 = sample(scene.poses, scene.params, 50, np.random.default_rng(3))
    a1, o1 = sample(moved, scene.params, 50, np.random.default_rng(3))
    assert np.array_equal(o0, o1)
    C0, _ = decompose_pose(scene.poses)
    C1, _ = decompose_pose(moved)
    mapped = map_actions(torch.as_tensor(a0), torch.as_tensor(o0), C0, C1.expand(50, 4, 4, 4))
    np.testing.assert_allclose(mapped.numpy(), a1, atol=1e-9)


def test_moving_lone_box_pushes_towards_goal():
    b = box(0.45, 0.0)
    goal = b.pose.copy()
    goal[0, 3] += 0.10
    mpc = PushMPC(PusherDynamics())
    res = mpc.plan([([b], 7)], MovingTask({7: goal}), np.random.default_rng(0))
    assert res.action is not None and res.action[3] > 0.05  # push along +x
    before = np.linalg.norm(b.pose[:3, 3] - goal[:3, 3])
    after = np.linalg.norm(res.predicted_next[0, :3, 3] - goal[:3, 3])
    assert after < 0.3 * before
    assert res.current_cost == pytest.approx(before**2)
    assert res.cost == pytest.approx(after**2)
    # a lone 5 cm box has 8 directions x 1 height x 4 starts = 32 candidates (4.5); the
    # touching ones (start offset 0) fail the start-pose check
    assert 0 < res.n_candidates == res.n_sampled - res.n_rejected_start <= 32
    assert res.pushed_id == 7
    assert set(res.timings_ms) >= {"sampling", "rollout", "cost", "grasp", "total"}


def test_grasping_large_pushes_towards_the_table_edge():
    # 16 cm flat box 10 cm from the y = +0.4 table edge: no grasp until it overhangs
    big = box(0.45, 0.30, (0.16, 0.16, 0.03))
    mpc = PushMPC(PusherDynamics(), reachability=always_reachable)
    res = mpc.plan([([big], 3)], GraspingTask(3), np.random.default_rng(0))
    assert res.current_cost == 1.0
    assert res.action is not None and res.cost == 0.0 and res.solved
    assert res.action[4] > 0.0  # the first push has a component towards the edge
    # and no sequence was allowed to carry the centre off the table
    assert res.predicted_next[0, 1, 3] <= 0.4
    assert res.n_rejected_workspace > 0


def test_grasping_impossible_target_reports_no_solution():
    cube = box(0.45, 0.0, (0.12, 0.12, 0.12))  # wider than the opening in every direction
    mpc = PushMPC(PusherDynamics(), reachability=always_reachable)
    res = mpc.plan([([cube], 1)], GraspingTask(1), np.random.default_rng(0))
    assert res.cost == 1.0 and not res.solved


def test_interactive_moving_never_pushes_the_target():
    objs = [([box(0.45, 0.0)], 1), ([box(0.38, 0.0)], 2), ([box(0.45, 0.12)], 3)]
    task = InteractiveMovingTask(1, np.array([0.55, 0.0, 0.025]))
    mpc = PushMPC(PusherDynamics(), config=MPCConfig(n_sequences=50))
    for seed in range(3):
        res = mpc.plan(objs, task, np.random.default_rng(seed))
        assert res.pushed_id in (2, 3)


def test_start_pose_collisions_are_rejected():
    # a tall neighbour 2 cm beside a short box: the sampler's tip is clear, but the palm of
    # the pusher (20 cm across) hits the neighbour for pushes along the gap
    objs = [([box(0.45, 0.0)], 0), ([box(0.45, 0.075, (0.06, 0.06, 0.14))], 1)]
    mpc = PushMPC(PusherDynamics())
    res = mpc.plan(objs, SingulationTask(), np.random.default_rng(0))
    assert res.n_rejected_start > 0
    assert res.action is not None
    scene = PackedScene.from_objects(objs)
    a = torch.as_tensor(res.sequence[:1])[None]
    assert bool(mpc._start_free(scene, a, scene.poses[None])[0, 0])
    # with the check off nothing is rejected
    loose = PushMPC(PusherDynamics(), config=MPCConfig(reject_start_collisions=False))
    assert loose.plan(objs, SingulationTask(), np.random.default_rng(0)).n_rejected_start == 0


def test_singulation_step_separates_the_closest_pair():
    objs = [([box(0.45, 0.0)], 0), ([box(0.45, 0.08)], 1)]
    mpc = PushMPC(PusherDynamics())
    res = mpc.plan(objs, SingulationTask(), np.random.default_rng(0))
    assert res.current_cost == pytest.approx(0.12)
    assert res.cost < res.current_cost
    d = np.linalg.norm(res.predicted_next[0, :3, 3] - res.predicted_next[1, :3, 3])
    assert d > 0.08


def test_plan_is_deterministic_given_the_seed():
    mpc = PushMPC(PusherDynamics(), reachability=always_reachable)
    objs = four_boxes()
    r1 = mpc.plan(objs, GraspingTask(0), np.random.default_rng(5))
    r2 = mpc.plan(objs, GraspingTask(0), np.random.default_rng(5))
    np.testing.assert_array_equal(r1.sequence, r2.sequence)


def _final_states(scene, moves):
    """``(S, N, 4, 4)``: the scene's poses with object ``i`` moved by ``moves[s][i]`` (x, y)."""
    out = scene.poses.repeat(len(moves), 1, 1, 1).clone()
    out[:, :, :2, 3] += torch.as_tensor(moves, dtype=out.dtype)
    return out


def test_without_any_grasp_a_large_target_ends_nearest_the_table_edge():
    from sqmanip.planning.mpc import _TaskContext

    mpc = PushMPC(PusherDynamics(), reachability=always_reachable)
    scene = PackedScene.from_objects([([box(0.55, 0.0, (0.13, 0.34, 0.05))], 0)])
    final = _final_states(scene, [[[0.0, 0.1]], [[0.0, -0.42]], [[0.1, 0.2]]])
    ctx = _TaskContext.build(GraspingTask(0), scene)
    chosen = mpc._closest_to_graspable(scene, ctx, final, torch.arange(3))
    assert chosen.tolist() == [1]  # centre 2 cm past the y = -0.4 edge


def test_a_large_box_lying_on_its_side_is_pushed_towards_a_side_edge_not_the_far_one():
    """The box's height is its superquadric a1 (x axis up): its footprint, not (a1, a2), decides
    that it is too wide to grasp. The far edge lies beyond the arm's reach and the near one at
    the pedestal, so a side edge 15 cm away beats the far edge 2 cm away."""
    from sqmanip.planning.costs import grasp_edges
    from sqmanip.planning.mpc import _TaskContext

    assert grasp_edges(MPCConfig().table).tolist() == [False, False, True, True]
    T = np.eye(4)
    T[:3, :3] = [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]  # x up, y along x, z along y
    T[:3, 3] = (0.55, 0.0, 0.025)
    lying = Superquadric(size=(0.025, 0.065, 0.17), shape=(0.2, 0.2), pose=T)
    mpc = PushMPC(PusherDynamics(), reachability=always_reachable)
    scene = PackedScene.from_objects([([lying], 0)])
    final = _final_states(scene, [[[0.38, 0.0]], [[0.0, 0.25]], [[0.0, 0.1]]])
    ctx = _TaskContext.build(GraspingTask(0), scene)
    chosen = mpc._closest_to_graspable(scene, ctx, final, torch.arange(3))
    assert chosen.tolist() == [1]


def test_without_any_grasp_a_small_target_ends_farthest_from_its_neighbours():
    from sqmanip.planning.mpc import _TaskContext

    mpc = PushMPC(PusherDynamics(), reachability=always_reachable)
    objs = [([box(0.45, 0.0)], 0), ([box(0.45, 0.07)], 1), ([box(0.52, 0.0)], 2)]
    scene = PackedScene.from_objects(objs)
    moves = [
        [[0, 0], [0, 0.02], [0, 0]],
        [[0, 0], [0, 0.10], [0.10, 0]],
        [[0, 0], [0, 0.1], [0, 0]],
    ]
    ctx = _TaskContext.build(GraspingTask(0), scene)
    chosen = mpc._closest_to_graspable(scene, ctx, _final_states(scene, moves), torch.arange(3))
    assert chosen.tolist() == [1]  # both neighbours moved away


def test_single_pushes_when_no_full_sequence_stays_on_the_table():
    # The only push moves the box 7.5 cm towards the y = +0.4 edge: three of them carry it off
    # the table, one does not. Instead of "no admissible push", the MPC plans single pushes.
    b = box(0.45, 0.20, (0.03, 0.03, 0.05))
    y_back = 0.20 - 0.04

    def only_outward(poses, params, allowed):
        return np.array([[0.45, y_back, 0.03, 0.0, 0.1, 0.0]]), np.array([0])

    mpc = PushMPC(PusherDynamics(), config=MPCConfig(horizon=3), sampler=only_outward)
    goal = b.pose.copy()
    goal[1, 3] = 0.30
    res = mpc.plan([([b], 7)], MovingTask({7: goal}), np.random.default_rng(0))
    assert res.action is not None
    assert res.sequence.shape == (1, 6)  # configured horizon 3, planned with horizon 1
    assert res.predicted_next[0, 1, 3] == pytest.approx(0.275)


def test_horizon_one_scores_every_free_push_not_only_k():
    """For the tasks named in ``score_every_single_push`` one-push steps score all admissible
    candidates (cheap, and K draws miss the best one); the others keep the K draws of B.4."""
    objs = four_boxes()
    goal = objs[0][0][0].pose.copy()
    goal[0, 3] -= 0.10
    task = MovingTask({0: goal})
    every = PushMPC(PusherDynamics(), config=MPCConfig(n_sequences=5)).plan(objs, task, 0)
    free = every.n_sampled - every.n_rejected_start
    assert every.n_candidates == free > 5
    off = MPCConfig(n_sequences=5, score_every_single_push=())
    five = PushMPC(PusherDynamics(), config=off).plan(objs, task, 0)
    assert five.n_candidates == 5
    assert every.cost <= five.cost  # the best of all is at least as good as the best of five
    sing = PushMPC(PusherDynamics(), config=MPCConfig(n_sequences=5)).plan(
        objs, SingulationTask(), 0
    )
    assert sing.n_candidates == 5
