"""gRPC client helpers: channels with the stack's max message sizes, deadlines on every call,
and remote adapters with the same methods as the in-process domain objects.

``RemoteRecognizer(address).recognize(request, timeout=...)`` behaves like
``sqmanip.perception.pipeline.Recognizer().recognize(request)``: same request and result types,
same exceptions (:mod:`sqmanip.errors`), so a domain package (e.g. search) can take either.
:class:`RemoteSimulator` does the same for :class:`sqmanip.sim.Simulator`,
:class:`RemoteGraspPlanner` for :class:`sqmanip.grasping.GraspPlanner` (``plan``,
``plan_detailed``) and :class:`RemoteDynamics` for ``SQPDNet.predict``.
:class:`RemotePlanner` (``plan`` like ``PushMPC.plan``, ``run_episode``) and
:class:`RemoteSearch` (``evaluate``, ``run_episode``) are the clients of the MPC planner and the
shelf-search services.
"""

from __future__ import annotations

import grpc

from sqmanip.errors import ValidationError
from sqmanip.perception.types import RecognizeRequest, Scene
from sqmanip.settings import StackSettings, get_settings
from sqmanip.v1 import (
    dynamics_pb2_grpc,
    grasp_pb2_grpc,
    perception_pb2_grpc,
    planner_pb2_grpc,
    search_pb2_grpc,
    sim_pb2,
    sim_pb2_grpc,
)

from . import convert
from .errors import REQUEST_ID_KEY, error_from_status
from .server import grpc_options


def channel(address: str, settings: StackSettings | None = None) -> grpc.Channel:
    """Blocking channel to ``host:port`` with the configured max message sizes."""
    return grpc.insecure_channel(address, options=grpc_options(settings or get_settings()))


def aio_channel(address: str, settings: StackSettings | None = None) -> grpc.aio.Channel:
    """asyncio channel (create it inside the event loop that uses it)."""
    return grpc.aio.insecure_channel(address, options=grpc_options(settings or get_settings()))


def _metadata(request_id: str | None) -> tuple[tuple[str, str], ...] | None:
    return ((REQUEST_ID_KEY, request_id),) if request_id else None


class RemoteRecognizer:
    """Blocking gRPC client of the Perception service with the Recognizer interface."""

    def __init__(self, address: str, settings: StackSettings | None = None) -> None:
        self._settings = settings or get_settings()
        self._channel = channel(address, self._settings)
        self._stub = perception_pb2_grpc.PerceptionStub(self._channel)

    def recognize(
        self,
        request: RecognizeRequest,
        *,
        timeout: float | None = None,
        request_id: str | None = None,
    ) -> Scene:
        """Recognize remotely; ``timeout`` (s) defaults to ``settings.request_timeout_s``."""
        msg = convert.recognize_request_to_proto(request)
        try:
            response = self._stub.Recognize(
                msg,
                timeout=timeout if timeout is not None else self._settings.request_timeout_s,
                metadata=_metadata(request_id),
            )
        except grpc.RpcError as err:
            raise error_from_status(err.code(), err.details() or "") from None
        return convert.scene_from_proto(response.scene)

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> RemoteRecognizer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class AsyncRemoteRecognizer:
    """asyncio variant of :class:`RemoteRecognizer` (``await recognizer.recognize(...)``)."""

    def __init__(self, address: str, settings: StackSettings | None = None) -> None:
        self._settings = settings or get_settings()
        self._channel = aio_channel(address, self._settings)
        self._stub = perception_pb2_grpc.PerceptionStub(self._channel)

    async def recognize(
        self,
        request: RecognizeRequest,
        *,
        timeout: float | None = None,
        request_id: str | None = None,
    ) -> Scene:
        msg = convert.recognize_request_to_proto(request)
        try:
            response = await self._stub.Recognize(
                msg,
                timeout=timeout if timeout is not None else self._settings.request_timeout_s,
                metadata=_metadata(request_id),
            )
        except grpc.aio.AioRpcError as err:
            raise error_from_status(err.code(), err.details() or "") from None
        return convert.scene_from_proto(response.scene)

    async def close(self) -> None:
        await self._channel.close()


