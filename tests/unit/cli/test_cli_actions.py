"""``sqmanip predict|plan|search`` command logic against a fake SDK client (no stack): what is
sent, what is printed, how a failed episode ends (one ``error:`` line, exit 1)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import sqmanip_client as sdk
from sqmanip.cli import common, main
from sqmanip_client.planning import EpisodeStatus


def _part(x: float, y: float) -> sdk.SuperquadricPart:
    return sdk.SuperquadricPart(
        "superellipsoid",
        (0.03, 0.03, 0.05),
        (0.2, 1.0),
        0.0,
        0.0,
        0.0,
        sdk.Pose((x, y, 0.05), (0.0, 0.0, 0.0, 1.0)),
    )


class FakeClient:
    base_url = "http://fake"

    def __init__(self, episodes=None) -> None:
        self.calls: list[tuple[str, tuple, dict]] = []
        self._episodes = list(episodes or [])

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass

    def sim_state(self):
        objs = (
            sdk.SimObject(0, "box_0", "box", _part(0.4, 0.0).pose, _part(0.4, 0.0)),
            sdk.SimObject(1, "mesh_1", "mesh", _part(0.5, 0.1).pose, None),
            sdk.SimObject(2, "cyl_2", "cylinder", _part(0.3, -0.1).pose, _part(0.3, -0.1)),
        )
        return sdk.SimState(0.0, "tabletop", objs, (0.0,) * 7, 0.08, _part(0, 0).pose, None)

    def predict(self, objects, actions, *, model):
        self.calls.append(("predict", (objects, actions), {"model": model}))
        poses = np.tile(np.eye(4), (len(actions), len(objects), 1, 1))
        for i, p in enumerate(objects):
            poses[:, i, :3, 3] = p.pose.position
        poses[0, 0, 0, 3] += 0.05  # push 0 moves object 0 by 5 cm along x
        return sdk.Prediction(poses, model, None, 12.0)

    def start_search_episode(self, scenario=None, **body):
        self.calls.append(("start_search_episode", (scenario,), body))
        return "ep0123456789"

    def get_search_episode(self, episode_id):
        return self._episodes.pop(0)


def _status(status, events, result=None, error=None) -> EpisodeStatus:
    return EpisodeStatus(
        "ep0123456789", "search", status, tuple(events), len(events), result, error, 1.5
    )


@pytest.fixture
def fake(monkeypatch):
    holder = {}

    def install(client: FakeClient) -> FakeClient:
        monkeypatch.setattr(common, "client", lambda args: client)
        holder["c"] = client
        return client

    return install


def test_predict_on_sim_objects_skips_meshes_and_reports_motion(fake, capsys) -> None:
    c = fake(FakeClient())
    assert main(["predict", "--sim", "--push", "-0.35,0,0.05,0.05,0,0", "--push",
                 "0.3,-0.2,0.05,0,0.05,0"]) == 0  # fmt: skip
    name, (objects, actions), kw = c.calls[0]
    assert name == "predict" and len(objects) == 2 and kw == {"model": "sqpdnet"}
    assert actions[0] == [-0.35, 0.0, 0.05, 0.05, 0.0, 0.0]
    out = capsys.readouterr().out
    rows = [ln.split() for ln in out.splitlines() if ln.strip().startswith(("0 ", "2 "))]
    assert rows[0][:2] == ["0", "0.450"] and rows[0][4] == "50.0"  # moved 50 mm
    assert rows[1][4] == "0.0"


def test_search_follows_events_and_prints_the_result(fake, tmp_path, capsys) -> None:
    ev0 = {
        "step": 0,
        "action": "push",
        "f_sum": 2.0,
        "fg_sum": 0.0,
        "visible": False,
        "graspable": False,
        "executed": True,
        "message": "pushed",
    }
    ev1 = {**ev0, "step": 1, "action": "grasp", "visible": True, "graspable": True}
    result = {
        "found": True,
        "grasped": True,
        "find_steps": 1,
        "grasp_steps": 1,
        "steps": 1,
        "reason": "target grasped and taken out",
        "wall_s": 1.0,
        "scenario": None,
    }
    c = fake(
        FakeClient(
            [
                _status("running", [ev0]),
                _status("running", [ev0, ev1]),
                _status("done", [ev0, ev1], result),
            ]
        )
    )
    out_file = tmp_path / "ep.json"
    argv = [
        "search",
        "--n-objects",
        "3",
        "--seed",
        "4",
        "--max-steps",
        "5",
        "--poll",
        "0",
        "--out",
        str(out_file),
    ]
    assert main(argv) == 0
    body = c.calls[0][2]
    assert body["n_objects"] == 3 and body["seed"] == 4 and body["max_steps"] == 5
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("step  0  push") and "executed" in out[0]
    assert out[1].startswith("step  1  grasp") and "target visible, graspable" in out[1]
    assert out[2].startswith("found at step 1, grasped; 1 step(s)")
    assert json.loads(out_file.read_text())["result"]["grasped"] is True


def test_failed_episode_is_one_error_line(fake, capsys) -> None:
    err = {"status": 503, "code": "UNAVAILABLE", "detail": "sim is not serving"}
    fake(FakeClient([_status("failed", [], None, err)]))
    assert main(["search", "--poll", "0"]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-1] == "error: episode ep0123456789 failed: sim is not serving"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["plan", "--sim"], "--task: required"),
        (["plan", "--sim", "--task", "moving"], "--goal ID:x,y,z: at least one"),
        (["plan", "--sim", "--task", "moving", "--goal", "a:1,2,3"], "integer object id"),
        (["plan", "--sim", "--task", "grasping"], "--target: required for --task grasping"),
        (["plan", "--scene-json", "s.json", "--task", "singulation", "--execute"], "needs --sim"),
        (["plan", "--task", "singulation"], "give the objects"),
        (["plan", "--episode", "moving", "--sim"], "--episode runs a generated scenario"),
    ],
)
def test_plan_argument_errors_are_usage_errors(fake, capsys, argv, message) -> None:
    fake(FakeClient())
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0]
