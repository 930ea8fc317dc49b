"""Shared builders for the planning tests: boxes on the table and an analytic pusher dynamics."""

from __future__ import annotations

import numpy as np
from sqmanip.geometry import Superquadric


def box(x: float, y: float, size=(0.05, 0.05, 0.05), yaw: float = 0.0, e: float = 0.2):
    """An upright box-like superquadric standing on the table (z = 0) at ``(x, y)``.

    ``size`` are full extents (m).
    """
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = (x, y, size[2] / 2)
    return Superquadric(size=tuple(0.5 * np.asarray(size)), shape=(e, e), pose=T)


class PusherDynamics:
    """Analytic stand-in with SQPD-Net's ``predict`` signature, for planner unit tests.

    Each object whose centre lies within ``max(a1, a2)`` of the push line, ahead of the start
    point, moves with the pusher: it is translated along the push by the distance the pusher
    travels after reaching it (``|v| - (along - r)``, at most ``|v|``). No rotation, no chains.
    """

    def predict(self, poses, params, actions, kinds=None):
        poses = np.asarray(poses, dtype=np.float64)
        actions = np.asarray(actions, dtype=np.float64)
        k = actions.shape[0]
        return self.predict_batch(np.broadcast_to(poses, (k, *poses.shape)), params, actions, kinds)

    def predict_batch(self, poses, params, actions, kinds=None):
        poses = np.asarray(poses, dtype=np.float64)
        params = np.asarray(params, dtype=np.float64)
        actions = np.asarray(actions, dtype=np.float64)
        p, v = actions[:, :2], actions[:, 3:5]
        length = np.linalg.norm(v, axis=-1, keepdims=True)
        d = v / np.maximum(length, 1e-12)
        rel = poses[..., :2, 3] - p[:, None]  # (K, N, 2)
        along = (rel * d[:, None]).sum(-1)
        perp = np.linalg.norm(rel - along[..., None] * d[:, None], axis=-1)
        r = params[:, :2].max(-1)  # (N,)
        hit = (perp < r) & (along > 0)
        travel = np.clip(length - (along - r), 0.0, length)  # (K, N)
        out = poses.copy()
        out[..., :2, 3] += np.where(hit, travel, 0.0)[..., None] * d[:, None]
        return out


class PredictOnly:
    """The same dynamics without ``predict_batch`` (exercises the per-sequence fallback)."""

    def __init__(self) -> None:
        self._inner = PusherDynamics()

    def predict(self, poses, params, actions, kinds=None):
        return self._inner.predict(poses, params, actions, kinds)
