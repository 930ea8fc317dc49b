"""Domain <-> proto conversion: round trips and size checks that name the field."""

import numpy as np
import pytest
from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric
from sqmanip.perception.types import (
    RecognizedObject,
    RecognizeOptions,
    RecognizeRequest,
    Scene,
    SupportPlane,
    Workspace,
)
from sqmanip.rpc import convert
from sqmanip.v1 import common_pb2, perception_pb2


def _pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = q, rng.normal(size=3)
    return T


def test_cloud_round_trip_keeps_points_labels_and_colors_to_one_step() -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(1000, 3)).astype(np.float32)
    colors = rng.uniform(size=(1000, 3)).astype(np.float32)
    labels = rng.integers(-1, 5, size=1000)
    msg = convert.cloud_to_proto(pts, colors, labels)
    assert msg.num_points == 1000 and len(msg.xyz) == 12_000 and len(msg.rgb) == 3000
    p2, c2, l2 = convert.cloud_from_proto(common_pb2.PointCloud.FromString(msg.SerializeToString()))
    np.testing.assert_array_equal(p2, pts)
    np.testing.assert_array_equal(l2, labels)
    assert np.abs(c2 - colors).max() <= 0.5 / 255 + 1e-6


def test_cloud_without_optional_planes_gives_none() -> None:
    pts, colors, labels = convert.cloud_from_proto(convert.cloud_to_proto(np.zeros((4, 3))))
    assert pts.shape == (4, 3) and pts.dtype == np.float32 and colors is None and labels is None


@pytest.mark.parametrize(
    ("field", "kwargs", "needle"),
    [
        (
            "xyz",
            {"num_points": 3, "xyz": b"\0" * 35},
            "cloud.xyz: expected num_points x 3 float32 = 36 bytes, got 35",
        ),
        ("rgb", {"num_points": 1, "xyz": b"\0" * 12, "rgb": b"\0" * 4}, "cloud.rgb"),
        ("labels", {"num_points": 2, "xyz": b"\0" * 24, "labels": b"\0" * 4}, "cloud.labels"),
    ],
)
def test_packed_plane_size_mismatch_names_the_plane(field, kwargs, needle) -> None:
    with pytest.raises(ValidationError, match=needle.replace("(", r"\(").replace(")", r"\)")):
        convert.cloud_from_proto(common_pb2.PointCloud(**kwargs))


def test_wrong_shapes_and_lengths_are_rejected_with_the_field_named() -> None:
    with pytest.raises(ValidationError, match=r"points: expected shape \(N, 3\), got \(5, 2\)"):
        convert.cloud_to_proto(np.zeros((5, 2)))
    with pytest.raises(ValidationError, match=r"labels: expected shape \(5,\)"):
        convert.cloud_to_proto(np.zeros((5, 3)), labels=np.zeros(4, dtype=int))
    with pytest.raises(ValidationError, match=r"colors: expected shape \(5, 3\)"):
        convert.cloud_to_proto(np.zeros((5, 3)), colors=np.zeros((6, 3)))
    with pytest.raises(ValidationError, match="colors: expected finite floats in"):
        convert.cloud_to_proto(np.zeros((1, 3)), colors=[[0.0, 2.0, 0.0]])
    with pytest.raises(ValidationError, match="points: expected numbers"):
        convert.cloud_to_proto([[1, 2, 3], [1, 2]])


def test_empty_cloud_is_packed_as_zero_points_for_the_domain_to_reject() -> None:
    assert convert.cloud_to_proto([]).num_points == 0


def test_superquadric_round_trip_all_fields() -> None:
    sq = Superquadric(
        size=(0.03, 0.04, 0.05), shape=(0.3, 1.2), pose=_pose(1), kind="supertoroid",
        taper=-0.4, bend=2.0, bend_direction=0.7, a4=0.02,
    )  # fmt: skip
    back = convert.superquadric_from_proto(convert.superquadric_to_proto(sq))
    assert back.kind == sq.kind and back.size == pytest.approx(sq.size)
    assert back.shape == pytest.approx(sq.shape) and back.a4 == pytest.approx(0.02)
    assert (back.taper, back.bend, back.bend_direction) == pytest.approx((-0.4, 2.0, 0.7))
    np.testing.assert_allclose(back.pose, sq.pose, atol=1e-9)


def test_pose_quaternion_is_xyzw() -> None:
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # +90 deg about z
    q = convert.pose_to_proto(T).orientation
    assert (q.x, q.y) == pytest.approx((0, 0)) and q.z == pytest.approx(q.w) == pytest.approx(
        2**-0.5
    )


def test_scene_round_trip() -> None:
    sq = Superquadric(size=(0.1, 0.2, 0.3), shape=(0.5, 0.5), pose=_pose(2))
    scene = Scene(
        objects=[
            RecognizedObject(0, [sq], np.array([3, 1, 2]), (0.1, 0.2, 0.3), 1e-5, 0.9),
            RecognizedObject(7, [sq, sq], np.array([], dtype=int), None, 2e-5, 0.5),
        ],
        support_plane=SupportPlane((0.0, 0.0, 1.0), -0.01),
        timings_ms={"fit": 12.5, "total": 20.0},
    )
    msg = perception_pb2.RecognizeResponse(scene=convert.scene_to_proto(scene))
    back = convert.scene_from_proto(
        perception_pb2.RecognizeResponse.FromString(msg.SerializeToString()).scene
    )
    assert [o.id for o in back.objects] == [0, 7]
    np.testing.assert_array_equal(back.objects[0].point_indices, [3, 1, 2])
    assert back.objects[0].mean_color == pytest.approx((0.1, 0.2, 0.3))
    assert back.objects[1].mean_color is None and len(back.objects[1].parts) == 2
    assert back.support_plane == SupportPlane((0.0, 0.0, 1.0), -0.01)
    assert back.timings_ms == {"fit": 12.5, "total": 20.0}
    assert convert.scene_from_proto(convert.scene_to_proto(Scene([]))).support_plane is None


def test_request_round_trip_and_option_defaults() -> None:
    req = RecognizeRequest(
        points=np.ones((10, 3), np.float32),
        labels=np.arange(10) % 3 - 1,
        viewpoint=np.array([0.5, 0.0, 1.0]),
        workspace=Workspace((-1, -1, 0), (1, 1, 1)),
        options=RecognizeOptions(points_per_segment=200, amodal=False, seed=4),
    )
    back = convert.recognize_request_from_proto(convert.recognize_request_to_proto(req))
    np.testing.assert_array_equal(back.labels, req.labels)
    np.testing.assert_allclose(back.viewpoint, [0.5, 0.0, 1.0])
    assert back.workspace == Workspace((-1.0, -1.0, 0.0), (1.0, 1.0, 1.0))
    assert back.options == req.options
    empty = perception_pb2.RecognizeRequest(cloud=convert.cloud_to_proto(np.ones((2, 3))))
    assert convert.recognize_request_from_proto(empty).options == RecognizeOptions()
    empty.cloud.labels = np.zeros(2, "<i4").tobytes()
    assert convert.recognize_request_from_proto(empty).options.segmentation == "labels"
