"""GraspPlanner: Algorithm 1 end to end (3.4), scores (3.4.2, 3.6.3), collision and reachability."""

import numpy as np
import pytest
import torch
from grasp_helpers import box, dense_min_implicit, lying_cylinder, pose
from sqmanip.errors import ValidationError
from sqmanip.geometry import pack, sample_parts, world_implicit, world_normal
from sqmanip.grasping import (
    PANDA_HAND,
    Environment,
    GraspPlanner,
    GripperSpec,
    PlanOptions,
    WorkspaceReachability,
    always_reachable,
    rank_order,
)

TABLE = Environment.table()
OPTS = PlanOptions(n_samples=160, max_results=30, seed=0)


def closing_axes(grasps) -> np.ndarray:
    return np.stack([g.pose[:3, 1] for g in grasps])


def test_box_is_grasped_across_its_narrow_side_only():
    # 4 x 12 x 10 cm box: only the 4 cm side fits the 8 cm opening
    target = box((0.02, 0.06, 0.05), pose(0.5, 0.0, 0.05, (0.0, 0.0, 0.4)))
    grasps = GraspPlanner(always_reachable).plan([target], environment=TABLE, options=OPTS)
    assert len(grasps) == OPTS.max_results
    x_obj = target.pose[:3, 0]
    assert (np.abs(closing_axes(grasps) @ x_obj) > 0.9).all()  # the relaxed test allows ~25 deg
    widths = np.array([g.width for g in grasps])
    assert np.allclose(widths, 0.04, atol=2e-3)
    assert grasps[0].score == pytest.approx(1.0)  # 3.4.2: top-down first
    scores = np.round([g.score for g in grasps], 6)  # ties compare at 1e-6 (SCORE_DECIMALS)
    assert (np.diff(scores) <= 0).all()


def test_no_grasp_when_every_side_is_wider_than_the_opening():
    target = box((0.05, 0.06, 0.045), pose(0.5, 0.0, 0.045))  # 10 x 12 x 9 cm
    planner = GraspPlanner(always_reachable)
    result = planner.plan_detailed([target], environment=TABLE, options=OPTS)
    assert result.grasps == []
    assert result.stats.n_pairs > 0 and result.stats.n_candidates == 0
    # a gripper opening to 11 cm grasps it across the 10 cm side
    wide = GripperSpec(max_opening=0.11, palm_size=(0.063, 0.25, 0.0586))
    grasps = planner.plan([target], environment=TABLE, gripper=wide, options=OPTS)
    assert grasps and all(g.width <= 0.11 for g in grasps)
    assert (np.abs(closing_axes(grasps) @ np.array([1.0, 0, 0])) > 0.9).all()


def test_lying_cylinder_grasps_have_antipodal_contacts_on_the_surface():
    cyl = lying_cylinder()
    grasps = GraspPlanner(always_reachable).plan([cyl], environment=TABLE, options=OPTS)
    assert grasps
    packed = pack([cyl], dtype=torch.float64)
    for g in grasps:
        c = torch.as_tensor(g.contacts)
        S = world_implicit(c, packed.params, packed.poses, packed.kinds)[0]
        assert torch.allclose(S, torch.ones(2, dtype=torch.float64), atol=1e-5)
        n = world_normal(c, packed.params, packed.poses, packed.kinds)[0]
        assert float(n[0] @ n[1]) < -0.9
        # the TCP is midway and the fingers close along the contact line
        assert np.allclose(g.position, g.contacts.mean(0), atol=1e-9)
        d = g.contacts[1] - g.contacts[0]
        assert abs(d @ g.pose[:3, 1]) == pytest.approx(np.linalg.norm(d), abs=1e-9)
        assert g.width == pytest.approx(np.linalg.norm(d), abs=1e-9)


def test_grasps_that_would_hit_a_neighbour_are_rejected():
    target = box((0.02, 0.05, 0.04), pose(0.5, 0.0, 0.04))
    neighbour = box((0.02, 0.05, 0.04), pose(0.545, 0.05, 0.04))  # 5 mm gap, covers y > 0
    planner = GraspPlanner(always_reachable)
    opts = PlanOptions(n_samples=100, max_results=None, seed=0)
    alone = planner.plan([target], environment=TABLE, options=opts)
    crowded = planner.plan_detailed([target], [[neighbour]], environment=TABLE, options=opts)
    assert crowded.stats.collisions.get("object:0", 0) > 0
    assert 0 < len(crowded.grasps) < len(alone)
    # every grasp kept is clear of the neighbour under a dense (unculled) check
    kept = np.stack([g.pose for g in crowded.grasps])
    assert (dense_min_implicit(kept, [neighbour], PANDA_HAND) >= 1.0).all()
    # and some grasps of the lone box would have hit it
    alone_poses = np.stack([g.pose for g in alone])
    assert (dense_min_implicit(alone_poses, [neighbour], PANDA_HAND) < 1.0).any()


