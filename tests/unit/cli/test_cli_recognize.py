"""``sqmanip recognize`` end to end against a real gateway + Perception server (loopback, in
this process), and the error path: one ``error:`` line, exit code 1, no traceback."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import sqmanip_client as sdk
from sqmanip.cli import main
from sqmanip.cli.common import load_scene_json
from sqmanip.io.clouds import write_cloud
from sqmanip.launch import free_port
from sqmanip.perception.synthetic import make_tabletop_scene


@pytest.fixture(scope="module")
def scene():
    return make_tabletop_scene(2, 12)


@pytest.fixture
def ply_file(tmp_path, scene):
    path = tmp_path / "cloud.ply"
    colors = np.where(scene.object_ids[:, None] >= 0, [0.8, 0.2, 0.1], [0.5, 0.5, 0.5])
    write_cloud(path, scene.points, colors, viewpoint=scene.viewpoint)  # as sim observe does
    return path


def test_recognize_prints_table_and_writes_json_and_obj(
    gateway_url, scene, ply_file, tmp_path, capsys
) -> None:
    obj, js = tmp_path / "shapes.obj", tmp_path / "shapes.json"
    argv = [
        "recognize",
        str(ply_file),
        "--gateway",
        gateway_url,
        "--out",
        str(obj),
        "--out",
        str(js),
        "--resolution",
        "8",
        "--view",
    ]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"2 object(s) from {len(scene.points)} points; support plane")
    assert "superellipsoid" in out and f"wrote {obj}" in out and f"wrote {js}" in out
    assert "viewer: http://127.0.0.1:" in out
    # the JSON reads back as the SDK's Scene; objects sit where the ground truth is
    shapes = load_scene_json(js)
    assert len(shapes.objects) == 2
    truth = np.array([o[0].pose[:3, 3] for o in scene.objects])
    for o in shapes.objects:
        centre = np.asarray(o.parts[0].pose.position)
        assert np.min(np.linalg.norm(truth[:, :2] - centre[:2], axis=1)) < 0.03
        assert o.mean_color == pytest.approx((0.8, 0.2, 0.1), abs=0.01)  # colors were sent
    lines = obj.read_text().splitlines()
    n_parts = sum(len(o.parts) for o in shapes.objects)
    assert sum(ln.startswith("o ") for ln in lines) == 2
    assert sum(ln.startswith("g ") for ln in lines) == n_parts


def test_recognize_json_output_is_the_scene_only(gateway_url, scene, tmp_path, capsys) -> None:
    npy = tmp_path / "cloud.npy"
    np.save(npy, scene.points)
    assert main(["recognize", str(npy), "--gateway", gateway_url, "--method", "mvbb",
                 "--json"]) == 0  # fmt: skip
    data = json.loads(capsys.readouterr().out)
    parsed = sdk.types.scene_from_json(data)
    assert len(parsed.objects) == 2 and parsed.objects[0].mean_color is None


def test_http_error_from_gateway_is_one_line(gateway_url, tmp_path, capsys) -> None:
    # this gateway has no grasp backend: /grasps answers 503 with a reason
    js = tmp_path / "s.json"
    js.write_text(json.dumps({"objects": [], "support_plane": None}))
    assert main(["grasp", "--scene-json", str(js), "--gateway", gateway_url]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: HTTP "), err


def test_unreachable_gateway_exits_1_with_one_error_line(tmp_path, scene) -> None:
    npy = tmp_path / "c.npy"
    np.save(npy, scene.points[:100])
    url = f"http://127.0.0.1:{free_port()}"
    res = subprocess.run(
        [sys.executable, "-m", "sqmanip.cli", "recognize", str(npy), "--gateway", url],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: cannot reach {url}"), res.stderr
    assert "Traceback" not in res.stderr and res.stdout == ""


def test_gateway_url_from_environment_and_debug_shows_the_exception(
    tmp_path, scene, monkeypatch, capsys
) -> None:
    npy = tmp_path / "c.npy"
    np.save(npy, scene.points[:100])
    url = f"http://127.0.0.1:{free_port()}"
    monkeypatch.setenv("SQMANIP_GATEWAY_URL", url)
    assert main(["recognize", str(npy), "--timeout", "5"]) == 1
    assert f"error: cannot reach {url}" in capsys.readouterr().err
    with pytest.raises(sdk.ConnectionError):
        main(["recognize", str(npy), "--debug"])


def test_bad_values_are_usage_errors(tmp_path, scene, capsys) -> None:
    npy = tmp_path / "c.npy"
    np.save(npy, scene.points[:100])
    assert main(["recognize", str(npy), "--viewpoint", "1,2"]) == 2
    assert main(["recognize", str(npy), "--out", str(tmp_path / "x.stl")]) == 2
    assert main(["predict", "--sim", "--push", "1,2,3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "error: --viewpoint: expected 3 comma-separated numbers, got 2",
        f"error: --out {tmp_path / 'x.stl'}: expected a .json, .obj or .ply file name",
        "error: --push: expected 6 comma-separated numbers, got 3",
    ]
