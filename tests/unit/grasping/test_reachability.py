"""PandaIKReachability: the simulator's IK as the planner's kinematic feasibility."""

from __future__ import annotations

import numpy as np
import pytest
from sqmanip.errors import PreconditionError, ValidationError
from sqmanip.grasping import Environment, GraspPlanner, PlanOptions
from sqmanip.grasping.config import PANDA_HAND
from sqmanip.grasping.reachability import (
    HALF_TURN_Z,
    PandaIKReachability,
    default_base_pose,
    sim_tool_pose,
)
from sqmanip.sim import ObjectSpec, SceneSpec, Simulator
from sqmanip.sim.actions import offset_along_z
from sqmanip.sim.config import HOME_TABLETOP
from sqmanip.sim.kinematics import TCP_OFFSET, PandaKinematics


def down(x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    """Gripper pose pointing straight down (z = -world z) at ``(x, y, z)``."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])
    T[:3, 3] = (x, y, z)
    return T


@pytest.fixture(scope="module")
def reach() -> PandaIKReachability:
    return PandaIKReachability()


def test_middle_of_workspace_reachable_far_pose_not(reach):
    poses = np.stack([down(0.45, 0.0, 0.03), down(1.5, 0.0, 0.03), down(0.0, 1.5, 0.03)])
    assert reach(poses).tolist() == [True, False, False]


def test_pre_grasp_pose_is_checked():
    """A grasp whose own pose is reachable fails when its pre-grasp (``approach_distance`` back
    along -z, i.e. straight up here) leaves the arm's reach."""
    T = down(0.72, 0.0, 0.05)[None]
    assert PandaIKReachability(approach_distance=0.0, check_lift=False)(T)[0]
    assert PandaIKReachability(approach_distance=0.10)(T)[0]  # the simulator's 10 cm
    assert not PandaIKReachability(approach_distance=0.8, check_lift=False)(T)[0]


def test_rejects_bad_shapes(reach):
    with pytest.raises(ValidationError, match=r"\(K, 4, 4\)"):
        reach(np.eye(4))
    with pytest.raises(ValidationError, match="finite"):
        PandaIKReachability(q_home=np.zeros(6))
    bad = down(0.45, 0.0, 0.03)
    bad[0, 3] = np.nan
    assert reach(bad[None]).tolist() == [False]


def test_sim_tool_pose_moves_tcp_to_the_simulators_depth():
    T = down(0.4, 0.1, 0.05, yaw=0.3)
    S = sim_tool_pose(T)
    np.testing.assert_allclose(S[:3, :3], T[:3, :3])
    shift = TCP_OFFSET - PANDA_HAND.flange_offset
    assert 0.0 < shift < 0.003
    np.testing.assert_allclose(S[:3, 3], T[:3, 3] + shift * T[:3, 2], atol=1e-12)
    # batched (K, 4, 4) gives the same
    np.testing.assert_allclose(sim_tool_pose(np.stack([T, T]))[1], S)


def test_solve_matches_the_simulators_ik_chain(reach):
    """Same model, seeds and order as the first chain of ``Simulator.plan_grasp``: identical
    joint angles."""
    T = down(0.5, -0.1, 0.04, yaw=0.7)
    q_pre, q_grasp, _ = reach.solve(T)
    kin = PandaKinematics(default_base_pose())
    tool = sim_tool_pose(T)
    ref_pre = kin.ik(offset_along_z(tool, -0.1), HOME_TABLETOP, rng=np.random.default_rng(5))
    ref_grasp = kin.ik(tool, ref_pre.q, rng=np.random.default_rng(5))
    assert ref_pre.success and ref_grasp.success
    np.testing.assert_array_equal(q_pre, ref_pre.q)
    np.testing.assert_array_equal(q_grasp, ref_grasp.q)
    np.testing.assert_allclose(kin.fk(q_grasp), tool, atol=2e-3)


def test_symmetric_twin_is_what_gets_executed(reach):
    strict = PandaIKReachability(symmetric=False)
    yaws = np.linspace(-np.pi, np.pi, 13)
    poses = np.stack([down(0.45, 0.12, 0.03, yaw=a) for a in yaws])
    sym_ok = reach(poses)
    strict_ok = strict(poses)
    assert sym_ok.all()
    assert np.all(sym_ok >= strict_ok)  # the twin only ever adds reachable poses
    for T in poses:
        tool = reach.executable_pose(T)
        assert tool is not None
        twin = sim_tool_pose(T @ HALF_TURN_Z)
        assert np.allclose(tool, sim_tool_pose(T)) or np.allclose(tool, twin)
        # the chosen twin is reachable as is
        back = tool.copy()
        back[:3, 3] -= (TCP_OFFSET - PANDA_HAND.flange_offset) * tool[:3, 2]
        assert strict(back[None])[0]
    assert reach.executable_pose(down(1.5, 0.0, 0.03)) is None


def test_planned_grasp_is_executable_in_the_simulator(reach):
    box = ObjectSpec("box", position=(0.42, 0.08, 0.035), size=(0.04, 0.05, 0.07))
    spec = SceneSpec(objects=(box,), seed=3)
    planner = GraspPlanner(reachability=reach)
    grasps = planner.plan(
        [box.superquadric()],
        environment=Environment.table(0.0),
        options=PlanOptions(max_results=3, chunk_size=32, seed=1),
    )
    assert grasps
    with Simulator() as sim:
        sim.reset(spec)
        executed = None
        for g in grasps:
            tool = reach.executable_pose(g.pose)
            assert tool is not None
            try:
                executed = sim.grasp(tool, min(g.width + 0.02, 0.08))
                break
            except PreconditionError as exc:  # arm collisions may refuse; IK never may
                assert "unreachable" not in str(exc)
        assert executed is not None and executed.success, executed


def test_arm_obstacle_test_agrees_with_pybullet():
    """``obstacles``: the link-vertex test against the table box agrees with PyBullet's arm-table
    collision check (links 1-7, the simulator's margin) on random configurations near the table:
    in 300 of them at most 2 PyBullet hits are missed (a hull face cutting a box corner between
    vertices) and no free configuration is refused."""
    import pybullet as p
    from sqmanip.planning.scenarios import sim_reachability

    reach = sim_reachability()
    kin = reach.kinematics
    rng = np.random.default_rng(0)
    with Simulator() as sim:
        sim.reset(SceneSpec(objects=(), seed=0))
        robot = sim._require_robot()
        table = next(b for b, name in sim._static.items() if name == "table")
        arm = {f"panda_link{i}" for i in range(1, 8)}
        links = {
            j
            for j in range(p.getNumJoints(robot.body, physicsClientId=sim.client))
            if p.getJointInfo(robot.body, j, physicsClientId=sim.client)[12].decode() in arm
        }
        margin = sim.config.collision_margin
        counts = np.zeros((2, 2), dtype=int)  # [pybullet hit, ours hit]
        while counts.sum() < 300:
            q = kin.lower + rng.random(7) * (kin.upper - kin.lower)
            if abs(kin.fk(q)[2, 3]) > 0.25:  # the tool far from the table: trivially free
                continue
            snap = robot.snapshot()
            robot.pose_config(q, 0.08)
            hits = p.getClosestPoints(robot.body, table, margin, physicsClientId=sim.client)
            robot.restore(snap)
            truth = any(c[3] in links and c[8] < margin for c in hits)
            counts[int(truth), int(reach._hits_obstacle(q))] += 1
    assert counts[0, 1] == 0, counts
    assert counts[1, 1] >= 10 and counts[1, 0] <= 2, counts
    assert not PandaIKReachability()._hits_obstacle(q)  # no obstacles: nothing to hit
