"""Bad requests are rejected with a ValidationError naming the field, the limit and the value."""

from __future__ import annotations

import numpy as np
import pytest
from sqmanip.errors import ValidationError
from sqmanip.perception.config import PerceptionSettings
from sqmanip.perception.types import RecognizeOptions, RecognizeRequest, Workspace
from sqmanip.perception.validate import validate_request

SETTINGS = PerceptionSettings(max_points=500_000)
GOOD = np.zeros((10, 3), dtype=np.float32)


def _check(match: str, **kwargs) -> None:
    req = RecognizeRequest(**{"points": GOOD, **kwargs})
    with pytest.raises(ValidationError, match=match):
        validate_request(req, SETTINGS)


def test_valid_request_converts_arrays():
    out = validate_request(
        RecognizeRequest(GOOD.astype(np.float64), labels=[0] * 10, viewpoint=[0, 0, 1]), SETTINGS
    )
    assert out.points.dtype == np.float32 and out.labels.dtype == np.int64
    assert out.viewpoint.shape == (3,)


@pytest.mark.parametrize(
    ("points", "match"),
    [
        (np.zeros((0, 3)), r"points: expected at least 1 point, got 0"),
        (np.zeros((5, 2)), r"points: expected shape \(N, 3\), got \(5, 2\)"),
        (np.zeros(7), r"points: expected shape \(N, 3\), got \(7,\)"),
        (np.array([[0, 0, np.nan]]), r"points: expected finite values, got nan at index \[0, 2\]"),
        (np.array([[0, np.inf, 0]]), r"points: expected finite values, got inf"),
        (np.array([["a", "b", "c"]]), r"points: expected numbers"),
    ],
)
def test_bad_points_are_named(points, match):
    with pytest.raises(ValidationError, match=match):
        validate_request(RecognizeRequest(points), SETTINGS)


def test_too_many_points_names_the_limit():
    pts = np.zeros((500_001, 3), dtype=np.float32)
    with pytest.raises(ValidationError, match=r"at most 500000 points, got 500001"):
        validate_request(RecognizeRequest(pts), SETTINGS)


def test_max_points_has_a_documented_floor():
    with pytest.raises(ValueError):
        PerceptionSettings(max_points=1000)
    assert PerceptionSettings().max_points == 2_000_000


def test_bad_colors_labels_viewpoint_workspace_options():
    _check(r"colors: expected shape \(10, 3\), got \(9, 3\)", colors=np.zeros((9, 3)))
    _check(
        r"colors: expected values in \[0, 1\], got range \[0, 2\]",
        colors=np.r_[np.zeros((9, 3)), np.full((1, 3), 2.0)],
    )
    _check(r"labels: expected shape \(10,\), got \(3,\)", labels=np.zeros(3, dtype=int))
    _check(r"labels: expected instance ids >= 0 or -1", labels=np.full(10, -5))
    _check(r"labels: expected integers", labels=np.full(10, 0.5))
    _check(r"viewpoint: expected shape \(3,\), got \(2,\)", viewpoint=np.zeros(2))
    _check(r"viewpoint: expected finite values", viewpoint=np.array([0, 0, np.nan]))
    _check(r"workspace: expected min < max", workspace=Workspace((0, 0, 0), (1, 0, 1)))
    _check(r"options.method: expected one of", options=RecognizeOptions(method="magic"))
    _check(
        r"options.points_per_segment: expected an int in \[16, 4096\], got 4",
        options=RecognizeOptions(points_per_segment=4),
    )
    _check(r"labels: expected per-point labels", options=RecognizeOptions(segmentation="labels"))
    _check(r"colors: expected per-point colors", options=RecognizeOptions(segmentation="color"))
