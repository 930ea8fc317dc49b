"""``POST /plan``: one pushing-MPC step (4.4.2, B.4) and ``POST /search/evaluate``: the f and g
maps of one shelf scene (C.2, C.3).

``/plan`` body: ``{"objects": [/recognize objects], "task": {"kind": "moving", "goals": [{"id":
0, "position": [x, y, z]}]}, "options": {"num_sequences": 8, "dynamics_model": "physics"}}``.
Response: the push ``action`` (p, v) to execute now, the predicted next poses, the cost and the
counts and timings. Malformed tasks (unknown object id, goal off the table, K = 0) are 400 naming
the field; a missing dynamics service 503; no SQPD-Net checkpoint 400 (FAILED_PRECONDITION).
"""

from __future__ import annotations

import math

import numpy as np
from fastapi import APIRouter, Request

from sqmanip.rpc import convert
from sqmanip.rpc.errors import REQUEST_ID_KEY

from ..deps import PlannerDep, SearchDep, SettingsDep
from ..schemas import (
    ObjectPoseOut,
    PlanBody,
    PlanOut,
    SearchEvaluateBody,
    SearchEvaluateOut,
    pose_out,
)

router = APIRouter(tags=["planning"])

PLAN_TIMEOUT_S = 120.0
"""A physics-model step re-simulates every push (100 in 8-20 s; three rounds with grasping's
horizon 3) and may take longer than the default request timeout."""


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@router.post(
    "/plan",
    response_model=PlanOut,
    operation_id="planning-plan",
    summary="One pushing-MPC step: the push to execute now for a task",
    responses={
        400: {"description": "Malformed task or options (names the field)"},
        429: {"description": "Planner busy"},
        503: {"description": "Planner or dynamics service unavailable"},
        504: {"description": "No answer within the deadline"},
    },
)
async def plan(
    request: Request, body: PlanBody, planner: PlannerDep, settings: SettingsDep
) -> PlanOut:
    """Samples K pushes with the 4.5 sampler, predicts each with the dynamics model in one
    batched call, scores the task cost and returns the first push of the best sequence."""
    objects = [
        ([p.to_domain(f"objects[{i}].parts[{j}]") for j, p in enumerate(o.parts)], o.id)
        for i, o in enumerate(body.objects)
    ]
    msg = convert.plan_request_to_proto(objects, body.task.to_domain(), **body.options.to_kwargs())
    response = await planner.Plan(
        msg,
        timeout=max(PLAN_TIMEOUT_S, settings.request_timeout_s),
        metadata=((REQUEST_ID_KEY, request.state.request_id),),
    )
    r = convert.plan_response_from_proto(response)
    return PlanOut(
        has_action=r.action is not None,
        action=None if r.action is None else r.action.tolist(),
        pushed_id=r.pushed_id,
        predicted_next=[
            ObjectPoseOut(id=i, pose=pose_out(T))
            for i, T in zip(r.object_ids, r.predicted_next, strict=True)
        ],  # fmt: skip
        cost=_finite(r.cost),
        current_cost=_finite(r.current_cost),
        num_candidates=r.n_candidates,
        num_sampled=r.n_sampled,
        num_rejected_start=r.n_rejected_start,
        num_rejected_workspace=r.n_rejected_workspace,
        sequence=r.sequence.tolist(),
        timings_ms=r.timings_ms,
        dynamics_model=response.dynamics_model,
        solved=r.solved,
    )


@router.post(
    "/search/evaluate",
    response_model=SearchEvaluateOut,
    tags=["search"],
    operation_id="search-evaluate",
    summary="Existence f and graspability g over the target pose grid of one shelf scene",
    responses={
        400: {"description": "Bad input (names the field)"},
        503: {"description": "Search service unavailable"},
    },
)
async def search_evaluate(
    request: Request, body: SearchEvaluateBody, search: SearchDep, settings: SettingsDep
) -> SearchEvaluateOut:
    from sqmanip.geometry import PinholeCamera
    from sqmanip.search.shelf import ShelfSpec, TargetSpec

    from ..errors import HTTPError

    objects = [p.to_domain(f"objects[{i}]") for i, p in enumerate(body.objects)]
    target = shelf = camera = None
    if body.target is not None:
        target = TargetSpec(body.target.kind, tuple(body.target.size))
    if body.shelf is not None:
        shelf = ShelfSpec(**body.shelf.model_dump(exclude_none=True))
    if body.camera is not None:
        c = body.camera
        camera = PinholeCamera(fx=c.fx, fy=c.fy, cx=c.cx, cy=c.cy, width=c.width,
                               height=c.height, pose=c.pose.matrix())  # fmt: skip
    if body.target_visible and body.target_pose is None:
        raise HTTPError(400, "target_pose: required when target_visible is true", "target_pose")
    msg = convert.evaluate_request_to_proto(
        objects, target, shelf, camera, target_visible=body.target_visible,
        target_pose=None if body.target_pose is None else body.target_pose.matrix(),
        resolution=body.resolution, n_theta=body.n_theta,
    )  # fmt: skip
    response = await search.Evaluate(
        msg,
        timeout=settings.request_timeout_s,
        metadata=((REQUEST_ID_KEY, request.state.request_id),),
    )
    r = convert.evaluate_response_from_proto(response)
    return SearchEvaluateOut(
        shape=list(r.shape),
        f=np.asarray(r.f, dtype=np.float64).tolist(),
        g=np.asarray(r.g, dtype=np.float64).tolist(),
        g_m=np.asarray(r.g_m, dtype=np.float64).tolist(),
        grid_xy=np.asarray(r.grid_xy, dtype=np.float64).tolist(),
        resolution=r.resolution,
        objective=r.objective,
        timings_ms=r.timings_ms,
    )
