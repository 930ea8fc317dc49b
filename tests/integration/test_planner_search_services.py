"""End to end (issue 9 item 3, issue 10 item 3): the launcher starts perception, sim, dynamics,
grasp, the MPC planner and the shelf-search orchestrator (and the gateway, and Zenoh). ``POST
/plan`` chooses a push that brings a lone box closer to a goal 10 cm along +x; malformed tasks
are 400 naming the field while the planner keeps answering; ``/search/evaluate`` returns maps of
the pose grid's shape; background episodes stream to ``GET /{mpc,search}/episodes/{id}`` (and
search events to Zenoh); with the simulator gone a search episode is 503 within seconds.

The dynamics model is SQPD-Net when ``models/sqpdnet`` holds a checkpoint, else the PyBullet
re-simulation baseline ("physics", a few sequences: ~1 s each). One stack serves the module."""

from __future__ import annotations

import asyncio
import contextlib
import os
import queue
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
import sqmanip_client as sdk
from sqmanip.launch import running_stack
from sqmanip.search.scenarios import scenario_from_objects
from sqmanip.search.shelf import ShelfSpec, TargetSpec, make_pose_grid
from sqmanip.sim import ObjectSpec

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]
HAS_SQPDNET = (REPO / "models" / "sqpdnet" / "model.pt").is_file() and (
    os.environ.get("SQMANIP_TEST_MPC_MODEL", "") != "physics"
)
"""Set SQMANIP_TEST_MPC_MODEL=physics to test the physics baseline although a checkpoint exists."""
MODEL = "sqpdnet" if HAS_SQPDNET else "physics"
K = 32 if HAS_SQPDNET else 6
SERVICES = ("perception", "sim", "dynamics", "grasp", "mpc", "search")


@pytest.fixture(scope="module")
def stack():
    with running_stack(services=SERVICES, zenoh=True, timeout=120) as s:
        yield s


@pytest.fixture(scope="module")
def client(stack):
    with sdk.Client(stack.gateway_url, timeout=120) as c:
        yield c


def lone_box(x: float = 0.55, y: float = 0.0) -> dict:
    part = {"kind": "superellipsoid", "size": [0.03, 0.03, 0.03], "shape": [0.2, 0.2],
            "pose": {"position": [x, y, 0.03]}}  # fmt: skip
    return {"id": 0, "parts": [part]}


def moving_body(goal_x: float = 0.65, **options) -> dict:
    opts = {"num_sequences": K, "seed": 0, "dynamics_model": MODEL, **options}
    return {
        "objects": [lone_box()],
        "task": {"kind": "moving", "goals": [{"id": 0, "position": [goal_x, 0.0, 0.03]}]},
        "options": opts,
    }


def wait_done(get, episode_id: str, timeout: float = 90.0) -> sdk.EpisodeStatus:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ep = get(episode_id)
        if ep.finished:
            return ep
        time.sleep(0.5)
    raise AssertionError(f"episode {episode_id} still running after {timeout} s")


def test_plan_pushes_a_lone_box_toward_its_goal(client):
    plan = client.plan(
        [lone_box()], {"kind": "moving", "goals": {0: (0.65, 0.0, 0.03)}},
        num_sequences=K, seed=0, dynamics_model=MODEL,
    )  # fmt: skip
    assert plan.action is not None and plan.pushed_id == 0 and plan.dynamics_model == MODEL
    assert plan.num_candidates == K and plan.sequence.shape == (1, 6)
    if not HAS_SQPDNET:  # the physics baseline: a box only moves the way it is pushed
        assert plan.action[3] > 0.0, f"the push should move along +x, got v = {plan.action[3:]}"
    predicted = np.asarray(plan.predicted_next[0].position)
    assert np.linalg.norm(predicted[:2] - [0.65, 0.0]) < 0.10 - 0.02  # closer than the start
    assert plan.cost < plan.current_cost == pytest.approx(0.01, abs=1e-6)
    assert {"sampling", "rollout", "cost", "total"} <= plan.timings_ms.keys()


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"task": {"kind": "moving", "goals": [{"id": 7, "position": [0.6, 0, 0.03]}]}},
         "task.goals"),
        ({"task": {"kind": "moving", "goals": [{"id": 0, "position": [3.0, 0, 0.03]}]}},
         "task.goals[0]"),
        ({"options": {"num_sequences": 0, "dynamics_model": MODEL}}, "options.num_sequences"),
        ({"task": {"kind": "grasping", "target_id": 5}}, "task.target_id"),
        ({"task": {"kind": "interactive_moving", "target_id": 0}}, "task.goal"),
    ],
)  # fmt: skip
def test_malformed_plans_are_400_naming_the_field(stack, change, field):
    body = {**moving_body(), **change}
    r = httpx.post(f"{stack.gateway_url}/plan", json=body, timeout=30)
    assert r.status_code == 400, r.text
    assert r.json()["field"] == field, r.text


