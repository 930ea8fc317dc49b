"""planner.proto <-> sqmanip.planning: tasks, options, plan requests/responses and episode events
round trip; malformed messages raise ValidationError naming the field."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric
from sqmanip.planning.episode import EpisodeResult, StepEvent
from sqmanip.planning.mpc import PlanResult
from sqmanip.planning.tasks import (
    GraspingTask,
    InteractiveMovingTask,
    MovingTask,
    SingulationTask,
)
from sqmanip.rpc import convert
from sqmanip.v1 import planner_pb2


def box(x: float, y: float) -> Superquadric:
    T = np.eye(4)
    T[:3, 3] = [x, y, 0.03]
    return Superquadric(size=(0.03, 0.02, 0.03), shape=(0.2, 0.2), pose=T)


def rz(yaw: float, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = t
    return T


@pytest.mark.parametrize(
    "task",
    [
        MovingTask({0: rz(0.3, (0.6, 0.1, 0.03)), 4: rz(0.0, (0.5, -0.1, 0.03))}, beta=0.5),
        SingulationTask(0.15),
        GraspingTask(3),
        InteractiveMovingTask(2, np.array([0.3, 0.0, 0.03])),
    ],
)
def test_task_round_trip(task):
    back = convert.task_from_proto(convert.task_to_proto(task))
    assert type(back) is type(task)
    if isinstance(task, MovingTask):
        assert back.goals.keys() == task.goals.keys() and back.beta == task.beta
        for k in task.goals:
            np.testing.assert_allclose(back.goals[k], task.goals[k], atol=1e-9)
    elif isinstance(task, InteractiveMovingTask):
        assert back.target_id == task.target_id
        np.testing.assert_allclose(back.goal, task.goal)
    else:
        assert back == task


def test_singulation_default_tau_and_missing_task():
    assert convert.task_from_proto(
        planner_pb2.PlanTask(singulation=planner_pb2.SingulationTask())
    ) == SingulationTask(0.20)
    with pytest.raises(ValidationError, match="^task:"):
        convert.task_from_proto(planner_pb2.PlanTask())


def test_plan_request_round_trip():
    objects = [([box(0.5, 0.0)], 7), ([box(0.6, 0.1), box(0.62, 0.1)], 9)]
    task = MovingTask.to_positions({7: [0.6, 0.0, 0.03]})
    msg = convert.plan_request_to_proto(
        objects, task, num_sequences=12, horizon=2, seed=5, dynamics_model="physics"
    )
    args = convert.plan_request_from_proto(
        planner_pb2.PlanRequest.FromString(msg.SerializeToString())
    )
    assert [i for _, i in args.objects] == [7, 9]
    assert [len(p) for p, _ in args.objects] == [1, 2]
    np.testing.assert_allclose(args.objects[1][0][1].pose, objects[1][0][1].pose)
    assert args.options == convert.MPCArgs(12, 2, 5, "physics")
    np.testing.assert_allclose(args.task.goals[7][:3, 3], [0.6, 0.0, 0.03])
    # unset options are the planner's defaults
    dflt = convert.plan_request_from_proto(convert.plan_request_to_proto(objects, task))
    assert dflt.options == convert.MPCArgs(None, None, None, "sqpdnet")


@pytest.mark.parametrize(
    ("options", "field"),
    [({"num_sequences": 0}, "options.num_sequences"), ({"horizon": 11}, "options.horizon")],
)
def test_bad_options_name_the_field(options, field):
    msg = convert.plan_request_to_proto([([box(0.5, 0)], 0)], SingulationTask(), **options)
    with pytest.raises(ValidationError, match=f"^{field}:"):
        convert.plan_request_from_proto(msg)


def test_bad_objects_name_the_field():
    msg = convert.plan_request_to_proto([([box(0.5, 0)], 1), ([box(0.6, 0)], 1)], GraspingTask(1))
    with pytest.raises(ValidationError, match=r"^objects\[1\]\.id:"):
        convert.plan_request_from_proto(msg)
    msg = convert.plan_request_to_proto([([box(0.5, 0)], 1)], GraspingTask(1))
    msg.objects[0].parts[0].a1 = float("nan")
    with pytest.raises(ValidationError, match=r"^objects\[0\]\.parts\[0\]:"):
        convert.plan_request_from_proto(msg)
    with pytest.raises(ValidationError, match="^objects:"):
        convert.plan_request_from_proto(planner_pb2.PlanRequest())


def plan_result(action=True) -> PlanResult:
    nxt = np.stack([rz(0.2, (0.55, 0.0, 0.03)), rz(-0.1, (0.6, 0.1, 0.03))])
    return PlanResult(
        action=np.array([0.4, 0.0, 0.03, 0.1, 0.0, 0.0]) if action else None,
        predicted_next=nxt,
        cost=0.0125 if action else math.inf,
        current_cost=0.04,
        n_candidates=17 if action else 0,
        timings_ms={"sampling": 1.5, "rollout": 2.5, "total": 4.0},
        sequence=np.arange(12, dtype=np.float64).reshape(2, 6) if action else np.zeros((2, 6)),
        pushed_id=3 if action else None,
        object_ids=(3, 5),
        n_sampled=40,
        n_rejected_start=4,
        n_rejected_workspace=2,
    )


@pytest.mark.parametrize("action", [True, False])
def test_plan_response_round_trip(action):
    r = plan_result(action)
    msg = convert.plan_response_to_proto(r, "physics")
    assert msg.dynamics_model == "physics" and msg.has_action is action
    back = convert.plan_response_from_proto(
        planner_pb2.PlanResponse.FromString(msg.SerializeToString())
    )
    if action:
        np.testing.assert_allclose(back.action, r.action)
    else:
        assert back.action is None and math.isinf(back.cost)
    np.testing.assert_allclose(back.predicted_next, r.predicted_next, atol=1e-9)
    np.testing.assert_allclose(back.sequence, r.sequence)
    assert back.object_ids == r.object_ids and back.pushed_id == r.pushed_id
    assert (back.n_candidates, back.n_sampled, back.n_rejected_start, back.n_rejected_workspace) == (
        r.n_candidates, r.n_sampled, r.n_rejected_start, r.n_rejected_workspace,
    )  # fmt: skip
    assert back.timings_ms == r.timings_ms and back.current_cost == r.current_cost


def test_episode_request_round_trip_and_errors():
    msg = convert.episode_request_to_proto(
        "singulation", 3, 11, objects="ground_truth", max_steps=4,
        options={"num_sequences": 8, "seed": 2, "dynamics_model": "physics"},
    )  # fmt: skip
    args = convert.episode_request_from_proto(msg)
    assert (args.kind, args.index, args.seed, args.objects, args.max_steps) == (
        "singulation", 3, 11, "ground_truth", 4,
    )  # fmt: skip
    assert args.options == convert.MPCArgs(8, None, 2, "physics")
    assert (
        convert.episode_request_from_proto(convert.episode_request_to_proto("moving")).max_steps
        == 10
    )
    with pytest.raises(ValidationError, match="^kind:"):
        convert.episode_request_from_proto(convert.episode_request_to_proto("flying"))
    with pytest.raises(ValidationError, match="^objects:"):
        convert.episode_request_from_proto(convert.episode_request_to_proto("moving", objects="x"))


def test_episode_event_and_result_to_dicts():
    truth = np.stack([rz(0.5, (0.5, 0.1, 0.03)), rz(0.0, (0.6, -0.1, 0.03))])
    ev = StepEvent(
        step=2, status="pushed", message="ok", n_points=1234, recognized_ids=(0, 1),
        missing_ids=(), action=(0.4, 0.0, 0.03, 0.1, 0.0, 0.0), pushed_id=1,
        predicted={0: (0.5, 0.1, 0.03, 0.5)}, recognized={1: (0.6, -0.1, 0.03, 0.0)},
        truth_before=truth, truth_after=truth, cost=math.inf, current_cost=0.2,
        metric_after=0.07, n_candidates=9, timings_ms={"plan": 12.0},
    )  # fmt: skip
    d = convert.episode_event_from_proto(convert.episode_event_to_proto(ev))
    assert d["step"] == 2 and d["status"] == "pushed" and d["pushed_id"] == 1
    assert d["cost"] is None and d["current_cost"] == pytest.approx(0.2)
    np.testing.assert_allclose(d["action"], ev.action)
    np.testing.assert_allclose(d["observed"]["0"], [0.5, 0.1, 0.03, 0.5])
    assert d["predicted"].keys() == {"0"} and d["recognized"].keys() == {"1"}
    res = EpisodeResult("grasping_clutter", 1, True, 3, "lifted", True, math.nan, 12.5, (ev,))
    out = convert.episode_event_from_proto(convert.episode_result_to_proto(res))
    assert out["status"] == "result"
    assert out["result"] == {
        "kind": "grasping_clutter", "index": 1, "success": True, "steps": 3,
        "reason": "lifted", "grasp_found": True, "metric": None, "wall_s": 12.5,
    }  # fmt: skip