def test_unreachable_grasps_are_rejected():
    target = box((0.02, 0.05, 0.04), pose(0.5, 0.0, 0.04))

    def no_top_down(poses: np.ndarray) -> np.ndarray:
        return poses[:, 2, 2] > -0.5  # rejects approaches pointing more than 60 deg down

    grasps = GraspPlanner(no_top_down).plan([target], environment=TABLE, options=OPTS)
    assert grasps and all(g.approach[2] > -0.5 for g in grasps)
    never = GraspPlanner(lambda poses: np.zeros(len(poses), dtype=bool))
    result = never.plan_detailed([target], environment=TABLE, options=OPTS)
    stats = result.stats
    assert result.grasps == [] and stats.n_unreachable > 0
    # every checked candidate was refused: by a collision, or else (collision-free) by the IK
    assert stats.n_unreachable + stats.n_colliding == stats.n_checked


def test_default_reachability_is_a_workspace_radius():
    target = box((0.02, 0.05, 0.04), pose(0.5, 0.0, 0.04))
    far = box((0.02, 0.05, 0.04), pose(1.5, 0.0, 0.04))
    planner = GraspPlanner()  # WorkspaceReachability
    assert planner.plan([target], environment=TABLE, options=OPTS)
    assert planner.plan([far], environment=TABLE, options=OPTS) == []
    reach = WorkspaceReachability()
    T = np.tile(np.eye(4), (2, 1, 1))
    T[0, :3, 3] = (0.5, 0, 0.1)
    T[1, :3, 3] = (0.0, 0, 0.333)  # flange inside the shoulder
    assert reach(T).tolist() == [True, False]


def test_planning_is_deterministic_given_the_seed():
    cyl = lying_cylinder()
    planner = GraspPlanner(always_reachable)
    a = planner.plan([cyl], environment=TABLE, options=OPTS)
    b = planner.plan([cyl], environment=TABLE, options=OPTS)
    c = planner.plan([cyl], environment=TABLE, options=PlanOptions(n_samples=160, seed=7))
    assert [g.pose.tolist() for g in a] == [g.pose.tolist() for g in b]
    assert [g.pose.tolist() for g in a] != [g.pose.tolist() for g in c]


def test_ties_are_broken_randomly_but_reproducibly():
    scores = torch.tensor([0.5, 1.0, 1.0 + 1e-12, 1.0, 0.2], dtype=torch.float64)
    orders = {tuple(rank_order(scores, s).tolist()) for s in range(20)}
    assert all(set(o[:3]) == {1, 2, 3} and o[3:] == (0, 4) for o in orders)
    assert len(orders) > 1
    assert rank_order(scores, 3).tolist() == rank_order(scores, 3).tolist()


def test_uncertainty_score_prefers_contacts_near_the_observation():
    # observed: only the +y half of a cylinder lying along world y
    cyl = lying_cylinder(yaw=0.0)  # axis along world y after the x rotation
    surface, _, _ = sample_parts([cyl], 2000, generator=5)
    observed = surface[surface[:, 1] > cyl.pose[1, 3] + 0.02]
    planner = GraspPlanner(always_reachable)
    opts = PlanOptions(n_samples=200, max_results=10, seed=0, score="uncertainty")
    unc = planner.plan([cyl], environment=TABLE, options=opts, observed_points=observed)
    plain = planner.plan([cyl], environment=TABLE, options=OPTS, observed_points=observed)
    assert unc and plain
    for g in unc:
        assert g.uncertainty is not None and 0.0 <= g.uncertainty <= 1.0
        assert g.score == pytest.approx(-g.approach @ TABLE.z_t - 5.0 * g.uncertainty)
    mean_y = lambda gs: np.mean([g.contacts[:, 1].mean() for g in gs])  # noqa: E731
    assert mean_y(unc[:5]) > cyl.pose[1, 3] + 0.02
    assert np.mean([g.uncertainty for g in unc[:5]]) < 0.2
    assert all(g.uncertainty is None for g in plain)


