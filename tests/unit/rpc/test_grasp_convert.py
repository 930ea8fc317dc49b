"""Grasp planner domain <-> proto conversion (grasp.proto): round trips through serialized bytes,
defaults for unset fields, and errors that name the field (unknown target id -> NotFoundError)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sqmanip.errors import NotFoundError, ValidationError
from sqmanip.geometry import Superquadric
from sqmanip.grasping import (
    PANDA_HAND,
    Environment,
    Grasp,
    GripperSpec,
    PlanOptions,
    PlanStats,
    RuleOptions,
)
from sqmanip.grasping.planner import PlanResult
from sqmanip.perception.types import RecognizedObject
from sqmanip.rpc import convert
from sqmanip.v1 import grasp_pb2


def _wire(msg):
    return type(msg).FromString(msg.SerializeToString())


def pose(x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = (x, y, z)
    return T


def box(x: float, y: float, half: float = 0.025, yaw: float = 0.0) -> Superquadric:
    return Superquadric(size=(half, half, half), shape=(0.2, 0.2), pose=pose(x, y, half, yaw))


MUG = [
    Superquadric(size=(0.04, 0.04, 0.05), shape=(0.3, 1.0), pose=pose(0.4, 0.1, 0.05, 0.3)),
    Superquadric(
        size=(0.03, 0.02, 0.01), shape=(1.0, 0.5), pose=pose(0.45, 0.1, 0.06), kind="supertoroid",
        a4=0.02, taper=0.1, bend=0.5, bend_direction=0.4,
    ),
]  # fmt: skip


def assert_parts_equal(a, b) -> None:
    assert len(a) == len(b)
    for p, q in zip(a, b, strict=True):
        assert (p.kind, p.size, p.shape, p.a4) == (q.kind, q.size, q.shape, q.a4)
        assert (p.taper, p.bend, p.bend_direction) == (q.taper, q.bend, q.bend_direction)
        np.testing.assert_allclose(p.pose, q.pose, atol=1e-12)


def test_plan_request_round_trips_every_argument() -> None:
    env = Environment(
        support_normal=(0.0, 0.0, 1.0), support_offset=-0.02, boxes=(box(0.7, 0.0, 0.1),)
    )
    gripper = GripperSpec(max_opening=0.1, finger_length=0.06, palm_size=(0.06, 0.25, 0.05))
    options = PlanOptions(
        n_samples=64, n_approach=6, beta=2.0, max_results=None, seed=3, score="uncertainty",
        method="rule_based", include_wrist=True, approach_distance=0.1, check_target=False,
        rule=RuleOptions.shelf(facing=(1.0, 0.0, 0.0)),
    )  # fmt: skip
    observed = np.random.default_rng(0).normal(size=(50, 3)).astype(np.float32)
    msg = convert.plan_grasps_request_to_proto(
        MUG, [[box(0.5, -0.1)], [box(0.3, 0.2)]], env, gripper, options, observed,
        check_reachability=False,
    )  # fmt: skip
    args = convert.plan_grasps_request_from_proto(_wire(msg))
    assert args.target_id == 0
    assert_parts_equal(args.target, MUG)
    assert len(args.obstacles) == 2
    assert_parts_equal(args.obstacles[1], [box(0.3, 0.2)])
    assert args.environment.support_normal == (0.0, 0.0, 1.0)
    assert args.environment.support_offset == -0.02
    assert_parts_equal(args.environment.boxes, env.boxes)
    assert args.gripper == gripper
    assert args.options == options
    assert args.check_reachability is False
    np.testing.assert_array_equal(args.observed_points, observed)


def test_recognized_objects_keep_their_ids_and_the_target_is_chosen_by_id() -> None:
    objs = [
        RecognizedObject(id=7, parts=[box(0.4, 0.0)], point_indices=np.arange(3)),
        RecognizedObject(id=2, parts=MUG, point_indices=np.arange(2)),
    ]
    msg = convert.plan_grasps_request_to_proto(objs[1], [objs[0]])
    assert msg.target_id == 2 and [o.id for o in msg.objects] == [2, 7]
    args = convert.plan_grasps_request_from_proto(_wire(msg))
    assert_parts_equal(args.target, MUG)
    assert_parts_equal(args.obstacles[0], [box(0.4, 0.0)])


def test_unset_fields_take_the_domain_defaults() -> None:
    msg = grasp_pb2.PlanGraspsRequest(objects=[convert._parts_object(4, [box(0.4, 0)])])
    msg.target_id = 4
    args = convert.plan_grasps_request_from_proto(_wire(msg))
    assert args.options == PlanOptions()
    assert args.gripper == PANDA_HAND
    assert args.environment.support_normal is None  # unset plane on the wire = no plane
    assert args.check_reachability is True and args.observed_points is None
    # None environment on the client side is the domain default (a table at z = 0).
    back = convert.plan_grasps_request_from_proto(
        _wire(convert.plan_grasps_request_to_proto([box(0.4, 0)]))
    )
    assert back.environment.support_normal == (0.0, 0.0, 1.0)
    assert back.environment.support_offset == 0.0


def test_max_results_zero_on_the_wire_means_all() -> None:
    opts = convert.plan_options_from_proto(grasp_pb2.GraspPlanOptions(max_results=0))
    assert opts.max_results is None
    assert convert.plan_options_to_proto(PlanOptions(max_results=None)).max_results == 0
    assert (
        convert.plan_options_from_proto(grasp_pb2.GraspPlanOptions(max_results=5)).max_results == 5
    )


def test_grasps_and_stats_round_trip() -> None:
    g1 = Grasp(pose=pose(0.4, 0.1, 0.05, 0.7), width=0.05, score=0.9,
               contacts=np.array([[0.4, 0.075, 0.05], [0.4, 0.125, 0.05]]), uncertainty=0.25)  # fmt: skip
    g2 = Grasp(pose=pose(0.3, 0.0, 0.1), width=0.03, score=-0.5)
    stats = PlanStats(n_samples=64, n_pairs=40, n_candidates=480, n_checked=256,
                      n_unreachable=3, n_colliding=17, collisions={"support": 15, "object:0": 2},
                      timings_ms={"total": 12.5})  # fmt: skip
    back = convert.plan_result_from_proto(
        _wire(convert.plan_result_to_proto(PlanResult([g1, g2], stats), target_id=5))
    )
    assert back.stats == stats
    a, b = back.grasps
    np.testing.assert_allclose(a.pose, g1.pose, atol=1e-12)
    np.testing.assert_allclose(a.contacts, g1.contacts)
    assert (a.width, a.score, a.uncertainty) == (0.05, 0.9, 0.25)
    assert b.contacts is None and b.uncertainty is None


def test_unknown_target_id_is_not_found() -> None:
    msg = convert.plan_grasps_request_to_proto([box(0.4, 0)], [[box(0.5, 0)]])
    msg.target_id = 9
    with pytest.raises(NotFoundError, match=r"target_id: no object with id 9"):
        convert.plan_grasps_request_from_proto(msg)


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda m: setattr(m.objects[1].parts[0], "a1", float("nan")), r"objects\[1\]\.parts\[0\]"),
        (lambda m: setattr(m.objects[0].parts[0], "a2", -0.1), r"objects\[0\]\.parts\[0\]"),
        (lambda m: setattr(m.objects[1], "id", 0), r"objects: ids must be unique"),
        (lambda m: m.objects[0].ClearField("parts"), r"objects\[0\]\.parts"),
        (lambda m: setattr(m.options, "n_samples", 0), r"options\.n_samples"),
        (lambda m: setattr(m.options, "score", "best"), r"options\.score"),
        (lambda m: setattr(m.options.rule, "tilt", 3.0), r"options\.rule\.tilt"),
        (lambda m: setattr(m.gripper, "max_opening", -1.0), r"gripper\.max_opening"),
        (lambda m: m.environment.support_plane.normal.CopyFrom(convert.vec3_to_proto((0, 0, 0))),
         r"environment\.support_normal"),
        (lambda m: m.observed_points.CopyFrom(
            convert.cloud_to_proto(np.zeros((3, 3))).__class__(num_points=4, xyz=b"\0" * 12)),
         r"cloud\.xyz"),
    ],
)  # fmt: skip
def test_bad_values_raise_validation_errors_naming_the_field(mutate, field) -> None:
    msg = convert.plan_grasps_request_to_proto([box(0.4, 0)], [[box(0.5, 0)]])
    mutate(msg)
    with pytest.raises(ValidationError, match=field):
        convert.plan_grasps_request_from_proto(_wire(msg))