class RemoteSimulator:
    """Blocking gRPC client of the Simulator service with the :class:`sqmanip.sim.Simulator`
    methods (``reset``, ``observe``, ``push``, ``grasp``, ``pick_and_place``, ``release``,
    ``get_state``): same arguments, result types and exceptions, so code written against the
    in-process simulator runs against the service unchanged."""

    def __init__(
        self, address: str, settings: StackSettings | None = None, *, timeout: float | None = None
    ) -> None:
        self._settings = settings or get_settings()
        self._channel = channel(address, self._settings)
        self._stub = sim_pb2_grpc.SimulatorStub(self._channel)
        self.timeout = timeout if timeout is not None else self._settings.request_timeout_s

    def _call(self, method: str, msg):
        try:
            return getattr(self._stub, method)(msg, timeout=self.timeout)
        except grpc.RpcError as err:
            raise error_from_status(err.code(), err.details() or "") from None

    def reset(self, scene=None, *, seed=None, n_objects=None, kind="", object_kinds=()):
        """Reset from a scene spec (or its dict) or a seed; returns the :class:`SimState`.
        The built scene (settled poses) is kept in :attr:`scene_spec`."""
        msg = convert.reset_request_to_proto(
            scene, seed=seed, n_objects=n_objects, kind=kind, object_kinds=object_kinds
        )
        response = self._call("Reset", msg)
        self.scene_spec = convert.scene_spec_from_json(response.scene_json)
        return convert.sim_state_from_proto(response.state)

    def observe(self, camera="default", *, intrinsics=None, camera_pose=None, noise=True):
        msg = convert.observe_request_to_proto(
            camera, intrinsics=intrinsics, camera_pose=camera_pose, noise=noise
        )
        return convert.observation_from_proto(self._call("Observe", msg))

    def push(self, p_start, v, upright: bool = False):
        return convert.action_result_from_proto(
            self._call("Push", convert.push_request_to_proto(p_start, v, upright))
        )

    def grasp(self, pose, width: float):
        return convert.action_result_from_proto(
            self._call("Grasp", convert.grasp_request_to_proto(pose, width))
        )

    def pick_and_place(self, grasp_pose, width: float, place_pose):
        msg = convert.pick_and_place_request_to_proto(grasp_pose, width, place_pose)
        return convert.action_result_from_proto(self._call("PickAndPlace", msg))

    def release(self):
        return convert.action_result_from_proto(self._call("Release", sim_pb2.ReleaseRequest()))

    def get_state(self):
        return convert.sim_state_from_proto(self._call("GetState", sim_pb2.GetStateRequest()))

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> RemoteSimulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _BlockingClient:
    """A channel, a stub, a default deadline and status -> domain exception mapping."""

    _stub_class: type

    def __init__(
        self, address: str, settings: StackSettings | None = None, *, timeout: float | None = None
    ) -> None:
        self._settings = settings or get_settings()
        self._channel = channel(address, self._settings)
        self._stub = self._stub_class(self._channel)
        self.timeout = timeout if timeout is not None else self._settings.request_timeout_s

    def _call(self, method: str, msg, timeout: float | None, request_id: str | None):
        try:
            return getattr(self._stub, method)(
                msg,
                timeout=timeout if timeout is not None else self.timeout,
                metadata=_metadata(request_id),
            )
        except grpc.RpcError as err:
            raise error_from_status(err.code(), err.details() or "") from None

    def close(self) -> None:
        self._channel.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RemoteGraspPlanner(_BlockingClient):
    """Blocking gRPC client of the GraspPlanner service with the
    :class:`sqmanip.grasping.GraspPlanner` methods ``plan`` and ``plan_detailed``: same
    arguments (``target`` parts, ``obstacles``, ``environment``, ``gripper``, ``options``,
    ``observed_points``), same results and exceptions. ``environment=None`` is the domain
    default (a table at z = 0). ``check_reachability=False`` skips the server's IK check."""

    _stub_class = grasp_pb2_grpc.GraspPlannerStub

    def plan_detailed(
        self,
        target,
        obstacles=(),
        environment=None,
        gripper=None,
        options=None,
        observed_points=None,
        *,
        check_reachability: bool = True,
        timeout: float | None = None,
        request_id: str | None = None,
    ):
        msg = convert.plan_grasps_request_to_proto(
            target, obstacles, environment, gripper, options, observed_points,
            check_reachability=check_reachability,
        )  # fmt: skip
        return convert.plan_result_from_proto(self._call("Plan", msg, timeout, request_id))

    def plan(
        self,
        target,
        obstacles=(),
        environment=None,
        gripper=None,
        options=None,
        observed_points=None,
        *,
        check_reachability: bool = True,
        timeout: float | None = None,
        request_id: str | None = None,
    ):
        """Feasible grasps on ``target``, best first (see :meth:`GraspPlanner.plan`)."""
        return self.plan_detailed(
            target, obstacles, environment, gripper, options, observed_points,
            check_reachability=check_reachability, timeout=timeout, request_id=request_id,
        ).grasps  # fmt: skip


