"""``/sim``: the PyBullet Panda simulator over HTTP (thin: JSON <-> sim.proto).

- ``POST /sim/reset`` ``{"seed": 7, "n_objects": 4}`` or ``{"scene": {...}}`` -> state + the
  scene as built (POST that ``scene`` back to replay it).
- ``POST /sim/observe`` (optional JSON body: camera, intrinsics, camera_pose, noise). The
  default JSON answer is a summary: intrinsics, camera pose, array shapes, point counts per
  label and the ground-truth objects. ``?include=points`` adds the world point cloud and its
  labels as lists; ``?format=npz`` returns every array instead, as a NumPy ``.npz`` download
  (``numpy.load(io.BytesIO(body))``: depth, rgb, segmentation, points, point_labels,
  point_pixels, camera_pose, camera_matrix, and ``meta``: the JSON summary as uint8 bytes).
- ``POST /sim/push`` ``{"p": [x,y,z], "v": [dx,dy,dz]}``, ``POST /sim/grasp`` ``{"pose":
  {"position", "orientation"}, "width"}``, ``POST /sim/pick_and_place``, ``POST /sim/release``
  -> ActionResult (``success``, ``message``, ``before``/``after`` states).
- ``GET /sim/state``.

A refused action (out of workspace, unreachable, colliding, too wide) is 400 with the reason in
``detail``; the robot did not move.
"""

from __future__ import annotations

import io
from typing import Literal

import numpy as np
from fastapi import APIRouter, Query, Request
from fastapi.responses import Response

from sqmanip.rpc import convert
from sqmanip.rpc.errors import REQUEST_ID_KEY
from sqmanip.sim.camera import Intrinsics
from sqmanip.v1 import sim_pb2

from ..deps import SettingsDep, SimDep
from ..schemas import (
    IntrinsicsIn,
    SimActionOut,
    SimGraspBody,
    SimObservationOut,
    SimObserveBody,
    SimPickAndPlaceBody,
    SimPushBody,
    SimResetBody,
    SimResetOut,
    SimStateOut,
    observation_arrays,
    sim_action_out,
    sim_observation_out,
    sim_state_out,
)

router = APIRouter(prefix="/sim", tags=["sim"])

_ERRORS = {
    400: {"description": "Bad input or refused action (the detail names the reason)"},
    503: {"description": "Simulator service unavailable"},
    504: {"description": "Simulator did not answer within the deadline"},
}


def _call_kwargs(request: Request, settings) -> dict:
    return {
        "timeout": settings.request_timeout_s,
        "metadata": ((REQUEST_ID_KEY, request.state.request_id),),
        "wait_for_ready": False,
    }


def _intrinsics(k: IntrinsicsIn) -> Intrinsics:
    base = Intrinsics.scaled(k.width, k.height)
    return Intrinsics(
        k.width,
        k.height,
        base.fx if k.fx is None else k.fx,
        base.fy if k.fy is None else k.fy,
        base.cx if k.cx is None else k.cx,
        base.cy if k.cy is None else k.cy,
        k.near,
        k.far,
    )


@router.post("/reset", response_model=SimResetOut, summary="Reset to a scene or a seed",
             responses=_ERRORS)  # fmt: skip
async def reset(request: Request, body: SimResetBody, sim: SimDep, settings: SettingsDep):
    """Rebuild the world from ``scene`` or sample a random scene from ``seed`` (same seed, same
    scene)."""
    msg = convert.reset_request_to_proto(
        body.scene,
        seed=body.seed,
        n_objects=body.n_objects,
        kind=body.kind if body.scene is None else "",
        object_kinds=body.object_kinds or (),
    )
    response = await sim.Reset(msg, **_call_kwargs(request, settings))
    spec = convert.scene_spec_from_json(response.scene_json)
    return SimResetOut(
        state=sim_state_out(convert.sim_state_from_proto(response.state)), scene=spec.to_dict()
    )


