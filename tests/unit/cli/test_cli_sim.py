"""``sqmanip sim observe --out frame.ply``: the colored cloud, without the robot's own points,
with the camera position recorded as the viewpoint (a fake simulator client, no PyBullet)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from sqmanip.cli import main
from sqmanip.io.clouds import read_cloud


@dataclasses.dataclass
class _Intrinsics:
    def matrix(self):
        return np.eye(3)


@dataclasses.dataclass
class _Obs:
    camera: str = "default"
    time: float = 0.5
    depth: np.ndarray = dataclasses.field(default_factory=lambda: np.ones((2, 3), np.float32))
    rgb: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((2, 3, 3), np.uint8))
    segmentation: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((2, 3)))
    points: np.ndarray = dataclasses.field(
        default_factory=lambda: np.array([[0.4, 0.0, 0.05], [0.5, 0.1, 0.3], [0.3, 0.0, 0.0]])
    )
    point_labels: np.ndarray = dataclasses.field(default_factory=lambda: np.array([0, -3, -2]))
    point_pixels: np.ndarray = dataclasses.field(default_factory=lambda: np.array([4, 0, 1]))
    camera_pose: np.ndarray = dataclasses.field(
        default_factory=lambda: np.array(
            [[1, 0, 0, 0.6], [0, 1, 0, -0.3], [0, 0, 1, 0.9], [0, 0, 0, 1.0]]
        )  # fmt: skip
    )
    intrinsics: _Intrinsics = dataclasses.field(default_factory=_Intrinsics)
    objects: tuple = ()


class _FakeSim:
    def __init__(self) -> None:
        self.obs = _Obs()
        self.obs.rgb[1, 1] = (255, 0, 0)  # pixel 4 = the object's point

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass

    def observe(self, camera, intrinsics=None, noise=True):
        return self.obs


@pytest.fixture
def fake_sim(monkeypatch):
    import sqmanip.sim.cli as sim_cli

    monkeypatch.setattr(sim_cli, "_remote", lambda args: _FakeSim())


def test_observe_writes_a_colored_ply_without_robot_points(fake_sim, tmp_path, capsys) -> None:
    out = tmp_path / "frame.ply"
    assert main(["sim", "observe", "--out", str(out)]) == 0
    assert f"point cloud written to {out}" in capsys.readouterr().out
    cloud = read_cloud(out)
    np.testing.assert_allclose(cloud.points, [[0.4, 0.0, 0.05], [0.3, 0.0, 0.0]], atol=1e-6)
    np.testing.assert_allclose(cloud.colors[0], (1.0, 0.0, 0.0))
    np.testing.assert_allclose(cloud.viewpoint, (0.6, -0.3, 0.9))
    assert main(["sim", "observe", "--out", str(out), "--keep-robot"]) == 0
    assert len(read_cloud(out).points) == 3


def test_observe_rejects_an_unknown_output_suffix(fake_sim, tmp_path, capsys) -> None:
    assert main(["sim", "observe", "--out", str(tmp_path / "frame.stl")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: sim observe: --out")
