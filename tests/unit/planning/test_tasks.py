"""Malformed tasks and inputs raise ValidationError naming the field."""

from __future__ import annotations

import numpy as np
import pytest
from planning_helpers import PusherDynamics, box
from sqmanip.errors import ValidationError
from sqmanip.planning import (
    GraspingTask,
    InteractiveMovingTask,
    MovingTask,
    MPCConfig,
    PushMPC,
    SingulationTask,
    TableSpec,
    validate_task,
)

OBJS = [([box(0.45, 0.0)], 1), ([box(0.35, 0.1)], 2)]


def plan(task, **cfg):
    return PushMPC(PusherDynamics(), config=MPCConfig(**cfg)).plan(OBJS, task, 0)


def test_unknown_target_id():
    with pytest.raises(ValidationError, match="task.target_id"):
        plan(GraspingTask(9))
    with pytest.raises(ValidationError, match="task.target_id"):
        plan(InteractiveMovingTask(9, np.array([0.4, 0.0, 0.02])))
    with pytest.raises(ValidationError, match="task.goals"):
        plan(MovingTask.to_positions({9: (0.4, 0.0, 0.02)}))


def test_goal_off_the_table():
    with pytest.raises(ValidationError, match=r"task.goals\[1\].*off the table"):
        plan(MovingTask.to_positions({1: (0.45, 0.9, 0.02)}))
    with pytest.raises(ValidationError, match=r"task.goal\b.*off the table"):
        plan(InteractiveMovingTask(1, np.array([1.2, 0.0, 0.02])))


def test_zero_sequences_and_bad_config():
    with pytest.raises(ValidationError, match="n_sequences"):
        MPCConfig(n_sequences=0)
    with pytest.raises(ValidationError, match="horizon"):
        MPCConfig(horizon=0)
    with pytest.raises(ValidationError, match="table.size"):
        TableSpec(size=(0.0, 1.0))


def test_malformed_task_values():
    with pytest.raises(ValidationError, match="task.tau"):
        SingulationTask(tau=0.0)
    with pytest.raises(ValidationError, match="task.beta"):
        MovingTask.to_positions({1: (0.4, 0.0, 0.0)}, beta=-1.0)
    with pytest.raises(ValidationError, match=r"task.goals\[1\]"):
        MovingTask({1: np.eye(3)})
    with pytest.raises(ValidationError, match="task.goal"):
        InteractiveMovingTask(1, np.array([np.nan, 0.0, 0.0]))
    with pytest.raises(ValidationError, match="task.target_id"):
        GraspingTask("box")  # type: ignore[arg-type]


def test_interactive_moving_needs_another_object():
    with pytest.raises(ValidationError, match="one other object"):
        validate_task(InteractiveMovingTask(1, np.array([0.4, 0.0, 0.0])), [1], TableSpec())


def test_malformed_objects():
    mpc = PushMPC(PusherDynamics())
    with pytest.raises(ValidationError, match="objects"):
        mpc.plan([], SingulationTask(), 0)
    with pytest.raises(ValidationError, match="unique"):
        mpc.plan([([box(0.4, 0.0)], 1), ([box(0.5, 0.0)], 1)], SingulationTask(), 0)
    with pytest.raises(ValidationError, match=r"objects\[0\]"):
        mpc.plan([([], 1)], SingulationTask(), 0)
