"""Task costs (4.4.6, 4.4.7, 4.7.9, B.5.13) on hand-made states, and the batched collision test."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from planning_helpers import box
from sqmanip.errors import ValidationError
from sqmanip.geometry.superquadric import implicit_homogeneous
from sqmanip.grasping import always_reachable
from sqmanip.grasping.config import PANDA_HAND
from sqmanip.planning import (
    GraspCostSpec,
    GraspFeasibility,
    PackedScene,
    TableSpec,
    grasping_cost,
    gripper_part_values,
    interactive_moving_cost,
    moving_cost,
    objects_off_table,
    singulation_cost,
)
from sqmanip.planning.costs import GripperCloud, grasp_edges


def poses_at(*xyz) -> torch.Tensor:
    T = torch.eye(4, dtype=torch.float64).repeat(len(xyz), 1, 1)
    T[:, :3, 3] = torch.tensor(xyz, dtype=torch.float64)
    return T


def rotz(theta: float) -> torch.Tensor:
    c, s = math.cos(theta), math.sin(theta)
    return torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=torch.float64)


class TestMovingCost:
    def test_zero_at_goal_and_squared_distance_elsewhere(self):
        goals = poses_at((0.5, 0.0, 0.02), (0.4, 0.1, 0.02))
        assert moving_cost(goals, goals, beta=1.0).item() == 0.0
        moved = goals.clone()
        moved[0, 0, 3] += 0.03
        moved[1, 1, 3] -= 0.04
        assert moving_cost(moved, goals).item() == pytest.approx(0.03**2 + 0.04**2)

    def test_beta_weights_the_rotation_distance(self):
        goals = poses_at((0.5, 0.0, 0.02))
        turned = goals.clone()
        turned[0, :3, :3] = rotz(math.pi / 2)  # d = 1 - cos(90 deg) = 1
        assert moving_cost(turned, goals, beta=0.0).item() == pytest.approx(0.0)
        assert moving_cost(turned, goals, beta=0.3).item() == pytest.approx(0.3)

    def test_weights_ignore_objects_without_goal_and_batch(self):
        goals = poses_at((0.5, 0.0, 0.0), (0.4, 0.0, 0.0))
        states = torch.stack([goals, goals + 0.0])
        states[1, 1, 0, 3] += 1.0
        w = torch.tensor([1.0, 0.0], dtype=torch.float64)
        assert moving_cost(states, goals, weights=w).tolist() == [0.0, 0.0]
        assert moving_cost(states, goals).tolist() == pytest.approx([0.0, 1.0])


class TestSingulationCost:
    def test_sign_and_tau(self):
        # two objects 10 cm apart fall 10 cm short of tau = 20 cm: cost +0.10 (positive)
        close = poses_at((0.4, 0.0, 0.0), (0.5, 0.0, 0.0))
        assert singulation_cost(close, 0.20).item() == pytest.approx(0.10)
        # 30 cm apart: separated, cost 0; with tau = 0.40 they are 10 cm short again
        far = poses_at((0.3, 0.0, 0.0), (0.6, 0.0, 0.0))
        assert singulation_cost(far, 0.20).item() == 0.0
        assert singulation_cost(far, 0.40).item() == pytest.approx(0.10)

    def test_closest_pair_decides_and_separating_lowers_cost(self):
        three = poses_at((0.3, 0.0, 0.0), (0.35, 0.0, 0.0), (0.7, 0.0, 0.0))
        assert singulation_cost(three).item() == pytest.approx(0.15)
        apart = poses_at((0.3, 0.0, 0.0), (0.45, 0.0, 0.0), (0.7, 0.0, 0.0))
        assert singulation_cost(apart).item() < singulation_cost(three).item()

    def test_single_object_is_free(self):
        assert singulation_cost(poses_at((0.4, 0.0, 0.0))).item() == 0.0


def test_interactive_moving_cost_is_squared_target_distance():
    s = poses_at((0.4, 0.0, 0.02), (0.2, 0.1, 0.02))
    assert interactive_moving_cost(s, 1, np.array([0.3, 0.1, 0.02])).item() == pytest.approx(0.01)
    assert interactive_moving_cost(s, 0, np.array([0.4, 0.0, 0.02])).item() == 0.0


def test_grasping_cost_is_one_minus_any():
    f = torch.tensor([[False, True, False], [False, False, False]])
    assert grasping_cost(f).tolist() == [0.0, 1.0]
    assert grasping_cost(torch.zeros(4, 0, dtype=torch.bool)).tolist() == [1.0] * 4


def test_objects_off_table():
    table = TableSpec(center=(0.45, 0.0), size=(0.8, 1.0))
    s = torch.stack([poses_at((0.45, 0.49, 0.0)), poses_at((0.45, 0.51, 0.0))])
    assert objects_off_table(s, table).tolist() == [False, True]
    assert objects_off_table(s, table, margin=0.02).tolist() == [True, True]


# --- grasp feasibility (B.5.13) ------------------------------------------------------------------


def checker(**kw) -> GraspFeasibility:
    return GraspFeasibility(
        always_reachable, spec=GraspCostSpec(**kw), gripper=PANDA_HAND, table=TableSpec()
    )


def grasp_cost_now(objects, target=0, **kw) -> float:
    scene = PackedScene.from_objects(objects)
    feas = checker(**kw).feasible(scene, scene.poses[None], target)
    return grasping_cost(feas).item()


def test_free_box_is_graspable():
    assert grasp_cost_now([([box(0.45, 0.0)], 1)]) == 0.0


def test_boxed_in_target_is_not_graspable():
    # 5 cm target, four taller 6 cm neighbours 1 cm away on every side
    objs = [([box(0.45, 0.0, (0.05, 0.05, 0.10))], 0)]
    for k, (dx, dy) in enumerate([(0.065, 0), (-0.065, 0), (0, 0.065), (0, -0.065)]):
        objs.append(([box(0.45 + dx, dy, (0.06, 0.06, 0.14))], k + 1))
    assert grasp_cost_now(objs) == 1.0
    assert grasp_cost_now(objs[:1]) == 0.0  # the same target alone is


def test_target_wider_than_the_opening_is_not_graspable():
    assert grasp_cost_now([([box(0.45, 0.0, (0.12, 0.12, 0.12))], 0)]) == 1.0


def test_flat_box_is_graspable_only_where_it_overhangs_the_table_edge():
    flat = (0.16, 0.16, 0.03)
    assert grasp_cost_now([([box(0.45, 0.0, flat)], 0)]) == 1.0
    assert grasp_cost_now([([box(0.45, 0.38, flat)], 0)]) == 0.0  # 6 cm past y = 0.4
    assert grasp_cost_now([([box(0.45, 0.38, flat)], 0)], edge_grasps=False) == 1.0


def test_no_grasp_past_the_edge_at_the_robot_or_beyond_its_reach():
    """The same flat box overhanging the near edge (x = 0.15, beside the pedestal) by 10 cm is
    not graspable: the hand fits there, but the arm would reach it through the table. It is
    graspable for a robot standing elsewhere, for which that edge is a side edge."""
    near = [([box(0.13, 0.25, (0.16, 0.16, 0.03))], 0)]
    assert grasp_edges(TableSpec()).tolist() == [False, False, True, True]
    assert grasp_cost_now(near) == grasp_cost_now(near, mount=None) == 1.0
    scene = PackedScene.from_objects(near)
    elsewhere = GraspFeasibility(
        always_reachable, spec=GraspCostSpec(mount=None), gripper=PANDA_HAND, table=TableSpec(),
        base=(0.55, 0.05, 0.10),
    )  # fmt: skip
    assert grasp_edges(TableSpec(), (0.55, 0.05, 0.10)).tolist() == [True, True, True, False]
    assert bool(elsewhere.feasible(scene, scene.poses[None], 0).any())


def test_feasibility_moves_with_predicted_states():
    # the flat box is infeasible now, feasible in a predicted state pushed over the edge
    scene = PackedScene.from_objects([([box(0.45, 0.30, (0.16, 0.16, 0.03))], 0)])
    states = scene.poses[None].repeat(2, 1, 1, 1)
    states[1, 0, 1, 3] += 0.08
    assert grasping_cost(checker().feasible(scene, states, 0)).tolist() == [1.0, 0.0]


def test_any_feasible_equals_feasible_any_with_fewer_ik_calls():
    """The MPC's early-stopping check agrees with the full matrix and asks the IK less."""
    rng = np.random.default_rng(0)
    target = box(0.45, 0.0, (0.05, 0.05, 0.10))
    scene = PackedScene.from_objects([([target], 0), ([box(0.52, 0.0, (0.06, 0.06, 0.14))], 1)])
    states = scene.poses[None].repeat(12, 1, 1, 1)
    states[:, 1, :2, 3] += torch.as_tensor(rng.uniform(-0.04, 0.04, (12, 2)))  # the neighbour
    calls = []

    def reach_left_half(poses):  # a reachability that rejects some grasps, counting calls
        calls.append(len(poses))
        return poses[:, 1, 3] < 0.005

    feas = GraspFeasibility(
        reach_left_half, spec=GraspCostSpec(), gripper=PANDA_HAND, table=TableSpec()
    )
    full = feas.feasible(scene, states, 0)
    n_full = sum(calls)
    calls.clear()
    some = feas.any_feasible(scene, states, 0)
    assert torch.equal(some, full.any(-1))
    assert some.any() and (~some).any()
    assert sum(calls) < n_full