def test_uncertainty_score_needs_observed_points():
    with pytest.raises(ValidationError, match="observed_points"):
        GraspPlanner().plan([lying_cylinder()], options=PlanOptions(score="uncertainty"))
    with pytest.raises(ValidationError, match="observed_points"):
        GraspPlanner().plan(
            [lying_cylinder()],
            options=PlanOptions(score="uncertainty"),
            observed_points=np.zeros((0, 3)),
        )


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"n_samples": 0}, "n_samples"),
        ({"antipodal_threshold": 1.5}, "antipodal_threshold"),
        ({"max_results": 0}, "max_results"),
        ({"score": "best"}, "score"),
        ({"method": "magic"}, "method"),
        ({"beta": -1.0}, "beta"),
    ],
)
def test_plan_options_validation_names_the_field(kwargs, field):
    with pytest.raises(ValidationError, match=field):
        PlanOptions(**kwargs)


def test_bad_inputs_are_rejected():
    planner = GraspPlanner()
    with pytest.raises(ValidationError, match="target"):
        planner.plan([])
    with pytest.raises(ValidationError, match="target"):
        planner.plan(lying_cylinder())  # one part, not a list
    with pytest.raises(ValidationError, match="support_normal"):
        Environment(support_normal=(0.0, 0.0, 0.0))


def test_check_poses_reports_reachability_and_collisions():
    target = box((0.02, 0.05, 0.04), pose(0.5, 0.0, 0.04))
    planner = GraspPlanner(lambda T: T[:, 0, 3] < 0.6)
    good = planner.plan([target], environment=TABLE, options=OPTS)[0].pose
    sunk = good.copy()
    sunk[2, 3] = 0.0  # fingers in the table
    far = good.copy()
    far[0, 3] = 0.7
    f = planner.check_poses(np.stack([good, sunk, far]), [target], environment=TABLE)
    assert f.feasible.tolist() == [True, False, False]
    assert f.reachable.tolist() == [True, True, False]
    assert f.collision.collides.tolist()[:2] == [False, True]


def test_widths_within_the_clearance_of_the_full_opening_are_dropped():
    # 7.8 x 12 x 10 cm box: its narrow side fits the 8 cm stroke only without clearance
    target = box((0.039, 0.06, 0.05), pose(0.5, 0.0, 0.05))
    planner = GraspPlanner(always_reachable)
    tight = PlanOptions(n_samples=160, max_results=5, seed=0, opening_clearance=0.004)
    assert planner.plan([target], environment=TABLE, options=tight) == []  # 4 mm clearance
    loose = PlanOptions(n_samples=160, max_results=5, seed=0)  # default: no clearance
    grasps = planner.plan([target], environment=TABLE, options=loose)
    assert grasps and all(0.077 <= g.width <= 0.08 for g in grasps)
    assert tight.opening(0.03, 0.08) == pytest.approx(0.05)  # width + open_margin
    assert tight.opening(0.075, 0.08) == pytest.approx(0.08)  # capped at the stroke


def test_collision_check_holds_the_fingers_at_the_execution_opening():
    # a 2 cm wide post and a neighbour 4-6 cm off its axis along world y: fully open (8 cm)
    # fingers would reach into the neighbour, but the hand opens only to 2 + 2 = 4 cm, so
    # grasps closing along y are feasible (fingers at +-2 cm, their backs clear of it)
    post = box((0.01, 0.01, 0.04), pose(0.5, 0.0, 0.04))
    wall = box((0.03, 0.01, 0.04), pose(0.5, 0.05, 0.04))
    planner = GraspPlanner(always_reachable)
    opts = PlanOptions(n_samples=200, max_results=None, seed=0)
    grasps = planner.plan([post], [[wall]], TABLE, options=opts)
    along_y = [g for g in grasps if abs(g.pose[:3, 1] @ np.array([0.0, 1.0, 0.0])) > 0.99]
    assert along_y and all(g.width < 0.025 for g in along_y)
    # executed fully open (open_margin 8 cm) the fingers would hit the neighbour: rejected
    full = PlanOptions(n_samples=200, max_results=None, seed=0, open_margin=0.08)
    wide = planner.plan([post], [[wall]], TABLE, options=full)
    assert not [g for g in wide if abs(g.pose[:3, 1] @ np.array([0.0, 1.0, 0.0])) > 0.99]