class RemoteDynamics(_BlockingClient):
    """Blocking gRPC client of the Dynamics service with ``SQPDNet.predict``'s signature:
    ``predict(poses (N, 4, 4), params (N, 9), actions (K, 6), kinds (N,))`` -> ``(K, N, 4, 4)``
    float32 tensor, all K actions in one call. ``model`` picks the server's model ("sqpdnet",
    "physics" or a checkpoint name); :attr:`last_failed` holds the physics model's flags."""

    _stub_class = dynamics_pb2_grpc.DynamicsStub

    def __init__(
        self,
        address: str,
        settings: StackSettings | None = None,
        *,
        model: str = "sqpdnet",
        timeout: float | None = None,
    ) -> None:
        super().__init__(address, settings, timeout=timeout)
        self.model = model
        self.last_failed = None
        self.last_latency_ms = 0.0

    def predict(
        self,
        poses,
        params,
        actions,
        kinds=None,
        *,
        model: str | None = None,
        timeout: float | None = None,
        request_id: str | None = None,
    ):
        msg = convert.predict_request_to_proto(
            poses, params, actions, kinds, model=model or self.model
        )
        return self._predict(msg, timeout, request_id)

    def predict_batch(
        self,
        poses,
        params,
        actions,
        kinds=None,
        *,
        model: str | None = None,
        timeout: float | None = None,
        request_id: str | None = None,
    ):
        """``SQPDNet.predict_batch`` over the wire: ``poses (K, N, 4, 4)``, one scene per push,
        in one call (the MPC's later horizon steps)."""
        import numpy as np

        scenes = np.asarray(poses.detach().cpu() if hasattr(poses, "detach") else poses)
        if scenes.ndim != 4 or scenes.shape[0] == 0:
            raise ValidationError(f"poses: expected shape (K >= 1, N, 4, 4), got {scenes.shape}")
        msg = convert.predict_request_to_proto(
            scenes[0], params, actions, kinds, model=model or self.model, scene_poses=scenes
        )
        return self._predict(msg, timeout, request_id)

    def _predict(self, msg, timeout: float | None, request_id: str | None):
        import torch

        response = self._call("Predict", msg, timeout, request_id)
        out, self.last_failed = convert.predict_response_from_proto(response)
        self.last_latency_ms = response.latency_ms
        return torch.from_numpy(out)


class RemotePlanner(_BlockingClient):
    """Blocking gRPC client of the Planner service.

    ``plan(objects [(parts, id)], task, ...)`` returns the same
    :class:`~sqmanip.planning.mpc.PlanResult` as ``PushMPC.plan``; ``run_episode(kind, ...)``
    yields the episode's events as dicts (:func:`convert.episode_event_from_proto`), the last
    one with ``result``."""

    _stub_class = planner_pb2_grpc.PlannerStub

    def plan(
        self,
        objects,
        task,
        *,
        num_sequences: int | None = None,
        horizon: int | None = None,
        seed: int | None = None,
        dynamics_model: str = "",
        timeout: float | None = None,
        request_id: str | None = None,
    ):
        msg = convert.plan_request_to_proto(
            objects, task, num_sequences=num_sequences, horizon=horizon, seed=seed,
            dynamics_model=dynamics_model,
        )  # fmt: skip
        return convert.plan_response_from_proto(self._call("Plan", msg, timeout, request_id))

    def run_episode(self, kind: str, index: int = 0, seed: int = 0, *, timeout=None, **kw):
        msg = convert.episode_request_to_proto(kind, index, seed, **kw)
        try:
            for ev in self._stub.RunEpisode(msg, timeout=timeout or self.timeout):
                yield convert.episode_event_from_proto(ev)
        except grpc.RpcError as err:
            raise error_from_status(err.code(), err.details() or "") from None


class RemoteSearch(_BlockingClient):
    """Blocking gRPC client of the Search service: ``evaluate(objects, target, ...)`` ->
    :class:`convert.EvaluateResult` (f, g, g_m maps of the grid shape); ``run_episode(...)``
    yields event dicts, the last one with ``result``."""

    _stub_class = search_pb2_grpc.SearchStub

    def evaluate(self, objects, target=None, shelf=None, camera=None, *, timeout=None, **kw):
        msg = convert.evaluate_request_to_proto(objects, target, shelf, camera, **kw)
        return convert.evaluate_response_from_proto(self._call("Evaluate", msg, timeout, None))

    def run_episode(self, scenario=None, *, timeout=None, **kw):
        msg = convert.search_episode_request_to_proto(scenario, **kw)
        try:
            for ev in self._stub.RunEpisode(msg, timeout=timeout or self.timeout):
                yield convert.search_event_from_proto(ev)
        except grpc.RpcError as err:
            raise error_from_status(err.code(), err.details() or "") from None
