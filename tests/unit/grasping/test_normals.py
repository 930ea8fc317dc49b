"""Closed-form normals of deformed shapes (2.3.21) agree with finite differences of the implicit.

The antipodal test (3.4.7) is only as good as these normals, so the planner's two sources are
checked: sample normals (``sample_parts``) and normals at ray hits (``part_normals``).
"""

import numpy as np
import pytest
import torch
from grasp_helpers import pose
from sqmanip.geometry import Superquadric, pack, sample_parts, world_implicit
from sqmanip.grasping.antipodal import part_normals

DEFORMED = [
    Superquadric((0.03, 0.04, 0.06), (0.6, 0.8), pose(0.1, -0.2, 0.3, (0.3, -0.2, 0.5)), taper=0.4),
    Superquadric((0.02, 0.02, 0.08), (0.7, 1.0), pose(0, 0, 0, (1.2, 0.1, 0.0)), bend=4.0),
    Superquadric(
        (0.03, 0.025, 0.07),
        (0.5, 0.9),
        pose(0.2, 0.1, 0.0, (0.0, 0.4, -0.7)),
        taper=-0.3,
        bend=3.0,
        bend_direction=0.8,
    ),
    Superquadric(
        (0.01, 0.01, 0.01), (0.8, 0.9), pose(0, 0, 0.1, (0.5, 0, 0)), kind="supertoroid", a4=3.0
    ),
]


def fd_normals(points: torch.Tensor, part: Superquadric, h: float = 1e-6) -> torch.Tensor:
    packed = pack([part], dtype=torch.float64)
    grads = []
    for axis in range(3):
        d = torch.zeros(3, dtype=torch.float64)
        d[axis] = h
        fp = world_implicit(points + d, packed.params, packed.poses, packed.kinds)[0]
        fm = world_implicit(points - d, packed.params, packed.poses, packed.kinds)[0]
        grads.append((fp - fm) / (2 * h))
    g = torch.stack(grads, -1)
    return g / g.norm(dim=-1, keepdim=True)


@pytest.mark.parametrize("part", DEFORMED, ids=["tapered", "bent", "tapered+bent", "toroid"])
def test_closed_form_normals_match_finite_differences(part):
    pts, nrm, _ = sample_parts([part], 200, generator=3)
    pts = torch.as_tensor(pts)
    ref = fd_normals(pts, part)
    cos = (torch.as_tensor(nrm) * ref).sum(-1)
    assert (cos > 0.9999).all(), float(cos.min())
    packed = pack([part], dtype=torch.float64)
    mine = part_normals(pts.unsqueeze(0), packed.params, packed.poses, packed.kinds)[0]
    assert ((mine * ref).sum(-1) > 0.9999).all()


def test_part_normals_evaluates_each_part_at_its_own_points():
    a, b = DEFORMED[0], DEFORMED[1]
    pa, _, _ = sample_parts([a], 30, generator=0)
    pb, _, _ = sample_parts([b], 30, generator=0)
    packed = pack([a, b], dtype=torch.float64)
    pts = torch.as_tensor(np.stack([pa, pb]))
    n = part_normals(pts, packed.params, packed.poses, packed.kinds)
    assert ((n[0] * fd_normals(pts[0], a)).sum(-1) > 0.9999).all()
    assert ((n[1] * fd_normals(pts[1], b)).sum(-1) > 0.9999).all()
