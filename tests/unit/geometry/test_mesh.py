"""Superquadric meshes: watertight, outward, vertices on the surface, right volume."""

import numpy as np
import pytest
import torch
import trimesh
from sqmanip.geometry import Superquadric
from sqmanip.geometry.mesh import superquadric_mesh, superquadric_trimesh, surface_area, union_mesh
from sqmanip.geometry.superquadric import implicit, normal

SHAPES = [
    (0, [0.1, 0.2, 0.3, 0.2, 0.2, 0.0, 0.0, 0.0, 0.0]),
    (0, [0.1, 0.2, 0.3, 1.7, 1.7, 0.0, 0.0, 0.0, 0.0]),
    (0, [0.1, 0.2, 0.3, 1.0, 0.5, 0.9, 2.0, 1.0, 0.0]),
    (1, [0.1, 0.1, 0.2, 0.2, 0.2, 0.0, 0.0, 0.0, 0.0]),
    (1, [0.1, 0.1, 0.2, 1.7, 1.0, -0.5, 1.0, 0.0, 0.0]),
    (2, [0.05, 0.05, 0.05, 1.0, 1.0, 0.0, 0.0, 0.0, 2.0]),
    (2, [0.05, 0.05, 0.05, 0.3, 0.2, 0.2, 1.0, 0.0, 2.0]),
]


@pytest.mark.parametrize(("kind", "p"), SHAPES)
def test_mesh_is_watertight_outward_and_on_surface(kind, p):
    V, F = superquadric_mesh(p, kind, resolution=12)
    m = trimesh.Trimesh(V, F, process=False)
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume > 0  # outward orientation
    assert m.area_faces.min() > 1e-10  # no degenerate (pole) triangles
    f = implicit(torch.tensor(V), torch.tensor(p, dtype=torch.float64), kind)
    assert torch.allclose(f, torch.ones_like(f), atol=1e-5)
    # every face normal agrees with the analytic outward normal (2.3.21) at its corners
    vn = normal(torch.tensor(V), torch.tensor(p, dtype=torch.float64), kind).numpy()
    agree = (m.face_normals * vn[F].mean(1)).sum(-1)
    assert (agree > 0).mean() > 0.99


def test_volumes_and_areas_converge_to_closed_forms():
    V, F = superquadric_mesh([0.1, 0.1, 0.1, 1, 1, 0, 0, 0, 0], 0, resolution=32)
    vol = trimesh.Trimesh(V, F, process=False).volume
    assert abs(vol - 4 / 3 * np.pi * 1e-3) / (4 / 3 * np.pi * 1e-3) < 0.01
    area = float(surface_area(torch.tensor([0.1, 0.1, 0.1, 1, 1, 0, 0, 0, 0.0]), 0))
    assert abs(area - 4 * np.pi * 0.01) / (4 * np.pi * 0.01) < 0.01
    V, F = superquadric_mesh([0.05, 0.05, 0.05, 1, 1, 0, 0, 0, 2.0], 2, resolution=32)
    torus = 2 * np.pi * 0.1 * np.pi * 0.05**2
    assert abs(trimesh.Trimesh(V, F, process=False).volume - torus) / torus < 0.01


def test_superellipsoid_counts_and_trimesh_pose():
    V, F = superquadric_mesh([0.1, 0.1, 0.1, 1, 1, 0, 0, 0, 0], 0, resolution=8)
    assert V.shape == (6 * 64 + 2, 3) and F.shape == (12 * 64, 3)
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 3.0]
    m = superquadric_trimesh(Superquadric((0.1, 0.1, 0.1), (1.0, 1.0), pose=pose), 8)
    assert np.allclose(m.vertices.mean(0), [1, 2, 3], atol=1e-9)


def test_union_mesh_concatenates_parts():
    parts = [Superquadric((0.1, 0.1, 0.1), (1.0, 1.0)), Superquadric((0.1, 0.2, 0.1), (0.3, 0.3))]
    m = union_mesh(parts, resolution=8)
    assert len(m.faces) == 2 * 12 * 64 and m.is_watertight
    assert len(union_mesh([]).faces) == 0


def test_bad_input_raises():
    with pytest.raises(ValueError, match="params"):
        superquadric_mesh([1.0, 2.0], 0)
    with pytest.raises(ValueError, match="kind"):
        superquadric_mesh([0.1] * 9, 5)
    with pytest.raises(ValueError, match="resolution"):
        superquadric_mesh([0.1] * 9, 0, resolution=1)
