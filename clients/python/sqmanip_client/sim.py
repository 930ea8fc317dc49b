"""Request bodies and response parsing of the ``/sim`` routes, shared by the sync and async
clients (``Client.sim_*`` / ``AsyncClient.sim_*``).

Poses are accepted as :class:`~sqmanip_client.types.Pose`, 4 x 4 matrices or
``{"position", "orientation"}`` dicts; quaternions are (x, y, z, w).
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping
from typing import Any

import numpy as np

from .types import Pose, SimObservation, sim_observation_from_json


def matrix_to_quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    """Rotation matrix (3, 3) -> unit quaternion (x, y, z, w) with w >= 0 (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, s / 4]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-12))
        q = [0.0, 0.0, 0.0, (R[k, j] - R[j, k]) / s]
        q[i] = s / 4
        q[j] = (R[j, i] + R[i, j]) / s
        q[k] = (R[k, i] + R[i, k]) / s
    qa = np.asarray(q) / np.linalg.norm(q)
    if qa[3] < 0:
        qa = -qa
    return tuple(float(v) for v in qa)  # type: ignore[return-value]


def pose_json(pose: Any, name: str = "pose") -> dict[str, list[float]]:
    """``Pose`` | 4 x 4 matrix | ``{"position", "orientation"}`` -> the JSON pose."""
    if isinstance(pose, Pose):
        return {"position": list(pose.position), "orientation": list(pose.orientation)}
    if isinstance(pose, Mapping):
        out = {"position": [float(v) for v in pose["position"]]}
        if "orientation" in pose:
            out["orientation"] = [float(v) for v in pose["orientation"]]
        return out
    T = np.asarray(pose, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"{name} must be a Pose, a 4 x 4 matrix or a dict, got shape {T.shape}")
    return {
        "position": [float(v) for v in T[:3, 3]],
        "orientation": list(matrix_to_quaternion(T[:3, :3])),
    }


def reset_body(
    scene: Mapping[str, Any] | None,
    seed: int | None,
    n_objects: int | None,
    kind: str,
    object_kinds: Any,
) -> dict[str, Any]:
    body: dict[str, Any] = {"kind": kind}
    if scene is not None:
        body["scene"] = dict(scene)
    if seed is not None:
        body["seed"] = int(seed)
    if n_objects is not None:
        body["n_objects"] = int(n_objects)
    if object_kinds is not None:
        body["object_kinds"] = list(object_kinds)
    return body


def observe_body(
    camera: str,
    width: int | None,
    height: int | None,
    intrinsics: Mapping[str, Any] | None,
    camera_pose: Any,
    noise: bool,
) -> dict[str, Any]:
    body: dict[str, Any] = {"camera": camera, "noise": bool(noise)}
    k = dict(intrinsics or {})
    if width is not None:
        k["width"] = int(width)
    if height is not None:
        k["height"] = int(height)
    if k:
        body["intrinsics"] = k
    if camera_pose is not None:
        body["camera_pose"] = pose_json(camera_pose, "camera_pose")
    return body


def vec3(v: Any, name: str) -> list[float]:
    arr = np.asarray(v, dtype=np.float64).reshape(-1)
    if arr.shape != (3,):
        raise ValueError(f"{name} must have 3 numbers, got shape {arr.shape}")
    return [float(x) for x in arr]


def observation_from_npz(content: bytes) -> SimObservation:
    """Parse the ``?format=npz`` download of ``/sim/observe``."""
    with np.load(io.BytesIO(content), allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(arrays.pop("meta").tobytes().decode())
    return sim_observation_from_json(meta, arrays)
