"""HTTP clients of the SQManip gateway, sync (:class:`Client`) and async (:class:`AsyncClient`).

``recognize`` sends the compact binary body (N x 3 float32 little-endian, options as query
parameters) when only points (and a viewpoint / workspace) are given, and JSON when colors or
labels are sent. The ``sim_*`` methods drive the simulator (``/sim``), ``plan_grasps`` plans
grasps (``/grasps``), ``predict`` predicts pushes (``/predict``), ``plan`` runs one pushing-MPC
step (``/plan``), ``start_*_episode`` / ``get_*_episode`` run closed-loop episodes in the
background (``/mpc/episodes``, ``/search/episodes``) and ``evaluate_search`` returns the shelf
search's f and g maps (``/search/evaluate``). Errors become
:mod:`sqmanip_client.errors` exceptions.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from typing import Any

import httpx
import numpy as np

from . import errors, grasps, planning, sim
from .planning import EpisodeStatus, MPCPlan, SearchMaps
from .types import (
    GraspPlan,
    Prediction,
    Scene,
    SimActionResult,
    SimObservation,
    SimResetResult,
    SimState,
    grasp_plan_from_json,
    prediction_from_json,
    scene_from_json,
    sim_action_from_json,
    sim_observation_from_json,
    sim_state_from_json,
)

DEFAULT_TIMEOUT = 60.0


def _points(points: Any, name: str = "points") -> np.ndarray:
    arr = np.asarray(points, dtype=np.float32)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    return arr


def _vec(v: Any, n: int, name: str) -> list[float]:
    arr = np.asarray(v, dtype=np.float64).reshape(-1)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have {n} numbers, got shape {arr.shape}")
    return [float(x) for x in arr]


def _workspace(ws: Any) -> tuple[list[float], list[float]] | None:
    if ws is None:
        return None
    if isinstance(ws, Mapping):
        return _vec(ws["min"], 3, "workspace.min"), _vec(ws["max"], 3, "workspace.max")
    lo, hi = ws
    return _vec(lo, 3, "workspace min"), _vec(hi, 3, "workspace max")


def build_request(
    points: Any,
    colors: Any = None,
    labels: Any = None,
    viewpoint: Any = None,
    workspace: Any = None,
    options: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """``httpx`` request arguments (content, headers, params) for ``POST /recognize``."""
    pts = _points(points)
    opts = {k: v for k, v in (options or {}).items() if v is not None}
    ws = _workspace(workspace)
    vp = None if viewpoint is None else _vec(viewpoint, 3, "viewpoint")
    if colors is None and labels is None:
        params: dict[str, Any] = {
            k: (str(v).lower() if isinstance(v, bool) else v) for k, v in opts.items()
        }
        if vp is not None:
            params["viewpoint"] = ",".join(repr(x) for x in vp)
        if ws is not None:
            params["workspace"] = ",".join(repr(x) for x in (*ws[0], *ws[1]))
        return {
            "content": np.ascontiguousarray(pts, dtype="<f4").tobytes(),
            "headers": {"content-type": "application/octet-stream"},
            "params": params,
        }
    body: dict[str, Any] = {"points": pts.tolist(), "options": opts}
    if colors is not None:
        body["colors"] = _points(colors, "colors").tolist()
    if labels is not None:
        lab = np.asarray(labels)
        if lab.shape != (len(pts),):
            raise ValueError(f"labels must have shape ({len(pts)},), got {lab.shape}")
        body["labels"] = lab.astype(np.int64).tolist()
    if vp is not None:
        body["viewpoint"] = vp
    if ws is not None:
        body["workspace"] = {"min": ws[0], "max": ws[1]}
    return {
        "content": json.dumps(body, allow_nan=True).encode(),
        "headers": {"content-type": "application/json"},
        "params": {},
    }


def _result(response: httpx.Response) -> Any:
    if response.status_code >= 400:
        try:
            payload = response.json()
        except ValueError:
            payload = None
        raise errors.from_response(response.status_code, payload, response.text)
    return response.json()


def _transport_error(exc: httpx.HTTPError, url: str) -> errors.SQManipError:
    if isinstance(exc, httpx.TimeoutException):
        return errors.TimeoutError(f"no answer from {url} within the timeout: {exc}")
    return errors.ConnectionError(f"cannot reach {url}: {exc}")


TOKEN_ENV = "SQMANIP_API_TOKEN"


def auth_headers(token: str | None = None) -> dict[str, str]:
    """``{"authorization": "Bearer <token>"}`` for ``token``, else ``$SQMANIP_API_TOKEN``, else
    ``{}`` (a gateway on loopback without a token needs none)."""
    token = (token if token is not None else os.environ.get(TOKEN_ENV, "")).strip()
    return {"authorization": f"Bearer {token}"} if token else {}


class Client:
    """Blocking client: ``Client("http://127.0.0.1:8080").recognize(points)``.

    ``http_client`` replaces the internal ``httpx.Client`` (e.g. a test client). ``token`` (else
    ``$SQMANIP_API_TOKEN``) is sent as ``Authorization: Bearer <token>`` on every request (set
    on ``http_client``'s default headers when one is given); a gateway that requires a token
    answers 401 without it (:class:`sqmanip_client.errors.AuthenticationError`).
    """

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8080",
        *,
        timeout: float = DEFAULT_TIMEOUT,
        http_client: httpx.Client | None = None,
        token: str | None = None,
    ) -> None:
        self.base_url = base_url.rstrip("/")
        self._own = http_client is None
        self._http = http_client or httpx.Client(base_url=self.base_url, timeout=timeout)
        self._http.headers.update(auth_headers(token))
        self.timeout = timeout

    def recognize(
        self,
        points: Any,
        colors: Any = None,
        labels: Any = None,
        viewpoint: Any = None,
        workspace: Any = None,
        **options: Any,
    ) -> Scene:
        """Recognize objects in ``points (N, 3)`` (world frame, m).

        ``colors (N, 3)`` in [0, 1], ``labels (N,)`` ints (-1 = background), ``viewpoint (3,)``
        sensor origin, ``workspace`` ``{"min": xyz, "max": xyz}`` or ``(min, max)``; ``options``:
        method, segmentation, points_per_segment, remove_support, amodal, deformable, seed.
        """
        req = build_request(points, colors, labels, viewpoint, workspace, options)
        try:
            resp = self._http.post(f"{self.base_url}/recognize", timeout=self.timeout, **req)
        except httpx.HTTPError as exc:
            raise _transport_error(exc, self.base_url) from None
        return scene_from_json(_result(resp))

    def health(self) -> dict[str, Any]:
        """``GET /healthz``: the gateway's view of each backend."""
        try:
            return _result(self._http.get(f"{self.base_url}/healthz", timeout=self.timeout))
        except httpx.HTTPError as exc:
            raise _transport_error(exc, self.base_url) from None

    # --- simulator (/sim) ------------------------------------------------------------------------

    def _send(self, method: str, path: str, **kw: Any) -> httpx.Response:
        try:
            resp = self._http.request(method, f"{self.base_url}{path}", timeout=self.timeout, **kw)
        except httpx.HTTPError as exc:
            raise _transport_error(exc, self.base_url) from None
        if resp.status_code >= 400:
            _result(resp)
        return resp

    def sim_reset(
        self,
        scene: Mapping[str, Any] | None = None,
        *,
        seed: int | None = None,
        n_objects: int | None = None,
        kind: str = "tabletop",
        object_kinds: Any = None,
    ) -> SimResetResult:
        """Reset the simulator to ``scene`` (a scene dict, e.g. an earlier result's ``scene``)
        or to a random scene from ``seed`` (``n_objects``, ``kind`` tabletop | shelf,
        ``object_kinds`` from box, cylinder, superquadric)."""
        body = sim.reset_body(scene, seed, n_objects, kind, object_kinds)
        d = self._send("POST", "/sim/reset", json=body).json()
        return SimResetResult(sim_state_from_json(d["state"]), d["scene"])

    def sim_observe(
        self,
        camera: str = "default",
        *,
        width: int | None = None,
        height: int | None = None,
        intrinsics: Mapping[str, Any] | None = None,
        camera_pose: Any = None,
        noise: bool = True,
        arrays: bool = True,
    ) -> SimObservation:
        """Render a frame (``camera``: default | wrist | shelf | overview; ``width``/``height``
        keep the default focal length). With ``arrays`` (default) depth, rgb, segmentation and
        the point cloud come as NumPy arrays (``.npz`` transfer); ``arrays=False`` fetches the
        summary only."""
        body = sim.observe_body(camera, width, height, intrinsics, camera_pose, noise)
        if not arrays:
            return sim_observation_from_json(self._send("POST", "/sim/observe", json=body).json())
        resp = self._send("POST", "/sim/observe", json=body, params={"format": "npz"})
        return sim.observation_from_npz(resp.content)

    def sim_push(self, p: Any, v: Any, upright: bool = False) -> SimActionResult:
        """Push from ``p (3,)`` by ``v (3,)`` (world frame, m); refused pushes raise
        BadRequestError with the reason (e.g. out of workspace). ``upright`` (shelf only) turns
        the hand on its side to fit beside an object near a side board."""
        body = {"p": sim.vec3(p, "p"), "v": sim.vec3(v, "v"), "upright": bool(upright)}
        return sim_action_from_json(self._send("POST", "/sim/push", json=body).json())

    def sim_grasp(self, pose: Any, width: float) -> SimActionResult:
        """Grasp with the tool at ``pose`` (Pose or 4 x 4; approach = tool z) and ``width`` (m)."""
        body = {"pose": sim.pose_json(pose), "width": float(width)}
        return sim_action_from_json(self._send("POST", "/sim/grasp", json=body).json())

    def sim_pick_and_place(self, grasp_pose: Any, width: float, place_pose: Any) -> SimActionResult:
        """Grasp at ``grasp_pose`` and release with the tool at ``place_pose``."""
        body = {
            "grasp_pose": sim.pose_json(grasp_pose, "grasp_pose"),
            "width": float(width),
            "place_pose": sim.pose_json(place_pose, "place_pose"),
        }
        return sim_action_from_json(self._send("POST", "/sim/pick_and_place", json=body).json())

    def sim_release(self) -> SimActionResult:
        """Open the gripper (a held object drops) and return home."""
        return sim_action_from_json(self._send("POST", "/sim/release").json())

    def sim_state(self) -> SimState:
        return sim_state_from_json(self._send("GET", "/sim/state").json())

    # --- grasps (/grasps) and dynamics (/predict) --------------------------------------------------

    def plan_grasps(
        self,
        objects: Any = None,
        target_id: int | None = None,
        *,
        points: Any = None,
        colors: Any = None,
        labels: Any = None,
        viewpoint: Any = None,
        workspace: Any = None,
        recognize_options: Mapping[str, Any] | None = None,
        observed_points: Any = None,
        support_plane: Any = grasps.UNSET,
        boxes: Any = None,
        gripper: Mapping[str, Any] | None = None,
        **options: Any,
    ) -> GraspPlan:
        """Ranked grasps on ``objects`` (a Scene, its RecognizedObjects, or /recognize dicts) or
        on a point cloud ``points (N, 3)`` that the gateway recognizes first.

        ``target_id``: the object to grasp (default: every object; the others are obstacles).
        ``support_plane``: a SupportPlane or ``{"normal", "offset"}``; ``None`` = no plane;
        omitted = the recognized plane (cloud) or a table at z = 0 (objects). ``boxes``: fixed
        obstacle parts. ``gripper``: Franka hand overrides (``max_opening``, ...). ``options``:
        n_samples, n_approach, max_results (0 = all), seed, score (top_down | uncertainty),
        method (antipodal | rule_based), check_reachability, ...
        """
        body = grasps.grasps_body(
            objects, target_id, points, colors, labels, viewpoint, workspace, recognize_options,
            observed_points, support_plane, boxes, gripper, options,
        )  # fmt: skip
        return grasp_plan_from_json(self._send("POST", "/grasps", json=body).json())

    def predict(self, objects: Any, actions: Any, *, model: str = "sqpdnet") -> Prediction:
        """Next poses of ``objects`` (one superquadric part each, at its current pose) under each
        of the pushes ``actions (K, 6)`` = ``(p, v)`` rows (world frame, m), in one call:
        ``result.poses`` is ``(K, N, 4, 4)``. ``model``: sqpdnet | physics | a checkpoint name."""
        body = grasps.predict_body(objects, actions, model)
        return prediction_from_json(self._send("POST", "/predict", json=body).json())

    def plan(self, objects: Any, task: Mapping[str, Any], **options: Any) -> MPCPlan:
        """One pushing-MPC step: the push to execute now. ``objects``: a :class:`Scene`, its
        recognized objects, or ``(parts, id)`` pairs; ``task``: ``{"kind": "moving", "goals":
        {id: (x, y, z)}}``, ``{"kind": "singulation", "tau": 0.2}``, ``{"kind": "grasping",
        "target_id": i}`` or ``{"kind": "interactive_moving", "target_id": i, "goal": (x, y,
        z)}``; ``options``: num_sequences, horizon, seed, dynamics_model (sqpdnet | physics).
        A physics-model step takes 8-20 s for 100 sequences: raise the client timeout."""
        body = planning.plan_body(objects, task, options)
        return planning.plan_from_json(self._send("POST", "/plan", json=body).json())

    def start_mpc_episode(self, kind: str, index: int = 0, seed: int = 0, **body: Any) -> str:
        """Start a closed-loop pushing episode (scenario ``kind``, ``index``, ``seed``); returns
        its id. ``body``: objects (recognition | ground_truth), max_steps, options (dict)."""
        payload = {"kind": kind, "index": index, "seed": seed, **body}
        return self._send("POST", "/mpc/episodes", json=payload).json()["id"]

    def get_mpc_episode(self, episode_id: str) -> EpisodeStatus:
        return planning.episode_from_json(self._send("GET", f"/mpc/episodes/{episode_id}").json())

    def start_search_episode(self, scenario: Any = None, **body: Any) -> str:
        """Start a shelf-search episode; ``scenario`` a ShelfScenario dict (or None: generate
        from ``n_objects``, ``seed``); ``body``: method, shapes, actions, dynamics_model,
        max_steps, num_sequences, plan_seed. Returns the episode id."""
        payload = {**body}
        if scenario is not None:
            payload["scenario"] = scenario if isinstance(scenario, Mapping) else scenario.to_dict()
        return self._send("POST", "/search/episodes", json=payload).json()["id"]

    def get_search_episode(self, episode_id: str) -> EpisodeStatus:
        return planning.episode_from_json(
            self._send("GET", f"/search/episodes/{episode_id}").json()
        )

    def evaluate_search(
        self,
        objects: Any,
        target: Mapping[str, Any] | None = None,
        *,
        target_pose: Any = None,
        **options: Any,
    ) -> SearchMaps:
        """f and g over the target pose grid for ``objects`` (superquadric parts) on the shelf;
        ``target``: ``{"kind": "cylinder", "size": half extents}``; ``target_pose`` marks the
        target visible there; ``options``: shelf, camera, resolution, n_theta."""
        body = planning.evaluate_body(objects, target, target_pose, options)
        return planning.maps_from_json(self._send("POST", "/search/evaluate", json=body).json())

    def close(self) -> None:
        if self._own:
            self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class AsyncClient:
    """asyncio client with the same methods as :class:`Client` (``await client.recognize(...)``)."""

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8080",
        *,
        timeout: float = DEFAULT_TIMEOUT,
        http_client: httpx.AsyncClient | None = None,
        token: str | None = None,
    ) -> None:
        self.base_url = base_url.rstrip("/")
        self._own = http_client is None
        self._http = http_client or httpx.AsyncClient(base_url=self.base_url, timeout=timeout)
        self._http.headers.update(auth_headers(token))
        self.timeout = timeout

    async def recognize(
        self,
        points: Any,
        colors: Any = None,
        labels: Any = None,
        viewpoint: Any = None,
        workspace: Any = None,
        **options: Any,
    ) -> Scene:
        """See :meth:`Client.recognize`."""
        req = build_request(points, colors, labels, viewpoint, workspace, options)
        try:
            resp = await self._http.post(f"{self.base_url}/recognize", timeout=self.timeout, **req)
        except httpx.HTTPError as exc:
            raise _transport_error(exc, self.base_url) from None
        return scene_from_json(_result(resp))

    async def health(self) -> dict[str, Any]:
        try:
            return _result(await self._http.get(f"{self.base_url}/healthz", timeout=self.timeout))
        except httpx.HTTPError as exc:
            raise _transport_error(exc, self.base_url) from None

    # --- simulator (/sim): see the Client methods -------------------------------------------------

    async def _send(self, method: str, path: str, **kw: Any) -> httpx.Response:
        try:
            resp = await self._http.request(
                method, f"{self.base_url}{path}", timeout=self.timeout, **kw
            )
        except httpx.HTTPError as exc:
            raise _transport_error(exc, self.base_url) from None
        if resp.status_code >= 400:
            _result(resp)
        return resp

    async def sim_reset(
        self,
        scene: Mapping[str, Any] | None = None,
        *,
        seed: int | None = None,
        n_objects: int | None = None,
        kind: str = "tabletop",
        object_kinds: Any = None,
    ) -> SimResetResult:
        """See :meth:`Client.sim_reset`."""
        body = sim.reset_body(scene, seed, n_objects, kind, object_kinds)
        d = (await self._send("POST", "/sim/reset", json=body)).json()
        return SimResetResult(sim_state_from_json(d["state"]), d["scene"])

    async def sim_observe(
        self,
        camera: str = "default",
        *,
        width: int | None = None,
        height: int | None = None,
        intrinsics: Mapping[str, Any] | None = None,
        camera_pose: Any = None,
        noise: bool = True,
        arrays: bool = True,
    ) -> SimObservation:
        """See :meth:`Client.sim_observe`."""
        body = sim.observe_body(camera, width, height, intrinsics, camera_pose, noise)
        if not arrays:
            resp = await self._send("POST", "/sim/observe", json=body)
            return sim_observation_from_json(resp.json())
        resp = await self._send("POST", "/sim/observe", json=body, params={"format": "npz"})
        return sim.observation_from_npz(resp.content)

    async def sim_push(self, p: Any, v: Any, upright: bool = False) -> SimActionResult:
        body = {"p": sim.vec3(p, "p"), "v": sim.vec3(v, "v"), "upright": bool(upright)}
        return sim_action_from_json((await self._send("POST", "/sim/push", json=body)).json())

    async def sim_grasp(self, pose: Any, width: float) -> SimActionResult:
        body = {"pose": sim.pose_json(pose), "width": float(width)}
        return sim_action_from_json((await self._send("POST", "/sim/grasp", json=body)).json())

    async def sim_pick_and_place(
        self, grasp_pose: Any, width: float, place_pose: Any
    ) -> SimActionResult:
        body = {
            "grasp_pose": sim.pose_json(grasp_pose, "grasp_pose"),
            "width": float(width),
            "place_pose": sim.pose_json(place_pose, "place_pose"),
        }
        resp = await self._send("POST", "/sim/pick_and_place", json=body)
        return sim_action_from_json(resp.json())

    async def sim_release(self) -> SimActionResult:
        return sim_action_from_json((await self._send("POST", "/sim/release")).json())

    async def sim_state(self) -> SimState:
        return sim_state_from_json((await self._send("GET", "/sim/state")).json())

    # --- grasps and dynamics: see the Client methods ----------------------------------------------

    async def plan_grasps(
        self,
        objects: Any = None,
        target_id: int | None = None,
        *,
        points: Any = None,
        colors: Any = None,
        labels: Any = None,
        viewpoint: Any = None,
        workspace: Any = None,
        recognize_options: Mapping[str, Any] | None = None,
        observed_points: Any = None,
        support_plane: Any = grasps.UNSET,
        boxes: Any = None,
        gripper: Mapping[str, Any] | None = None,
        **options: Any,
    ) -> GraspPlan:
        """See :meth:`Client.plan_grasps`."""
        body = grasps.grasps_body(
            objects, target_id, points, colors, labels, viewpoint, workspace, recognize_options,
            observed_points, support_plane, boxes, gripper, options,
        )  # fmt: skip
        return grasp_plan_from_json((await self._send("POST", "/grasps", json=body)).json())

    async def predict(self, objects: Any, actions: Any, *, model: str = "sqpdnet") -> Prediction:
        """See :meth:`Client.predict`."""
        body = grasps.predict_body(objects, actions, model)
        return prediction_from_json((await self._send("POST", "/predict", json=body)).json())

    async def plan(self, objects: Any, task: Mapping[str, Any], **options: Any) -> MPCPlan:
        """See :meth:`Client.plan`."""
        body = planning.plan_body(objects, task, options)
        return planning.plan_from_json((await self._send("POST", "/plan", json=body)).json())

    async def start_mpc_episode(self, kind: str, index: int = 0, seed: int = 0, **body: Any) -> str:
        """See :meth:`Client.start_mpc_episode`."""
        payload = {"kind": kind, "index": index, "seed": seed, **body}
        return (await self._send("POST", "/mpc/episodes", json=payload)).json()["id"]

    async def get_mpc_episode(self, episode_id: str) -> EpisodeStatus:
        r = await self._send("GET", f"/mpc/episodes/{episode_id}")
        return planning.episode_from_json(r.json())

    async def start_search_episode(self, scenario: Any = None, **body: Any) -> str:
        """See :meth:`Client.start_search_episode`."""
        payload = {**body}
        if scenario is not None:
            payload["scenario"] = scenario if isinstance(scenario, Mapping) else scenario.to_dict()
        return (await self._send("POST", "/search/episodes", json=payload)).json()["id"]

    async def get_search_episode(self, episode_id: str) -> EpisodeStatus:
        r = await self._send("GET", f"/search/episodes/{episode_id}")
        return planning.episode_from_json(r.json())

    async def evaluate_search(
        self,
        objects: Any,
        target: Mapping[str, Any] | None = None,
        *,
        target_pose: Any = None,
        **options: Any,
    ) -> SearchMaps:
        """See :meth:`Client.evaluate_search`."""
        body = planning.evaluate_body(objects, target, target_pose, options)
        r = await self._send("POST", "/search/evaluate", json=body)
        return planning.maps_from_json(r.json())

    async def aclose(self) -> None:
        if self._own:
            await self._http.aclose()

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()