def test_gripper_part_values_equals_dense_evaluation():
    gen = torch.Generator().manual_seed(0)
    scene = PackedScene.from_objects(
        [([box(0.45, 0.0)], 0), ([box(0.5, 0.06, (0.04, 0.08, 0.1), yaw=0.4)], 1)]
    )
    cloud = GripperCloud.from_spec(PANDA_HAND, 256)
    S, Q = 3, 20
    frames = torch.eye(4).repeat(S, Q, 1, 1)
    frames[..., :3, 3] = torch.tensor([0.47, 0.03, 0.05]) + 0.08 * (
        torch.rand(S, Q, 3, generator=gen) - 0.5
    )
    ang = torch.rand(S, Q, generator=gen) * 6.28
    frames[..., 0, 0], frames[..., 0, 1] = torch.cos(ang), -torch.sin(ang)
    frames[..., 1, 0], frames[..., 1, 1] = torch.sin(ang), torch.cos(ang)
    part_poses = scene.part_poses(scene.poses)[None]
    got = gripper_part_values(frames, cloud, part_poses, scene)
    world = frames[..., None, :3, :3] @ cloud.points.T + frames[..., None, :3, 3:]  # (S,Q,1,3,P)
    world = world.squeeze(2).transpose(-1, -2)  # (S, Q, P, 3)
    for m in range(2):
        T = part_poses[0, m]
        local = (world - T[:3, 3]) @ T[:3, :3]
        dense = implicit_homogeneous(local, scene.part_params[m], 0).amin(-1)
        collide_dense = dense < 1.0
        assert torch.equal(got[..., m] < 1.0, collide_dense)
        assert collide_dense.any() and (~collide_dense).any()