def test_planner_keeps_answering_after_bad_requests(stack):
    url = f"{stack.gateway_url}/plan"
    bad = httpx.post(url, json={**moving_body(), "options": {"num_sequences": 0}}, timeout=30)
    assert bad.status_code == 400
    ok = httpx.post(url, json=moving_body(num_sequences=2), timeout=60)
    assert ok.status_code == 200, ok.text
    assert ok.json()["has_action"] is True


def test_search_evaluate_returns_maps_of_the_grid_shape(stack):
    shelf = ShelfSpec()
    T = np.eye(4)
    T[:3, 3] = [shelf.front_x + 0.10, 0.0, shelf.bottom_z + 0.08]
    box = {"size": [0.03, 0.10, 0.08], "shape": [0.2, 0.2],
           "pose": {"position": T[:3, 3].tolist()}}  # fmt: skip
    target = TargetSpec.cylinder(0.025, 0.10)
    grid = make_pose_grid(shelf, target, 0.02)

    async def evaluate():
        async with sdk.AsyncClient(stack.gateway_url, timeout=60) as c:
            return await c.evaluate_search(
                [box], {"kind": "cylinder", "size": list(target.size)}, resolution=0.02
            )

    maps = asyncio.run(evaluate())
    assert maps.shape == tuple(grid.shape)
    assert maps.f.shape == maps.g.shape == maps.g_m.shape == tuple(grid.shape)
    assert maps.grid_xy.shape == (len(grid), 2)
    assert set(np.unique(maps.f)) <= {0.0, 1.0}
    assert 0 < maps.f.sum() < maps.f.size  # hidden behind the box, seen elsewhere
    hidden = maps.grid_xy[maps.f.reshape(-1) > 0]
    assert np.all(hidden[:, 0] > T[0, 3]), "the target can only hide behind the box (+x)"


def test_mpc_episode_runs_in_the_background(client):
    eid = client.start_mpc_episode(
        "moving", 0, 0, objects="ground_truth", max_steps=1,
        options={"num_sequences": 4 if not HAS_SQPDNET else K, "seed": 0,
                 "dynamics_model": MODEL},
    )  # fmt: skip
    ep = wait_done(client.get_mpc_episode, eid)
    assert ep.status == "done", ep.error
    assert ep.result["steps"] == 1 and ep.result["kind"] == "moving"
    assert ep.n_events == 1 and ep.events[0]["status"] in ("pushed", "push_refused")
    assert len(ep.events[0]["action"]) == 6
    with pytest.raises(sdk.NotFoundError):
        client.get_mpc_episode("no-such-episode")


def test_search_episode_runs_and_publishes_on_zenoh(client, stack):
    from sqmanip.streams import subscribe

    shelf = ShelfSpec()
    box = ObjectSpec("box", size=(0.06, 0.12, 0.16)).with_pose(
        (shelf.front_x + 0.12, 0.0, shelf.bottom_z + 0.08 + 1e-4), (0.0, 0.0, 0.0, 1.0)
    )
    scenario = scenario_from_objects([box], (shelf.front_x + 0.25, 0.0))
    session, sub = subscribe("sqmanip/search/episode", stack.settings)
    try:
        for _ in range(3):  # a later episode once the subscription has reached the publisher
            eid = client.start_search_episode(scenario, max_steps=1, num_sequences=4)
            ep = wait_done(client.get_search_episode, eid)
            assert ep.status == "done", ep.error
            assert ep.result["steps"] <= 1 and ep.result["reason"]
            assert ep.result["scenario"]["n_objects"] == 1
            assert ep.n_events >= 1
            first = ep.events[0]
            assert first["action"] in ("push", "pick_and_place", "grasp", "none")
            assert first["f_sum"] >= first["fg_sum"] >= 0.0
            with contextlib.suppress(queue.Empty):
                key, payload = sub.get(timeout=5)
                break
        else:
            pytest.fail("no search event on Zenoh after 3 episodes")
        assert key == "sqmanip/search/episode" and len(payload) > 0
    finally:
        sub.close()
        session.close()
    with pytest.raises(sdk.NotFoundError):
        client.get_search_episode("no-such-episode")


def test_search_episode_without_sim_is_503_quickly(client, stack):
    """Runs last: stops the simulator for good."""
    stack.kill("sim")
    proc = next(p for p in stack.procs if p.name == "sim")
    proc.popen.wait(10)
    t0 = time.monotonic()
    with pytest.raises(sdk.ServiceUnavailableError, match="sim service unavailable"):
        client.start_search_episode(n_objects=2, seed=0)
    assert time.monotonic() - t0 < 5.0
    with pytest.raises(sdk.ServiceUnavailableError, match="sim"):
        client.start_mpc_episode("moving", objects="ground_truth", options={"num_sequences": 2,
                                 "dynamics_model": MODEL})  # fmt: skip
    # the orchestrator itself still answers what needs no simulator
    maps = client.evaluate_search([], resolution=0.04)
    grid = make_pose_grid(ShelfSpec(), TargetSpec.cylinder(0.025, 0.10), 0.04)
    assert maps.shape == tuple(grid.shape)
    assert maps.f.sum() < 0.5 * maps.f.size  # an empty shelf hides the target almost nowhere
