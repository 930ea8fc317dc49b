"""PLY parsing (ascii and binary little-endian, with and without colors) and its errors."""

import numpy as np
import pytest
from sqmanip.errors import ValidationError
from sqmanip.gateway.ply import parse_ply, to_ply


@pytest.mark.parametrize("binary", [True, False])
@pytest.mark.parametrize("with_colors", [True, False])
def test_round_trip(binary: bool, with_colors: bool) -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3)).astype(np.float32)
    colors = rng.uniform(size=(50, 3)) if with_colors else None
    cloud = parse_ply(to_ply(pts, colors, binary=binary))
    np.testing.assert_allclose(cloud.points, pts, rtol=1e-6)
    if with_colors:
        assert cloud.colors.shape == (50, 3)
        assert np.abs(cloud.colors - colors).max() <= 0.5 / 255 + 1e-6
    else:
        assert cloud.colors is None


def test_extra_properties_and_comments_are_skipped() -> None:
    text = (
        "ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 2\n"
        "property double x\nproperty double y\nproperty double z\nproperty float intensity\n"
        "element face 0\nproperty list uchar int vertex_indices\nend_header\n"
        "1 2 3 0.5\n4 5 6 0.25\n"
    )
    with pytest.raises(
        ValidationError, match="list properties are not supported in element 'face'"
    ):
        parse_ply(text.encode())
    text = text.replace("element face 0\nproperty list uchar int vertex_indices\n", "")
    cloud = parse_ply(text.encode())
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])


def test_binary_uchar_colors_are_scaled_to_unit_range() -> None:
    pts = np.zeros((1, 3), np.float32)
    cloud = parse_ply(to_ply(pts, np.array([[1.0, 0.0, 0.5]])))
    np.testing.assert_allclose(cloud.colors, [[1.0, 0.0, 128 / 255]], atol=1e-6)


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        (b"solid cube\n", "must start with 'ply'"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "no 'end_header'"),
        (
            b"ply\nformat binary_big_endian 1.0\nelement vertex 0\nend_header\n",
            "binary_little_endian",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n",
            "no 'z' property",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n",
            "expected 2 vertex lines",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 abc\n",
            "3 numbers",
        ),
        (
            b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
            + b"\0" * 20,
            "need 36 bytes",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quaternion x\nend_header\n",
            "bad property line",
        ),
    ],
)
def test_malformed_files_are_rejected_with_a_reason(data: bytes, needle: str) -> None:
    with pytest.raises(ValidationError, match=needle):
        parse_ply(data)


def test_vertex_count_over_limit_is_rejected_before_parsing() -> None:
    data = b"ply\nformat binary_little_endian 1.0\nelement vertex 999999999\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    with pytest.raises(ValidationError, match="points: expected at most 1000 points"):
        parse_ply(data, max_points=1000)
