"""End-to-end recognition of synthetic tabletop scenes (in-process)."""

from __future__ import annotations

import numpy as np
import pytest
from sqmanip.errors import PreconditionError, ValidationError
from sqmanip.geometry import volume_iou
from sqmanip.perception.pipeline import Recognizer
from sqmanip.perception.synthetic import make_tabletop_scene
from sqmanip.perception.types import RecognizeOptions, RecognizeRequest, Workspace


@pytest.fixture(scope="module")
def scene():
    return make_tabletop_scene(4, seed=0, n_points=20_000, camera_scale=0.35)


@pytest.fixture(scope="module")
def result(scene):
    return Recognizer().recognize(RecognizeRequest(scene.points, viewpoint=scene.viewpoint))


def test_scene_has_one_object_per_ground_truth_object(scene, result):
    assert len(result.objects) == 4
    matched = set()
    for obj in result.objects:
        ids = scene.object_ids[obj.point_indices]
        gt = np.bincount(ids + 1).argmax() - 1
        assert gt >= 0 and (ids == gt).mean() > 0.95  # indices refer to the request cloud
        matched.add(int(gt))
        assert volume_iou(obj.parts, scene.objects[gt], n=10000) > 0.6
        assert 0.0 < obj.confidence <= 1.0 and obj.residual < 1e-4
    assert matched == {0, 1, 2, 3}
    assert result.support_plane is not None
    assert result.support_plane.normal[2] > 0.999 and abs(result.support_plane.offset) < 0.002
    assert set(result.timings_ms) == {"preprocess", "segment", "fit", "total"}


def test_recognition_is_deterministic_for_a_seed(scene, result):
    again = Recognizer().recognize(RecognizeRequest(scene.points, viewpoint=scene.viewpoint))
    for a, b in zip(result.objects, again.objects, strict=True):
        assert np.array_equal(a.point_indices, b.point_indices)
        assert np.allclose(a.parts[0].params(), b.parts[0].params())
        assert np.allclose(a.parts[0].pose, b.parts[0].pose)


def test_labels_colors_and_workspace_crop_map_back_to_the_request(scene):
    colors = np.tile(np.array([[0.2, 0.4, 0.6]], dtype=np.float32), (len(scene.points), 1))
    ws = Workspace((-0.5, -0.5, -0.1), (0.5, 0.5, 0.5))
    req = RecognizeRequest(
        scene.points,
        colors=colors,
        labels=scene.object_ids,
        viewpoint=scene.viewpoint,
        workspace=ws,
        options=RecognizeOptions(method="mvbb"),
    )
    out = Recognizer().recognize(req)
    assert len(out.objects) == 4
    for obj in out.objects:
        assert len(np.unique(scene.object_ids[obj.point_indices])) == 1
        assert np.allclose(obj.mean_color, (0.2, 0.4, 0.6))
        assert obj.parts[0].shape == (0.2, 0.2)


def test_network_methods_without_a_checkpoint_fail_clearly_and_bad_input_is_rejected(
    scene, tmp_path
):
    from sqmanip.perception.config import PerceptionSettings

    settings = PerceptionSettings(network_model_dir=tmp_path / "missing_model")
    for method in ("network", "hybrid"):
        with pytest.raises(PreconditionError, match="missing_model"):
            Recognizer(settings).recognize(
                RecognizeRequest(scene.points, options=RecognizeOptions(method=method))
            )
    with pytest.raises(ValidationError, match="points"):
        Recognizer().recognize(RecognizeRequest(np.full((3, 3), np.nan)))


def test_a_part_resting_on_another_segment_joins_its_object():
    """A bottle-like stack (wide body on the table, narrow neck on top, split at the concave
    shoulder) is one object with two parts; a separate box on the table stays its own object."""
    from sqmanip.geometry import Superquadric, sample_parts

    def at(x, y, z):
        pose = np.eye(4)
        pose[:3, 3] = (x, y, z)
        return pose

    body = Superquadric((0.035, 0.035, 0.06), (0.2, 1.0), at(0.0, 0.0, 0.06))
    neck = Superquadric((0.012, 0.012, 0.03), (0.2, 1.0), at(0.0, 0.0, 0.15))
    box = Superquadric((0.03, 0.03, 0.04), (0.2, 0.2), at(0.2, 0.0, 0.04))
    eye = np.array([0.6, 0.0, 0.6])
    pts, nrm, _ = sample_parts([body, neck, box], 6000, generator=0)
    pts, nrm = np.asarray(pts), np.asarray(nrm)
    inside_other = np.zeros(len(pts), dtype=bool)
    for part in (body, neck):  # drop the body's cap under the neck and the neck's bottom
        local = pts - part.pose[:3, 3]
        a1, _, a3 = part.size
        inside_other |= (np.hypot(local[:, 0], local[:, 1]) < a1 - 1e-3) & (
            abs(local[:, 2]) < a3 - 1e-3
        )
    seen = ((eye - pts) * nrm).sum(-1) > 0
    xy = np.random.default_rng(0).uniform(-0.3, 0.4, size=(4000, 2))
    table = np.column_stack([xy, np.zeros(len(xy))])
    cloud = np.concatenate([pts[seen & ~inside_other], table]).astype(np.float32)
    scene = Recognizer().recognize(RecognizeRequest(cloud, viewpoint=eye))
    by_parts = sorted(len(o.parts) for o in scene.objects)
    assert by_parts == [1, 2], [(len(o.parts), len(o.point_indices)) for o in scene.objects]


def test_color_segmentation_separates_flush_boxes_that_clustering_merges():
    """Two boxes of equal height pushed together, red and blue: one object by geometry alone
    (their tops are one plane, no concave seam), two with segmentation='color'."""
    from sqmanip.geometry import Superquadric, sample_parts

    def at(x):
        pose = np.eye(4)
        pose[:3, 3] = (x, 0.0, 0.04)
        return pose

    boxes = [Superquadric((0.04, 0.03, 0.04), (0.1, 0.1), at(x)) for x in (-0.04, 0.04)]
    eye = np.array([0.0, -0.5, 0.6])
    pts, nrm, part = sample_parts(boxes, 8000, generator=0)
    pts, nrm, part = np.asarray(pts), np.asarray(nrm), np.asarray(part)
    seen = (((eye - pts) * nrm).sum(-1) > 0) & (np.abs(pts[:, 0]) > 0.001)  # no inner faces
    xy = np.random.default_rng(0).uniform(-0.3, 0.3, size=(4000, 2))
    table = np.column_stack([xy, np.zeros(len(xy))])
    table = table[(np.abs(table[:, 0]) > 0.08) | (np.abs(table[:, 1]) > 0.03)]
    cloud = np.concatenate([pts[seen], table]).astype(np.float32)
    red, blue = np.array([0.8, 0.1, 0.1]), np.array([0.15, 0.3, 0.7])
    shade = np.where(nrm[seen][:, 2] > 0.5, 1.0, 0.6)[:, None]  # lit tops, darker sides
    colors = np.concatenate(
        [shade * np.where((part[seen] == 0)[:, None], red, blue), np.full((len(table), 3), 0.6)]
    ).astype(np.float32)
    counts = {}
    for seg in ("clustering", "color"):
        opts = RecognizeOptions(segmentation=seg)
        req = RecognizeRequest(cloud, colors=colors, viewpoint=eye, options=opts)
        counts[seg] = len(Recognizer().recognize(req).objects)
    assert counts == {"clustering": 1, "color": 2}
