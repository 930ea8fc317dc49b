"""Closed-loop episodes in the real simulator (ground-truth shapes, PyBullet physics dynamics)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sqmanip.dynamics.physics import PhysicsDynamics
from sqmanip.planning.episode import EpisodeRunner, StepEvent, run_episode, sim_planner
from sqmanip.planning.recognition import GroundTruthObjects
from sqmanip.planning.scenarios import Scenario
from sqmanip.planning.tasks import GraspingTask, MovingTask
from sqmanip.sim import ObjectSpec, SceneSpec, Simulator

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def runner():
    torch.set_num_threads(1)
    sim = Simulator()
    dyn = PhysicsDynamics()
    # K = 6 physics rollouts per step keeps a step at a few seconds on 2 cores
    yield EpisodeRunner(sim, GroundTruthObjects(), sim_planner(dyn, n_sequences=6), max_steps=2)
    dyn.close()
    sim.close()


def _box(x: float, y: float) -> ObjectSpec:
    return ObjectSpec("box", position=(x, y, 0.03), size=(0.05, 0.05, 0.06), name="box")


def test_moving_episode_brings_lone_box_toward_goal_10cm_along_x(runner):
    box = _box(0.42, 0.0)
    goal = (0.52, 0.0, 0.03)
    sc = Scenario(
        "moving", 0, 0, SceneSpec("tabletop", (box,), 3), MovingTask.to_positions({0: goal}), "t"
    )
    events: list[StepEvent] = []
    gen = runner.run(sc)
    while True:
        try:
            events.append(next(gen))
        except StopIteration as stop:
            res = stop.value
            break
    assert events, "the episode must execute at least one push"
    assert events[0].status == "pushed" and events[0].action is not None
    d0 = 0.10
    final = res.metric
    assert final < d0 - 0.03, f"distance to goal {final:.3f} m did not shrink from {d0}"
    assert res.steps == len([e for e in events if e.action is not None])
    assert 1 <= res.steps <= 2
    # the planner's prediction and the simulated outcome agree on the pushed box (GT physics)
    pred = np.array(events[0].predicted[0][:2])
    obs = np.array(events[0].observed[0][:2])
    assert np.linalg.norm(pred - obs) < 0.02


def test_grasping_episode_on_graspable_lone_box_succeeds_without_pushing(runner):
    sc = Scenario(
        "grasping_large",
        0,
        0,
        SceneSpec("tabletop", (_box(0.45, 0.05),), 3),
        GraspingTask(0),
        "t",
    )
    res = run_episode(runner, sc)
    assert res.success, res.reason
    assert res.grasp_found
    assert res.steps <= 1
    assert runner.sim.get_state().held_object == 0
