"""Read a point cloud from a file: PLY (ascii / binary; a mesh PLY's vertices), NPY ``(N, 3)``
or ``(N, 6)`` (xyz + rgb), or the NPZ of ``sqmanip sim observe --out frame.npz``.

Every reader returns a :class:`Cloud` (``points (N, 3)`` float32 in metres, ``colors (N, 3)``
float32 in [0, 1] or None, and the sensor ``viewpoint (3,)`` when the file records it) and raises
:class:`ValidationError` naming the file and what is wrong (shape, non-finite values, suffix).

Why the viewpoint: recognition completes the hidden back of each object from the free space seen
from the sensor (amodal completion, Ch. 3). ``sqmanip sim observe --out frame.ply`` writes it as a
PLY header line ``comment viewpoint X Y Z`` and the ``.npz`` holds ``camera_pose``; both are read
back here, so ``sqmanip recognize frame.ply`` uses it without ``--viewpoint``.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

from sqmanip.errors import ValidationError

from .ply import parse_ply, to_ply

CLOUD_SUFFIXES = (".ply", ".npy", ".npz")
_VIEWPOINT = re.compile(rb"^comment viewpoint (\S+) (\S+) (\S+)\s*$", re.M)


@dataclasses.dataclass(frozen=True)
class Cloud:
    points: np.ndarray
    """(N, 3) float32, metres, world frame."""
    colors: np.ndarray | None
    """(N, 3) float32 in [0, 1], or None."""
    viewpoint: np.ndarray | None = None
    """(3,) float64 sensor origin in the world frame, or None when the file does not say."""


def _colors(raw: np.ndarray, where: str) -> np.ndarray:
    """RGB in [0, 1]: values above 1 are taken as 0-255 (uchar) and scaled."""
    c = np.asarray(raw, dtype=np.float32)
    if c.size and float(np.nanmax(c)) > 1.0:
        c = c / 255.0
    if not np.isfinite(c).all() or c.min(initial=0.0) < 0.0 or c.max(initial=0.0) > 1.0:
        raise ValidationError(f"{where}: colors must be in [0, 1] or [0, 255]")
    return c


def cloud_from_array(arr: np.ndarray, where: str = "array") -> Cloud:
    """``(N, 3)`` xyz or ``(N, 6)`` xyz + rgb (rgb in [0, 1] or [0, 255]) -> Cloud."""
    a = np.asarray(arr)
    if a.ndim != 2 or a.shape[1] not in (3, 6) or not np.issubdtype(a.dtype, np.number):
        raise ValidationError(
            f"{where}: expected a numeric array of shape (N, 3) or (N, 6), got {a.shape} {a.dtype}"
        )
    points = a[:, :3].astype(np.float32)
    colors = _colors(a[:, 3:], where) if a.shape[1] == 6 else None
    return Cloud(points, colors)


def _ply_viewpoint(data: bytes) -> np.ndarray | None:
    end = data.find(b"end_header", 0, 16 * 1024)
    m = _VIEWPOINT.search(data[: max(end, 0)])
    if m is None:
        return None
    try:
        vp = np.array([float(v) for v in m.groups()])
    except ValueError:
        return None
    return vp if np.isfinite(vp).all() else None


def _from_npz(path: Path) -> Cloud:
    with np.load(path, allow_pickle=False) as z:
        if "points" not in z:
            raise ValidationError(f"{path}: the .npz has no 'points' array (have {list(z)})")
        points = np.asarray(z["points"])
        cloud = cloud_from_array(points, f"{path}: points")
        viewpoint = None
        if "viewpoint" in z and np.asarray(z["viewpoint"]).size == 3:
            viewpoint = np.asarray(z["viewpoint"], dtype=np.float64).reshape(3)
        elif "camera_pose" in z and np.asarray(z["camera_pose"]).shape == (4, 4):
            viewpoint = np.asarray(z["camera_pose"], dtype=np.float64)[:3, 3].copy()
        colors = cloud.colors
        if "colors" in z:
            colors = _colors(np.asarray(z["colors"]).reshape(-1, 3), f"{path}: colors")
        elif "rgb" in z and "point_pixels" in z:  # sqmanip sim observe --out frame.npz
            rgb = np.asarray(z["rgb"]).reshape(-1, 3)
            pix = np.asarray(z["point_pixels"]).reshape(-1)
            if len(pix) == len(points) and (len(pix) == 0 or pix.max() < len(rgb)):
                colors = (rgb[pix] / 255.0).astype(np.float32)
        return Cloud(cloud.points, colors, viewpoint)


def read_cloud(path: str | Path) -> Cloud:
    """Points (and colors) from ``path``: ``.ply``, ``.npy`` or ``.npz`` (by suffix)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise ValidationError(
            f"{path}: unknown point-cloud format {suffix or '(no suffix)'!r}; "
            f"expected one of {', '.join(CLOUD_SUFFIXES)}"
        )
    if not path.is_file():
        raise ValidationError(f"{path}: no such file")
    if suffix == ".ply":
        data = path.read_bytes()
        try:
            ply = parse_ply(data, allow_mesh=True)
        except ValidationError as exc:
            raise ValidationError(f"{path}: {exc.message}") from None
        cloud = Cloud(ply.points, ply.colors, _ply_viewpoint(data))
    elif suffix == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except ValueError as exc:
            raise ValidationError(f"{path}: not a plain numeric .npy ({exc})") from None
        cloud = cloud_from_array(arr, str(path))
    else:
        cloud = _from_npz(path)
    if len(cloud.points) == 0:
        raise ValidationError(f"{path}: the cloud has no points")
    if not np.isfinite(cloud.points).all():
        bad = int((~np.isfinite(cloud.points).all(axis=1)).sum())
        raise ValidationError(f"{path}: {bad} points have non-finite coordinates")
    return cloud


def write_cloud(
    path: str | Path,
    points: np.ndarray,
    colors: np.ndarray | None = None,
    viewpoint: np.ndarray | None = None,
) -> None:
    """Write ``points (N, 3)`` (and ``colors (N, 3)`` in [0, 1]) as ``.ply`` (binary; the
    ``viewpoint (3,)`` as a ``comment viewpoint X Y Z`` header line) or ``.npy`` (``(N, 3)`` or
    ``(N, 6)``; no viewpoint), by suffix."""
    path = Path(path)
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    if path.suffix.lower() == ".ply":
        data = to_ply(pts, colors, binary=True)
        if viewpoint is not None:
            vp = np.asarray(viewpoint, dtype=np.float64).reshape(3)
            line = "comment viewpoint " + " ".join(repr(float(v)) for v in vp)
            data = data.replace(b"\nelement vertex", f"\n{line}\nelement vertex".encode(), 1)
        path.write_bytes(data)
    elif path.suffix.lower() == ".npy":
        arr = pts if colors is None else np.hstack([pts, np.asarray(colors, np.float32)])
        np.save(path, arr)
    else:
        raise ValidationError(f"{path}: expected a .ply or .npy file name for a point cloud")
