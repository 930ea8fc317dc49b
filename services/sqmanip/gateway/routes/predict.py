"""``POST /predict``: next poses of pushed objects under K candidate pushes, in one call (Ch. 4).

Body: ``{"objects": [part, ...], "actions": [[px, py, pz, vx, vy, vz], ...], "model": "sqpdnet"}``
where each object is one superquadric in the JSON shape of a ``/recognize`` part (its ``pose``
is the object's current pose) and each action moves the tool tip to ``p`` and then to ``p + v``
(world frame, m). Response: ``poses[k][i]`` is object ``i`` after push ``k`` (position +
quaternion x, y, z, w). Errors: wrong shapes or values 400 naming the field, request-model errors
422, an unknown model 404, no checkpoint on the server 400 (FAILED_PRECONDITION, with the
command that trains one).
"""

from __future__ import annotations

import numpy as np
from fastapi import APIRouter, Request

from sqmanip.rpc import convert
from sqmanip.rpc.errors import REQUEST_ID_KEY

from ..deps import DynamicsDep, SettingsDep
from ..errors import HTTPError
from ..schemas import PredictBody, PredictResponse, pose_out

router = APIRouter(tags=["dynamics"])


@router.post(
    "/predict",
    response_model=PredictResponse,
    operation_id="dynamics-predict",
    summary="Predict the objects' next poses under K pushes",
    responses={
        400: {"description": "Bad input, or the model has no checkpoint (names the field)"},
        404: {"description": "Unknown model name"},
        503: {"description": "Dynamics service unavailable"},
        504: {"description": "Dynamics did not answer within the deadline"},
    },
)
async def predict(
    request: Request, body: PredictBody, dynamics: DynamicsDep, settings: SettingsDep
) -> PredictResponse:
    """SQPD-Net (B.3) evaluates every push in one batched pass; ``model: "physics"``
    re-simulates the pushes in PyBullet (4.7.4), all in one world (100 in 8-20 s)."""
    parts = [o.to_domain(f"objects[{i}]") for i, o in enumerate(body.objects)]
    actions = convert._array(body.actions, "actions", (None, 6)) if body.actions else None
    if actions is None:
        actions = np.zeros((0, 6))
    poses = np.stack([p.pose for p in parts]) if parts else np.zeros((0, 4, 4))
    params = np.stack([p.params() for p in parts]) if parts else np.zeros((0, 9))
    kinds = [p.kind_index for p in parts]
    msg = convert.predict_request_to_proto(poses, params, actions, kinds, model=body.model)
    if msg.ByteSize() > settings.grpc_max_message_bytes:
        raise HTTPError(413, "actions: too many actions for one message", "actions")
    response = await dynamics.Predict(
        msg,
        timeout=settings.request_timeout_s,
        metadata=((REQUEST_ID_KEY, request.state.request_id),),
        wait_for_ready=False,
    )
    nxt, failed = convert.predict_response_from_proto(response)
    return PredictResponse(
        model=response.model,
        num_actions=int(response.num_actions),
        num_objects=int(response.num_objects),
        poses=[[pose_out(T) for T in row] for row in nxt.astype(np.float64)],
        failed=None if failed is None else failed.tolist(),
        latency_ms=float(response.latency_ms),
    )
