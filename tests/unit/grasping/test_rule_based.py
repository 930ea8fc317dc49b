"""Rule-based candidates of B.5 (tabletop) and C.3 (shelf): directions, counts and width limits."""

import math

import numpy as np
import pytest
import torch
from grasp_helpers import box, lying_cylinder, pose
from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric, pack, world_implicit, world_normal
from sqmanip.grasping import (
    Environment,
    GraspPlanner,
    PlanOptions,
    RuleOptions,
    always_reachable,
    rule_based_candidates,
)

UP = np.array([0.0, 0.0, 1.0])


def on_surface(part: Superquadric, points: torch.Tensor, atol: float = 1e-5) -> bool:
    packed = pack([part], dtype=torch.float64)
    S = world_implicit(points.reshape(-1, 3), packed.params, packed.poses, packed.kinds)[0]
    return bool(torch.allclose(S, torch.ones_like(S), atol=atol))


def test_small_box_gets_top_down_and_four_side_directions_thirty_at_most():
    b = box((0.025, 0.03, 0.05), pose(0.5, 0.0, 0.05, (0.0, 0.0, 0.3)))
    c = rule_based_candidates([b], up=UP)
    assert len(c) == 30  # 5 directions x 6 (B.5)
    z = c.poses[:, :3, 2].numpy()
    top = z @ -UP > 0.999
    assert top.sum() == 6
    side = np.abs(z @ UP) < 1e-9
    assert side.sum() == 24
    # the four side directions are the box's +-x and +-y axes
    axes = np.concatenate([b.pose[:3, :2].T, -b.pose[:3, :2].T])
    dirs = {int(np.argmax(axes @ zi)) for zi in z[side]}
    assert dirs == {0, 1, 2, 3}
    assert on_surface(b, c.contacts)
    assert (c.widths <= 0.07).all()
    # fingers close along the contact line, TCP midway
    mid = c.contacts.mean(1)
    assert torch.allclose(mid, c.poses[:, :3, 3], atol=1e-9)


def test_width_limit_drops_sides_too_wide_to_grasp():
    b = box((0.02, 0.05, 0.06), pose(0.5, 0.0, 0.06))  # 4 x 10 x 12 cm
    c = rule_based_candidates([b], up=UP)
    assert len(c) > 0
    assert (c.widths <= 0.07).all()
    y = c.poses[:, :3, 1].numpy()
    assert (np.abs(y[:, 0]) > 0.999).all()  # only across the 4 cm x side
    assert np.allclose(c.widths.numpy(), 0.04, atol=1e-3)
    # a 7.2 cm side: accepted by the 7.5 cm shelf rule, rejected by the 7 cm table rule
    b72 = box((0.036, 0.08, 0.06), pose(0.5, 0.0, 0.06))
    assert len(rule_based_candidates([b72], up=UP)) == 0
    shelf = rule_based_candidates([b72], up=UP, options=RuleOptions.shelf())
    assert len(shelf) > 0 and (shelf.widths <= 0.075).all() and (shelf.widths > 0.07).all()


def test_shelf_rule_is_side_only_and_tilted_twenty_degrees_down():
    cyl = Superquadric((0.025, 0.025, 0.06), (0.2, 1.0), pose(0.6, 0.0, 0.36))
    c = rule_based_candidates([cyl], up=UP, options=RuleOptions.shelf())
    assert len(c) > 0
    z = c.poses[:, :3, 2].numpy()
    assert np.allclose(z @ UP, -math.sin(math.radians(20.0)), atol=1e-9)
    assert on_surface(cyl, c.contacts)
    R = c.poses[:, :3, :3]
    assert torch.allclose(torch.linalg.det(R), torch.ones(len(c), dtype=torch.float64))
    # facing: only grasps approaching along +x (into the shelf from a robot at the origin)
    f = rule_based_candidates([cyl], up=UP, options=RuleOptions.shelf(facing=(1.0, 0.0, 0.0)))
    zf = f.poses[:, :3, 2].numpy()
    assert 0 < len(f) < len(c)
    horiz = zf[:, :2] / np.linalg.norm(zf[:, :2], axis=-1, keepdims=True)
    assert (horiz[:, 0] >= math.cos(math.pi / 4) - 1e-9).all()


def test_lying_cylinder_is_grasped_across_its_diameter():
    cyl = lying_cylinder()
    c = rule_based_candidates([cyl], up=UP)
    assert len(c) > 0
    # side grasps at other heights would close on a chord with non-opposite normals: dropped
    assert np.allclose(c.widths.numpy(), 0.05, atol=2e-3)
    packed = pack([cyl], dtype=torch.float64)
    n = world_normal(c.contacts.reshape(-1, 3), packed.params, packed.poses, packed.kinds)[0]
    n = n.reshape(-1, 2, 3)
    assert ((n[:, 0] * n[:, 1]).sum(-1) < -0.9).all()
    axis = cyl.pose[:3, 2]
    assert (np.abs(c.poses[:, :3, 1].numpy() @ axis) < 1e-6).all()


def test_rule_based_planning_filters_collisions():
    b = box((0.025, 0.03, 0.05), pose(0.5, 0.0, 0.05))
    planner = GraspPlanner(always_reachable)
    opts = PlanOptions(method="rule_based", max_results=None)
    res = planner.plan_detailed([b], environment=Environment.table(), options=opts)
    assert 0 < len(res.grasps) < res.stats.n_candidates  # low side grasps hit the table
    assert res.stats.collisions.get("support", 0) > 0
    assert all(g.width <= 0.07 for g in res.grasps)
    assert res.grasps[0].score == pytest.approx(1.0)


def test_rule_options_validation():
    with pytest.raises(ValidationError, match="max_width"):
        RuleOptions(max_width=0.0)
    with pytest.raises(ValidationError, match="tilt"):
        RuleOptions(tilt=2.0)
    with pytest.raises(ValidationError, match="parts"):
        rule_based_candidates([])