@router.post(
    "/observe",
    response_model=SimObservationOut,
    summary="Render one camera frame",
    responses={
        **_ERRORS,
        200: {
            "content": {"application/octet-stream": {"schema": {"type": "string"}}},
            "description": "JSON summary, or the arrays as .npz with ?format=npz",
        },
    },
)
async def observe(
    request: Request,
    sim: SimDep,
    settings: SettingsDep,
    body: SimObserveBody | None = None,
    include: Literal["points"] | None = Query(
        None, description="'points': add the world cloud and its labels as JSON lists"
    ),
    format: Literal["json", "npz"] = Query(  # noqa: A002 - the query parameter's name
        "json", description="'npz': every array as a NumPy .npz download"
    ),
):
    """Depth, RGB, instance segmentation, the noisy world point cloud and ground truth.

    Also published on the Zenoh key ``sqmanip/sim/observation``.
    """
    body = body or SimObserveBody()
    msg = convert.observe_request_to_proto(
        body.camera,
        intrinsics=None if body.intrinsics is None else _intrinsics(body.intrinsics),
        camera_pose=None if body.camera_pose is None else body.camera_pose.matrix(),
        noise=body.noise,
    )
    response = await sim.Observe(msg, **_call_kwargs(request, settings))
    obs = convert.observation_from_proto(response)
    summary = sim_observation_out(obs, include_points=include == "points")
    if format == "json":
        return summary
    buf = io.BytesIO()
    meta = np.frombuffer(summary.model_dump_json().encode(), dtype=np.uint8)
    np.savez(buf, meta=meta, **observation_arrays(obs))
    return Response(
        buf.getvalue(),
        media_type="application/octet-stream",
        headers={"content-disposition": 'attachment; filename="observation.npz"'},
    )


@router.post("/push", response_model=SimActionOut, summary="Push (Ch. 4.5)", responses=_ERRORS)
async def push(request: Request, body: SimPushBody, sim: SimDep, settings: SettingsDep):
    """Tool tip to ``p`` with the Fig. 4.6 orientation, then to ``p + v`` through 10 via points."""
    msg = convert.push_request_to_proto(body.p, body.v, body.upright)
    response = await sim.Push(msg, **_call_kwargs(request, settings))
    return sim_action_out(convert.action_result_from_proto(response))


@router.post("/grasp", response_model=SimActionOut, summary="Grasp and lift", responses=_ERRORS)
async def grasp(request: Request, body: SimGraspBody, sim: SimDep, settings: SettingsDep):
    """Pre-grasp 10 cm back along the tool z axis, approach, close, lift, hold; on success the
    object stays in the hand until ``/sim/release``."""
    msg = convert.grasp_request_to_proto(body.pose.matrix(), body.width)
    response = await sim.Grasp(msg, **_call_kwargs(request, settings))
    return sim_action_out(convert.action_result_from_proto(response))


@router.post("/pick_and_place", response_model=SimActionOut, summary="Pick and place",
             responses=_ERRORS)  # fmt: skip
async def pick_and_place(
    request: Request, body: SimPickAndPlaceBody, sim: SimDep, settings: SettingsDep
):
    """Grasp at ``grasp_pose`` and release with the tool at ``place_pose``."""
    msg = convert.pick_and_place_request_to_proto(
        body.grasp_pose.matrix(), body.width, body.place_pose.matrix()
    )
    response = await sim.PickAndPlace(msg, **_call_kwargs(request, settings))
    return sim_action_out(convert.action_result_from_proto(response))


@router.post("/release", response_model=SimActionOut, summary="Open the gripper",
             responses=_ERRORS)  # fmt: skip
async def release(request: Request, sim: SimDep, settings: SettingsDep):
    """Open the gripper where it is (a held object drops) and return home."""
    response = await sim.Release(sim_pb2.ReleaseRequest(), **_call_kwargs(request, settings))
    return sim_action_out(convert.action_result_from_proto(response))


@router.get("/state", response_model=SimStateOut, summary="Current state", responses=_ERRORS)
async def state(request: Request, sim: SimDep, settings: SettingsDep):
    """Object poses and shapes, joints, gripper, tool pose, held object."""
    response = await sim.GetState(sim_pb2.GetStateRequest(), **_call_kwargs(request, settings))
    return sim_state_out(convert.sim_state_from_proto(response))