def test_pre_grasp_hand_must_clear_the_robot_mount():
    # a top-down grasp whose hand and wrist (links 6-7, up to z 0.60) are clear at the grasp
    # pose but rise into an overhead slab (z 0.65-0.70) when backed off 10 cm to the pre-grasp
    down = np.eye(4)
    down[:3, :3] = np.diag([1.0, -1.0, -1.0])  # tool z (approach) points down
    down[:3, 3] = (0.45, 0.0, 0.30)
    frames = torch.as_tensor(down)[None]
    slab = TableSpec(center=(0.45, 0.0), size=(0.3, 0.3), height=0.70, thickness=0.05)
    assert checker(mount=slab).static_collisions(frames).tolist() == [True]
    assert checker(mount=slab, approach_distance=0.0).static_collisions(frames).tolist() == [False]
    assert checker(mount=None).static_collisions(frames).tolist() == [False]


def test_pre_grasp_distance_is_validated():
    with pytest.raises(ValidationError, match="approach_distance"):
        GraspCostSpec(approach_distance=-0.1)


def test_grasps_are_tried_nearest_the_object_centre_first():
    # edge grasps spread along a long box overhanging the table: the one at the recognized tip is
    # the one a few cm of size error spoils (it closes on air), so it is tried last
    from sqmanip.grasping.types import Candidates
    from sqmanip.planning.episode import centred_first

    centre = np.array([0.45, 0.30, 0.025])
    mid_y = np.array([0.496, 0.442, 0.30, 0.47])  # contact midpoints along the box's length
    contacts = np.zeros((4, 2, 3))
    contacts[:, :, :] = centre
    contacts[:, :, 1] = mid_y[:, None]
    contacts[:, 0, 2], contacts[:, 1, 2] = 0.0, 0.05  # fingers on the bottom and top faces
    cands = Candidates(
        torch.eye(4, dtype=torch.float64).expand(4, 4, 4),
        torch.full((4,), 0.05, dtype=torch.float64),
        torch.as_tensor(contacts),
    )
    feasible = np.array([0, 1, 3])  # the centre one collides with the table
    assert centred_first(cands, feasible, centre).tolist() == [1, 3, 0]
    assert centred_first(cands, np.zeros(0, dtype=np.int64), centre).tolist() == []


