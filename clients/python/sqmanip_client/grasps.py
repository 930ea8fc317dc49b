"""Request bodies of ``POST /grasps`` and ``POST /predict``, shared by the sync and async clients
(``Client.plan_grasps`` / ``Client.predict`` and their ``AsyncClient`` twins).

Objects are accepted as :class:`~sqmanip_client.types.RecognizedObject` (from ``recognize``),
a :class:`~sqmanip_client.types.Scene` (its objects), or the ``/recognize`` JSON dicts; parts as
:class:`~sqmanip_client.types.SuperquadricPart` or dicts.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from .sim import pose_json
from .types import RecognizedObject, Scene, SuperquadricPart, SupportPlane

UNSET: Any = object()
"""Marker: ``support_plane`` not given (the gateway's default applies)."""


def part_json(part: SuperquadricPart | Mapping[str, Any]) -> dict[str, Any]:
    if isinstance(part, Mapping):
        return dict(part)
    if not isinstance(part, SuperquadricPart):
        raise TypeError(f"expected a SuperquadricPart or a dict, got {type(part).__name__}")
    return {
        "kind": part.kind,
        "size": [float(v) for v in part.size],
        "shape": [float(v) for v in part.shape],
        "taper": float(part.taper),
        "bend": float(part.bend),
        "bend_direction": float(part.bend_direction),
        "pose": pose_json(part.pose),
    }


def object_json(obj: RecognizedObject | Mapping[str, Any]) -> dict[str, Any]:
    if isinstance(obj, Mapping):
        return {k: v for k, v in obj.items() if k in ("id", "parts", "point_indices")}
    return {"id": int(obj.id), "parts": [part_json(p) for p in obj.parts]}


def grasps_body(
    objects: Any,
    target_id: int | None,
    points: Any,
    colors: Any,
    labels: Any,
    viewpoint: Any,
    workspace: Any,
    recognize_options: Mapping[str, Any] | None,
    observed_points: Any,
    support_plane: Any,
    boxes: Any,
    gripper: Mapping[str, Any] | None,
    options: Mapping[str, Any],
) -> dict[str, Any]:
    if (objects is None) == (points is None):
        raise ValueError("give either objects or points (a point cloud), not both")
    body: dict[str, Any] = {"options": {k: v for k, v in options.items() if v is not None}}
    if objects is not None:
        objs = objects.objects if isinstance(objects, Scene) else objects
        body["objects"] = [object_json(o) for o in objs]
    else:
        pts = np.asarray(points, dtype=np.float32)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
        body["points"] = pts.tolist()
        if colors is not None:
            body["colors"] = np.asarray(colors, dtype=np.float64).tolist()
        if labels is not None:
            body["labels"] = np.asarray(labels, dtype=np.int64).tolist()
        if viewpoint is not None:
            body["viewpoint"] = [float(v) for v in np.asarray(viewpoint).reshape(3)]
        if workspace is not None:
            lo, hi = (
                (workspace["min"], workspace["max"])
                if isinstance(workspace, Mapping)
                else workspace
            )
            body["workspace"] = {"min": [float(v) for v in lo], "max": [float(v) for v in hi]}
        if recognize_options:
            body["recognize"] = dict(recognize_options)
    if target_id is not None:
        body["target_id"] = int(target_id)
    if observed_points is not None:
        body["observed_points"] = np.asarray(observed_points, dtype=np.float64).tolist()
    if support_plane is not UNSET:
        if support_plane is None:
            body["support_plane"] = None
        elif isinstance(support_plane, SupportPlane):
            body["support_plane"] = {
                "normal": list(support_plane.normal),
                "offset": float(support_plane.offset),
            }
        else:
            body["support_plane"] = dict(support_plane)
    if boxes:
        body["boxes"] = [part_json(b) for b in boxes]
    if gripper:
        body["gripper"] = dict(gripper)
    return body


def predict_body(objects: Any, actions: Any, model: str) -> dict[str, Any]:
    """``objects``: parts (one superquadric per object) or single-part recognized objects."""
    parts = []
    for i, o in enumerate(objects.objects if isinstance(objects, Scene) else objects):
        if isinstance(o, Mapping) and "parts" in o:
            if len(o["parts"]) != 1:
                raise ValueError(f"objects[{i}]: the dynamics model takes one part per object")
            o = o["parts"][0]
        elif isinstance(o, RecognizedObject):
            if len(o.parts) != 1:
                raise ValueError(f"objects[{i}]: the dynamics model takes one part per object")
            o = o.parts[0]
        parts.append(part_json(o))
    acts = np.asarray(actions, dtype=np.float64)
    if acts.ndim != 2 or acts.shape[1] != 6:
        raise ValueError(f"actions must have shape (K, 6), got {acts.shape}")
    return {"objects": parts, "actions": acts.tolist(), "model": model}
