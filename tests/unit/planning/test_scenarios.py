"""Scenario generators, id association, task metrics and the PNG writer of the episode runner."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from sqmanip.geometry import Superquadric
from sqmanip.planning.episode import task_metric, write_png
from sqmanip.planning.recognition import FIRST_NEW_ID, ObjectTracker
from sqmanip.planning.scenarios import (
    LARGE_FLAT_BOX,
    SCENARIO_KINDS,
    _footprint,
    _overlap,
    make_scenario,
    sim_table,
)
from sqmanip.planning.tasks import (
    GraspingTask,
    InteractiveMovingTask,
    MovingTask,
    SingulationTask,
    validate_task,
)


@pytest.mark.parametrize("kind", [k for k in SCENARIO_KINDS if k != "grasping_clutter"])
def test_scenarios_are_deterministic_valid_and_non_overlapping(kind):
    a = make_scenario(kind, 1, seed=7)
    b = make_scenario(kind, 1, seed=7)
    c = make_scenario(kind, 2, seed=7)
    assert a.scene.to_dict() == b.scene.to_dict()
    assert a.scene.to_dict() != c.scene.to_dict()
    validate_task(a.task, range(len(a.scene.objects)), sim_table())
    polys = [_footprint(o, np.array(o.position[:2]), _yaw(o)) for o in a.scene.objects]
    for i in range(len(polys)):
        for j in range(i + 1, len(polys)):
            assert not _overlap(polys[i], polys[j], 0.0)
    for o in a.scene.objects:  # resting on the table top
        h = o.size[2] if o.kind == "box" else o.height
        assert o.position[2] == pytest.approx(h / 2)
        assert sim_table().contains_xy(np.array(o.position[:2]), margin=0.05)


def _yaw(o) -> float:
    x, y, z, w = o.orientation
    return 2 * np.arctan2(z, w)


def test_task_kinds_match_the_thesis_setups():
    mv = make_scenario("moving", 0)
    assert isinstance(mv.task, MovingTask)
    for k, T in mv.task.goals.items():  # 4.6.3: goal (0.3, y0, z0)
        assert T[0, 3] == pytest.approx(0.30)
        assert T[1, 3] == pytest.approx(mv.scene.objects[k].position[1])
    sg = make_scenario("singulation", 0)
    assert isinstance(sg.task, SingulationTask) and sg.task.tau == pytest.approx(0.20)
    xy = sg.initial_positions()[:, :2]
    assert task_metric(sg.task, _poses(sg)) <= 0.20  # not singulated at the start
    assert len(xy) >= 3
    lg = make_scenario("grasping_large", 0)
    assert isinstance(lg.task, GraspingTask)
    assert min(LARGE_FLAT_BOX[:2]) > 0.08  # wider than the 8 cm opening both ways
    im = make_scenario("interactive_moving", 0)
    assert isinstance(im.task, InteractiveMovingTask)
    assert im.task.goal[:2] == pytest.approx([0.30, 0.0])


def test_object_sets_alternate_between_boxes_and_cylinders():
    kinds = [{o.kind for o in make_scenario("moving", i).scene.objects} for i in range(4)]
    assert kinds == [{"box"}, {"cylinder"}, {"box"}, {"cylinder"}]


def _poses(sc) -> np.ndarray:
    return np.stack([o.pose for o in sc.scene.objects])


def test_task_metric_moving_and_singulation_on_hand_made_states():
    P = np.tile(np.eye(4), (2, 1, 1))
    P[0, :3, 3] = (0.40, 0.0, 0.03)
    P[1, :3, 3] = (0.40, 0.15, 0.03)
    mv = MovingTask.to_positions({0: (0.30, 0.0, 0.03), 1: (0.40, 0.10, 0.03)})
    assert task_metric(mv, P) == pytest.approx((0.10 + 0.05) / 2)
    assert task_metric(SingulationTask(0.2), P) == pytest.approx(0.15)


def _sq(x: float, y: float) -> Superquadric:
    T = np.eye(4)
    T[:3, 3] = (x, y, 0.03)
    return Superquadric((0.02, 0.02, 0.03), (0.2, 0.2), T)


def test_tracker_matches_nearest_centres_and_follows_predictions():
    tr = ObjectTracker({0: np.array([0.40, 0.0, 0.03]), 1: np.array([0.50, 0.0, 0.03])})
    # recognized in swapped order with the recognizer's own ids, slightly off
    objs, missing = tr.associate([([_sq(0.51, 0.01)], 0), ([_sq(0.41, -0.01)], 1)])
    assert [oid for _, oid in objs] == [1, 0] and missing == []
    # object 0 was pushed 8 cm along +y: matched through the predicted position
    tr.expect({0: np.array([0.41, 0.07, 0.03])})
    objs, missing = tr.associate([([_sq(0.415, 0.075)], 5)])
    assert [oid for _, oid in objs] == [0] and missing == [1]
    # something far from every expectation gets a fresh id
    objs, _ = tr.associate([([_sq(0.30, -0.2)], 0)])
    assert objs[0][1] == FIRST_NEW_ID


def test_tracker_pairs_one_lost_and_one_new_object_by_elimination():
    tr = ObjectTracker({0: np.array([0.40, 0.0, 0.03]), 1: np.array([0.60, 0.2, 0.03])})
    # object 0 went 18 cm instead of the predicted few: beyond the gate, still the same object
    objs, missing = tr.associate([([_sq(0.58, 0.0)], 9), ([_sq(0.60, 0.21)], 8)])
    assert sorted(oid for _, oid in objs) == [0, 1] and missing == []
    # 40 cm away (beyond three gates) is something else
    objs, missing = tr.associate([([_sq(0.18, 0.0)], 9), ([_sq(0.60, 0.21)], 8)])
    assert sorted(oid for _, oid in objs) == [1, FIRST_NEW_ID] and missing == [0]


def test_write_png_round_trips_pixels(tmp_path):
    img = np.zeros((3, 4, 3), np.uint8)
    img[1, 2] = (10, 200, 30)
    path = tmp_path / "x.png"
    write_png(path, img)
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = struct.unpack(">II", data[16:24])
    assert (w, h) == (4, 3)
    i = data.index(b"IDAT")
    n = struct.unpack(">I", data[i - 4 : i])[0]
    raw = zlib.decompress(data[i + 4 : i + 4 + n])
    rows = np.frombuffer(raw, np.uint8).reshape(3, 1 + 4 * 3)
    assert (rows[:, 0] == 0).all()
    assert np.array_equal(rows[:, 1:].reshape(3, 4, 3), img)


def test_planner_default_table_is_the_simulators_table():
    from sqmanip.planning.config import TableSpec
    from sqmanip.planning.scenarios import sim_table

    assert TableSpec() == sim_table()