def test_the_simulator_planner_grasps_a_can_recognized_slightly_too_wide():
    """PyBullet renders the 6.7 cm tomato-soup can 7.0 cm wide and recognition adds a few mm:
    at B.5's 7 cm such a can has no candidate; ``sim_planner`` keeps grasps up to 7.5 cm."""
    from planning_helpers import PusherDynamics
    from sqmanip.planning.config import MPCConfig
    from sqmanip.planning.costs import GraspFeasibility
    from sqmanip.planning.episode import SIM_GRASP_WIDTH, sim_planner

    can = box(0.45, 0.0, size=(0.072, 0.072, 0.101), e=0.3)
    cfg = MPCConfig()
    thesis = GraspFeasibility(
        always_reachable, spec=cfg.grasp, gripper=cfg.gripper, table=cfg.table
    )
    assert len(thesis.candidates([can])) == 0
    cands = sim_planner(PusherDynamics()).grasp_checker.candidates([can])
    assert len(cands) > 0
    assert float(cands.widths.max()) <= SIM_GRASP_WIDTH


def test_edge_grasps_come_turned_about_the_vertical_through_their_tcp():
    from sqmanip.grasping.types import RuleOptions
    from sqmanip.planning.costs import edge_grasp_candidates

    plate = [box(0.45, 0.30, (0.13, 0.34, 0.05), yaw=0.3)]
    rule = RuleOptions(max_width=0.075)
    flat = edge_grasp_candidates(plate, rule)
    turned = edge_grasp_candidates(plate, rule, turns_deg=(0.0, -20.0, 20.0))
    assert len(turned) == 3 * len(flat) > 0
    P = turned.poses.reshape(len(flat), 3, 4, 4)
    torch.testing.assert_close(P[:, 0], flat.poses)
    torch.testing.assert_close(P[:, :, :3, 3], flat.poses[:, None, :3, 3].expand(-1, 3, -1))
    torch.testing.assert_close(turned.widths.reshape(-1, 3)[:, 1], flat.widths)
    for k, angle in ((1, -20.0), (2, 20.0)):
        torch.testing.assert_close(
            P[:, k, :3, :3], rotz(math.radians(angle)) @ flat.poses[:, :3, :3]
        )
    # fingers still close across the vertical; the approach stays horizontal
    assert torch.allclose(P[..., 2, 1].abs(), torch.ones((), dtype=P.dtype), atol=1e-9)
    assert torch.allclose(P[..., 2, 2], torch.zeros((), dtype=P.dtype), atol=1e-9)
    with pytest.raises(ValidationError, match="edge_turns_deg"):
        GraspCostSpec(edge_turns_deg=())
    with pytest.raises(ValidationError, match="max_edge_candidates"):
        GraspCostSpec(max_edge_candidates=0)


def test_turned_edge_grasps_reach_a_large_box_overhanging_a_side_edge_at_an_angle():
    """The 34 x 13 cm box overhangs the simulator table's -y edge by 13 cm at a yaw of -15 deg.
    Held along its own axes, every hand the Panda IK can reach has its wrist over the table;
    turned 20 degrees, the hand reaches in from the robot's side with the wrist off it."""
    from sqmanip.grasping.types import RuleOptions
    from sqmanip.planning.episode import SIM_GRASP_WIDTH
    from sqmanip.planning.scenarios import sim_reachability, sim_table

    scene = PackedScene.from_objects(
        [([box(0.46, -0.36, (0.13, 0.34, 0.05), math.radians(-15))], 0)]
    )

    def n_feasible(**kw) -> int:
        spec = GraspCostSpec(rule=RuleOptions(max_width=SIM_GRASP_WIDTH), **kw)
        feas = GraspFeasibility(
            sim_reachability(), spec=spec, gripper=PANDA_HAND, table=sim_table()
        )
        return int(feas.feasible(scene, scene.poses[None], 0).sum())

    assert n_feasible(edge_turns_deg=(0.0,)) == 0
    assert n_feasible() > 0
