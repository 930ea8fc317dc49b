"""Clouds in (PLY ascii/binary, NPY, NPZ) and meshes out (OBJ, PLY) for ``sqmanip recognize``."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric
from sqmanip.io.clouds import read_cloud, write_cloud
from sqmanip.io.meshes import object_meshes, write_meshes
from sqmanip.io.ply import parse_ply, to_ply


@pytest.fixture
def cloud():
    rng = np.random.default_rng(0)
    return rng.uniform(-1, 1, (50, 3)).astype(np.float32), rng.uniform(0, 1, (50, 3))


@pytest.mark.parametrize("binary", [False, True], ids=["ascii", "binary"])
@pytest.mark.parametrize("with_colors", [False, True], ids=["xyz", "xyzrgb"])
def test_ply_file_round_trip(tmp_path, cloud, binary, with_colors) -> None:
    pts, cols = cloud
    path = tmp_path / "c.ply"
    path.write_bytes(to_ply(pts, cols if with_colors else None, binary=binary))
    got = read_cloud(path)
    np.testing.assert_allclose(got.points, pts, atol=1e-6)
    if with_colors:
        np.testing.assert_allclose(got.colors, cols, atol=1 / 255)
    else:
        assert got.colors is None


def test_npy_xyz_and_xyzrgb_with_0_255_colors(tmp_path, cloud) -> None:
    pts, cols = cloud
    np.save(tmp_path / "a.npy", pts.astype(np.float64))
    got = read_cloud(tmp_path / "a.npy")
    assert got.points.dtype == np.float32 and got.colors is None
    np.testing.assert_allclose(got.points, pts)
    np.save(tmp_path / "b.npy", np.hstack([pts, np.rint(cols * 255)]))
    got = read_cloud(tmp_path / "b.npy")
    np.testing.assert_allclose(got.colors, cols, atol=1 / 255)
    write_cloud(tmp_path / "c.npy", pts, cols)
    np.testing.assert_allclose(read_cloud(tmp_path / "c.npy").colors, cols, atol=1e-6)


def test_npz_of_sim_observe_takes_colors_from_rgb_pixels_and_viewpoint_from_camera(
    tmp_path,
) -> None:
    rgb = np.zeros((2, 3, 3), np.uint8)
    rgb[1, 2] = (255, 0, 51)
    pts = np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]], np.float32)
    cam = np.eye(4)
    cam[:3, 3] = (0.5, -0.2, 0.9)
    np.savez(tmp_path / "f.npz", points=pts, rgb=rgb, point_pixels=np.array([5, 0], np.int32),
             camera_pose=cam)  # fmt: skip
    got = read_cloud(tmp_path / "f.npz")
    np.testing.assert_allclose(got.colors, [[1.0, 0.0, 0.2], [0.0, 0.0, 0.0]], atol=1e-6)
    np.testing.assert_allclose(got.viewpoint, (0.5, -0.2, 0.9))


def test_ply_records_the_viewpoint_in_a_header_comment(tmp_path, cloud) -> None:
    pts, cols = cloud
    write_cloud(tmp_path / "v.ply", pts, cols, viewpoint=(0.25, -1.5, 0.8))
    assert b"comment viewpoint 0.25 -1.5 0.8\n" in (tmp_path / "v.ply").read_bytes()[:300]
    got = read_cloud(tmp_path / "v.ply")
    np.testing.assert_allclose(got.viewpoint, (0.25, -1.5, 0.8))
    np.testing.assert_allclose(got.points, pts)
    write_cloud(tmp_path / "n.ply", pts)
    assert read_cloud(tmp_path / "n.ply").viewpoint is None


@pytest.mark.parametrize(
    ("name", "content", "needle"),
    [
        ("a.npy", np.zeros((4, 2)), r"shape \(N, 3\) or \(N, 6\), got \(4, 2\)"),
        ("b.npy", np.array([[0, 0, np.nan]] * 3), "3 points have non-finite"),
        ("c.npy", np.zeros((0, 3)), "no points"),
        ("d.xyz", None, "unknown point-cloud format '.xyz'"),
        ("e.ply", b"solid cube\n", "e.ply: ply: file must start with 'ply'"),
        ("missing.ply", "absent", "no such file"),
    ],
)
def test_bad_cloud_files_name_the_file_and_the_problem(tmp_path, name, content, needle) -> None:
    path = tmp_path / name
    if isinstance(content, np.ndarray):
        np.save(path, content)
    elif isinstance(content, bytes):
        path.write_bytes(content)
    elif content is None:
        path.write_text("1 2 3\n")
    with pytest.raises(ValidationError, match=needle):
        read_cloud(path)


def _objects():
    box = Superquadric(size=(0.03, 0.02, 0.05), shape=(0.2, 0.2))
    T = np.eye(4)
    T[:3, 3] = (0.4, 0.1, 0.05)
    ball = Superquadric(size=(0.04, 0.04, 0.04), shape=(1.0, 1.0), pose=T)
    handle = Superquadric(size=(0.01, 0.01, 0.03), shape=(1.0, 1.0), pose=T)
    return [(3, [box]), (7, [ball, handle])]


RES = 6
PART_VERTS = 6 * RES**2 + 2  # superellipsoid mesh: 6 R^2 + 2 vertices, 12 R^2 faces
PART_FACES = 12 * RES**2


def test_obj_has_one_object_per_recognized_object_and_a_group_per_part(tmp_path) -> None:
    [path] = write_meshes(tmp_path / "s.obj", object_meshes(_objects(), RES))
    text = path.read_text().splitlines()
    assert [ln for ln in text if ln.startswith("o ")] == ["o object_3", "o object_7"]
    groups = [ln for ln in text if ln.startswith("g ")]
    assert groups == ["g object_3_part_0", "g object_7_part_0", "g object_7_part_1"]
    assert sum(ln.startswith("v ") for ln in text) == 3 * PART_VERTS
    assert sum(ln.startswith("f ") for ln in text) == 3 * PART_FACES
    mesh = trimesh.load(path, force="mesh", process=False)  # global 1-based indices resolve
    assert len(mesh.vertices) == 3 * PART_VERTS and len(mesh.faces) == 3 * PART_FACES
    # the posed ball (object 7, part 0) is centred where its pose puts it
    start = text.index("g object_7_part_0") + 1
    ball = np.array([ln.split()[1:] for ln in text[start : start + PART_VERTS]], dtype=float)
    np.testing.assert_allclose(ball.mean(0), (0.4, 0.1, 0.05), atol=1e-3)
    np.testing.assert_allclose(np.ptp(ball, axis=0), 0.08, atol=1e-6)


def test_ply_mesh_parses_back_with_faces_and_per_object_colors(tmp_path) -> None:
    [path] = write_meshes(tmp_path / "s.ply", object_meshes(_objects(), RES))
    mesh = trimesh.load(path, process=False)
    assert len(mesh.vertices) == 3 * PART_VERTS and len(mesh.faces) == 3 * PART_FACES
    # the first part (a box with half sizes 3 x 2 x 5 cm at the origin) is watertight on its own
    part = trimesh.Trimesh(mesh.vertices[:PART_VERTS], mesh.faces[:PART_FACES], process=False)
    assert part.is_watertight and part.volume > 0
    np.testing.assert_allclose(part.bounds, [[-0.03, -0.02, -0.05], [0.03, 0.02, 0.05]], atol=1e-6)
    colors = mesh.visual.vertex_colors[:, :3]
    assert len(np.unique(colors[:PART_VERTS], axis=0)) == 1
    assert not np.array_equal(colors[0], colors[PART_VERTS])  # objects differ in color
    # our own cloud reader takes a mesh PLY's vertices as the cloud (faces ignored)
    np.testing.assert_allclose(read_cloud(path).points, mesh.vertices, atol=1e-6)
    with pytest.raises(ValidationError, match="list properties are not supported"):
        parse_ply(path.read_bytes())  # the gateway's uploads still expect a cloud


@pytest.mark.parametrize("suffix", [".obj", ".ply"])
def test_split_writes_one_file_per_part(tmp_path, suffix) -> None:
    files = write_meshes(tmp_path / f"p{suffix}", object_meshes(_objects(), RES), split=True)
    assert [f.name for f in files] == [f"p_3_0{suffix}", f"p_7_0{suffix}", f"p_7_1{suffix}"]
    for f in files:
        m = trimesh.load(f, force="mesh", process=False)
        assert len(m.vertices) == PART_VERTS and len(m.faces) == PART_FACES


def test_unknown_mesh_suffix_is_rejected(tmp_path) -> None:
    with pytest.raises(ValidationError, match="expected .obj or .ply"):
        write_meshes(tmp_path / "s.stl", object_meshes(_objects(), RES))
