"""Pinhole cameras for PyBullet: OpenCV intrinsics/extrinsics <-> OpenGL view/projection.

Conventions. ``Intrinsics`` are OpenCV's (pixel ``(u, v)`` = column, row; the centre of pixel
``(i, j)`` is at ``u = i, v = j``). A camera pose ``T_wc`` (4 x 4) maps the *optical* frame
(x right, y down, z forward) to the world. PyBullet renders with OpenGL matrices (camera looks
down -z, y up, column-major lists); :func:`view_matrix` and :func:`projection_matrix` convert,
and :func:`linearize_depth` turns the depth buffer into metric depth along the optical axis.
The default intrinsics are those of the Azure Kinect's NFOV unbinned depth mode (640 x 576,
fx = fy ~ 504 px), the camera used in Ch. 3.5.3, 4.5 and 5.5.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from ..errors import ValidationError

# OpenCV optical frame -> OpenGL camera frame (flip y and z).
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclasses.dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics (pixels) and the clipping range (m)."""

    width: int = 640
    height: int = 576
    fx: float = 504.0
    fy: float = 504.0
    cx: float = 319.5
    cy: float = 287.5
    near: float = 0.05
    far: float = 3.0

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0 or self.width > 4096 or self.height > 4096:
            raise ValidationError(
                f"camera size must be in 1..4096 px, got {self.width} x {self.height}"
            )
        vals = (self.fx, self.fy, self.cx, self.cy, self.near, self.far)
        if not all(np.isfinite(vals)) or self.fx <= 0 or self.fy <= 0:
            raise ValidationError(f"camera intrinsics must be finite with fx, fy > 0, got {vals}")
        if not 0 < self.near < self.far:
            raise ValidationError(f"need 0 < near < far, got near={self.near}, far={self.far}")

    @classmethod
    def from_fov(cls, width: int, height: int, fov_y_deg: float, **kw) -> Intrinsics:
        """Square pixels and the principal point at the image centre, from a vertical FOV."""
        f = 0.5 * height / np.tan(np.deg2rad(fov_y_deg) / 2)
        return cls(width, height, f, f, (width - 1) / 2, (height - 1) / 2, **kw)

    @classmethod
    def scaled(cls, width: int, height: int, base: Intrinsics | None = None) -> Intrinsics:
        """The default (or ``base``) focal length, principal point at the centre of a new size."""
        b = base or cls()
        return cls(width, height, b.fx, b.fy, (width - 1) / 2, (height - 1) / 2, b.near, b.far)

    def matrix(self) -> np.ndarray:
        """The 3 x 3 camera matrix ``K``."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])


def projection_matrix(k: Intrinsics) -> list[float]:
    """OpenGL projection (column-major, 16 floats) reproducing the OpenCV pinhole ``k``.

    With ``u = fx X / Z + cx`` and pixel ``i`` covering ``[i - 0.5, i + 0.5)`` in OpenCV
    coordinates, the GL viewport maps NDC ``x = -1`` to ``u = -0.5``; hence the ``+ 0.5``.
    PyBullet returns images top row first, so NDC ``y = +1`` is row ``v = -0.5``.
    """
    w, h, n, f = k.width, k.height, k.near, k.far
    cx, cy = k.cx + 0.5, k.cy + 0.5
    P = np.array(
        [
            [2 * k.fx / w, 0.0, 1.0 - 2 * cx / w, 0.0],
            [0.0, 2 * k.fy / h, 2 * cy / h - 1.0, 0.0],
            [0.0, 0.0, -(f + n) / (f - n), -2 * f * n / (f - n)],
            [0.0, 0.0, -1.0, 0.0],
        ]
    )
    return P.T.reshape(-1).tolist()


def view_matrix(T_wc: np.ndarray) -> list[float]:
    """OpenGL view matrix (column-major) for the optical-frame camera pose ``T_wc`` (4 x 4)."""
    V = _CV_TO_GL @ np.linalg.inv(np.asarray(T_wc, np.float64))
    return V.T.reshape(-1).tolist()


def linearize_depth(buffer: np.ndarray, k: Intrinsics) -> np.ndarray:
    """Depth buffer values in [0, 1] ``(H, W)`` -> metric depth along the optical axis (m).

    Pixels at the far plane (nothing rendered) become ``inf``.
    """
    d = np.asarray(buffer, np.float64)
    z = k.far * k.near / (k.far - (k.far - k.near) * d)
    return np.where(d >= 1.0 - 1e-7, np.inf, z)


@functools.lru_cache(maxsize=8)
def pixel_rays(k: Intrinsics) -> np.ndarray:
    """``(H, W, 3)`` optical-frame rays with ``z = 1`` through every pixel centre (cached,
    read-only)."""
    u = np.arange(k.width, dtype=np.float64)
    v = np.arange(k.height, dtype=np.float64)
    uu, vv = np.meshgrid(u, v)
    rays = np.stack([(uu - k.cx) / k.fx, (vv - k.cy) / k.fy, np.ones_like(uu)], axis=-1)
    rays.setflags(write=False)
    return rays


def backproject(
    depth: np.ndarray, k: Intrinsics, T_wc: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Depth ``(H, W)`` -> world points ``(N, 3)`` of the finite pixels and their flat indices ``(N,)``."""
    flat = depth.reshape(-1)
    idx = np.flatnonzero(np.isfinite(flat))
    T = np.asarray(T_wc, np.float64)
    # Rotate the rays once per pixel, scale by depth, translate: one (N, 3) pass.
    rays_w = pixel_rays(k).reshape(-1, 3)[idx] @ T[:3, :3].T
    rays_w *= flat[idx, None]
    rays_w += T[:3, 3]
    return rays_w, idx


def add_point_noise(points: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """Appendix A.1 sensor noise: ``x -> x + m v``, ``m ~ N(0, std)``, ``v`` uniform on S^2."""
    n = points.shape[0]
    v = rng.normal(size=(n, 3))
    v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    m = rng.normal(0.0, std, size=(n, 1))
    return points + m * v


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Optical-frame pose ``T_wc`` of a camera at ``eye`` looking at ``target`` (image up ~ ``up``)."""
    eye = np.asarray(eye, np.float64)
    z = np.asarray(target, np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, -np.asarray(up, np.float64))
    if np.linalg.norm(x) < 1e-9:  # looking along up: pick any perpendicular
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T
