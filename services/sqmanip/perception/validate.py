"""Validation of recognition requests: every failure is a ValidationError naming the field,
what was expected and what was received (ARCHITECTURE.md error mapping -> HTTP 400)."""

from __future__ import annotations

import dataclasses
from typing import get_args

import numpy as np

from sqmanip.errors import ValidationError

from .config import PerceptionSettings
from .types import Method, RecognizeRequest, Segmentation, Workspace


@dataclasses.dataclass(frozen=True)
class ValidRequest:
    """Arrays of a validated request, in the dtypes the pipeline uses."""

    points: np.ndarray
    """(N, 3) float32, finite."""
    colors: np.ndarray | None
    """(N, 3) float32 in [0, 1]."""
    labels: np.ndarray | None
    """(N,) int64, >= -1."""
    viewpoint: np.ndarray | None
    """(3,) float64, finite."""
    workspace: Workspace | None


def _array(value, field: str) -> np.ndarray:
    try:
        return np.asarray(value)
    except Exception as exc:  # ragged lists and the like
        raise ValidationError(
            f"{field}: expected a numeric array, got {type(value).__name__}"
        ) from exc


def _finite_float(arr: np.ndarray, field: str) -> np.ndarray:
    if arr.dtype.kind not in "fiub":
        raise ValidationError(f"{field}: expected numbers, got dtype {arr.dtype}")
    arr = arr.astype(np.float64, copy=False)
    bad = ~np.isfinite(arr)
    if bad.any():
        first = np.argwhere(bad)[0].tolist()
        raise ValidationError(
            f"{field}: expected finite values, got {arr[tuple(first)]} at index {first}"
        )
    return arr


def validate_points(points, max_points: int) -> np.ndarray:
    """``points`` must be ``(N, 3)`` finite numbers with ``1 <= N <= max_points``."""
    arr = _array(points, "points")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValidationError(f"points: expected shape (N, 3), got {tuple(arr.shape)}")
    n = arr.shape[0]
    if n < 1:
        raise ValidationError("points: expected at least 1 point, got 0")
    if n > max_points:
        raise ValidationError(f"points: expected at most {max_points} points, got {n}")
    return np.ascontiguousarray(_finite_float(arr, "points"), dtype=np.float32)


def validate_request(request: RecognizeRequest, settings: PerceptionSettings) -> ValidRequest:
    """Check shapes, ranges and options of ``request``; return its arrays converted."""
    if not isinstance(request, RecognizeRequest):
        raise ValidationError(f"request: expected a RecognizeRequest, got {type(request).__name__}")
    points = validate_points(request.points, settings.max_points)
    n = len(points)

    colors = None
    if request.colors is not None:
        c = _array(request.colors, "colors")
        if c.shape != (n, 3):
            raise ValidationError(f"colors: expected shape ({n}, 3), got {tuple(c.shape)}")
        c = _finite_float(c, "colors")
        if c.size and (c.min() < 0.0 or c.max() > 1.0):
            raise ValidationError(
                f"colors: expected values in [0, 1], got range [{c.min():g}, {c.max():g}]"
            )
        colors = c.astype(np.float32)

    labels = None
    if request.labels is not None:
        lab = _array(request.labels, "labels")
        if lab.shape != (n,):
            raise ValidationError(f"labels: expected shape ({n},), got {tuple(lab.shape)}")
        if lab.dtype.kind == "f":
            if not np.all(np.isfinite(lab)) or not np.all(lab == np.round(lab)):
                raise ValidationError("labels: expected integers, got non-integer floats")
        elif lab.dtype.kind not in "iub":
            raise ValidationError(f"labels: expected integers, got dtype {lab.dtype}")
        lab = lab.astype(np.int64)
        if n and lab.min() < -1:
            raise ValidationError(
                f"labels: expected instance ids >= 0 or -1 (background), got {lab.min()}"
            )
        labels = lab

    viewpoint = None
    if request.viewpoint is not None:
        v = _array(request.viewpoint, "viewpoint")
        if v.shape != (3,):
            raise ValidationError(f"viewpoint: expected shape (3,), got {tuple(v.shape)}")
        viewpoint = _finite_float(v, "viewpoint").copy()

    ws = request.workspace
    if ws is not None:
        lo = _finite_float(_array(ws.min, "workspace.min"), "workspace.min")
        hi = _finite_float(_array(ws.max, "workspace.max"), "workspace.max")
        if lo.shape != (3,) or hi.shape != (3,):
            raise ValidationError(
                f"workspace: expected min and max of shape (3,), got {lo.shape} and {hi.shape}"
            )
        if not np.all(lo < hi):
            raise ValidationError(
                f"workspace: expected min < max on every axis, got min {lo.tolist()} max {hi.tolist()}"
            )

    opt = request.options
    if opt.method not in get_args(Method):
        raise ValidationError(
            f"options.method: expected one of {list(get_args(Method))}, got {opt.method!r}"
        )
    if opt.segmentation not in get_args(Segmentation):
        raise ValidationError(
            f"options.segmentation: expected one of {list(get_args(Segmentation))}, "
            f"got {opt.segmentation!r}"
        )
    if opt.segmentation == "color" and colors is None:
        raise ValidationError("colors: expected per-point colors when options.segmentation='color'")
    if opt.segmentation == "labels" and labels is None:
        raise ValidationError(
            "labels: expected per-point labels when options.segmentation='labels'"
        )
    if not isinstance(opt.points_per_segment, int) or not 16 <= opt.points_per_segment <= 4096:
        raise ValidationError(
            f"options.points_per_segment: expected an int in [16, 4096], got {opt.points_per_segment!r}"
        )
    return ValidRequest(points, colors, labels, viewpoint, ws)
