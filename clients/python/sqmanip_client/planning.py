"""Request bodies and typed results of the planning and search routes: ``/plan``,
``/mpc/episodes``, ``/search/episodes`` and ``/search/evaluate``."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from .grasps import object_json, part_json
from .sim import pose_json
from .types import Pose, RecognizedObject, Scene, _pose


@dataclasses.dataclass(frozen=True)
class MPCPlan:
    """Result of :meth:`sqmanip_client.Client.plan`: one MPC step."""

    action: np.ndarray | None
    """(6,) push ``(p, v)`` to execute now (world frame, m), or None when nothing is admissible."""
    pushed_id: int | None
    predicted_next: dict[int, Pose]
    """Object id -> predicted pose after the push."""
    cost: float | None
    current_cost: float | None
    num_candidates: int
    num_sampled: int
    num_rejected_start: int
    num_rejected_workspace: int
    sequence: np.ndarray
    """(H, 6) the chosen sequence."""
    timings_ms: dict[str, float]
    dynamics_model: str
    solved: bool


@dataclasses.dataclass(frozen=True)
class EpisodeStatus:
    """Progress of a background episode (:meth:`Client.get_mpc_episode`,
    :meth:`Client.get_search_episode`)."""

    id: str
    kind: str
    status: str
    """running | done | failed."""
    events: tuple[dict[str, Any], ...]
    n_events: int
    result: dict[str, Any] | None
    error: dict[str, Any] | None
    elapsed_s: float

    @property
    def finished(self) -> bool:
        return self.status != "running"


@dataclasses.dataclass(frozen=True)
class SearchMaps:
    """Result of :meth:`Client.evaluate_search`: f, g, g_m of the grid ``shape``."""

    shape: tuple[int, ...]
    f: np.ndarray
    g: np.ndarray
    g_m: np.ndarray
    grid_xy: np.ndarray
    resolution: float
    objective: float
    timings_ms: dict[str, float]


def _objects(objects: Any) -> list[dict[str, Any]]:
    """Recognized objects (Scene, RecognizedObject, /recognize dicts) or ``(parts, id)`` pairs."""
    if isinstance(objects, Scene):
        objects = objects.objects
    out = []
    for i, o in enumerate(objects):
        if isinstance(o, RecognizedObject | Mapping):
            out.append(object_json(o))
        elif isinstance(o, tuple) and len(o) == 2:
            parts, oid = o
            out.append({"id": int(oid), "parts": [part_json(p) for p in parts]})
        else:
            raise ValueError(f"objects[{i}]: expected a recognized object or (parts, id)")
    return out


def task_json(task: Mapping[str, Any]) -> dict[str, Any]:
    """``{"kind": "moving", "goals": {id: (x, y, z)}}`` (a dict of goals is accepted) or any
    other task dict of the gateway's ``TaskIn``."""
    d = dict(task)
    goals = d.get("goals")
    if isinstance(goals, Mapping):
        d["goals"] = [{"id": int(k), "position": [float(v) for v in p]} for k, p in goals.items()]
    return d


def plan_body(objects: Any, task: Mapping[str, Any], options: Mapping[str, Any]) -> dict[str, Any]:
    return {"objects": _objects(objects), "task": task_json(task), "options": dict(options)}


def _opt_float(x: Any) -> float | None:
    return None if x is None else float(x)


def plan_from_json(d: dict[str, Any]) -> MPCPlan:
    return MPCPlan(
        action=None if d["action"] is None else np.asarray(d["action"], dtype=np.float64),
        pushed_id=d.get("pushed_id"),
        predicted_next={int(p["id"]): _pose(p["pose"]) for p in d["predicted_next"]},
        cost=_opt_float(d.get("cost")),
        current_cost=_opt_float(d.get("current_cost")),
        num_candidates=int(d["num_candidates"]),
        num_sampled=int(d["num_sampled"]),
        num_rejected_start=int(d["num_rejected_start"]),
        num_rejected_workspace=int(d["num_rejected_workspace"]),
        sequence=np.asarray(d["sequence"], dtype=np.float64).reshape(-1, 6),
        timings_ms=dict(d["timings_ms"]),
        dynamics_model=d["dynamics_model"],
        solved=bool(d["solved"]),
    )


def episode_from_json(d: dict[str, Any]) -> EpisodeStatus:
    return EpisodeStatus(
        id=d["id"], kind=d["kind"], status=d["status"], events=tuple(d["events"]),
        n_events=int(d["n_events"]), result=d.get("result"), error=d.get("error"),
        elapsed_s=float(d["elapsed_s"]),
    )  # fmt: skip


def evaluate_body(
    objects: Any,
    target: Mapping[str, Any] | None,
    target_pose: Any,
    options: Mapping[str, Any],
) -> dict[str, Any]:
    """``objects``: superquadric parts (the target excluded)."""
    body: dict[str, Any] = {"objects": [part_json(p) for p in objects], **dict(options)}
    if target is not None:
        body["target"] = dict(target)
    if target_pose is not None:
        body["target_visible"] = True
        body["target_pose"] = pose_json(target_pose, "target_pose")
    return body


def maps_from_json(d: dict[str, Any]) -> SearchMaps:
    shape = tuple(int(s) for s in d["shape"])
    return SearchMaps(
        shape=shape,
        f=np.asarray(d["f"], dtype=np.float32).reshape(shape),
        g=np.asarray(d["g"], dtype=np.float32).reshape(shape),
        g_m=np.asarray(d["g_m"], dtype=np.float32).reshape(shape),
        grid_xy=np.asarray(d["grid_xy"], dtype=np.float64).reshape(-1, 2),
        resolution=float(d["resolution"]),
        objective=float(d["objective"]),
        timings_ms=dict(d["timings_ms"]),
    )
