"""``POST /grasps``: ranked parallel-jaw grasps on recognized objects (thesis 3.4, 3.6.3).

Two inputs (JSON):

- ``{"objects": [...], "target_id": 3}``: objects exactly as ``POST /recognize`` returns them;
  grasps for ``target_id`` (or for every object when it is omitted), the others are obstacles.
  The support plane defaults to a table at z = 0.
- ``{"points": [[x, y, z], ...], "target_id": 0}`` (+ ``colors``, ``labels``, ``viewpoint``,
  ``workspace``, ``recognize`` options): the gateway sends the cloud to perception first, then
  plans for the recognized object with that id, or for every recognized object; the response
  includes the recognized ``objects`` and the support plane perception found. The target's
  recognized points are its observed points (``options.score = "uncertainty"``).

Response: ``{"targets": [{"target_id", "grasps": [{"pose": {"position", "orientation"
(x, y, z, w)}, "width" (m), "score", "contacts": [[x, y, z], [x, y, z]]}], "stats"}], ...}``.
Errors: bad values 400 naming the field, request-model errors 422, unknown ``target_id`` 404.
"""

from __future__ import annotations

import numpy as np
from fastapi import APIRouter, Request

from sqmanip.errors import NotFoundError, ValidationError
from sqmanip.grasping.types import Environment
from sqmanip.perception.types import RecognizedObject, RecognizeRequest, Scene, Workspace
from sqmanip.rpc import convert
from sqmanip.rpc.errors import REQUEST_ID_KEY
from sqmanip.v1 import grasp_pb2

from ..deps import GraspDep, SettingsDep
from ..errors import HTTPError
from ..schemas import (
    GraspsBody,
    GraspsResponse,
    SupportPlaneOut,
    object_out,
    target_grasps_out,
)

router = APIRouter(tags=["grasp"])


def _call_kwargs(request: Request, settings) -> dict:
    return {
        "timeout": settings.request_timeout_s,
        "metadata": ((REQUEST_ID_KEY, request.state.request_id),),
        "wait_for_ready": False,
    }


async def _recognize(request: Request, body: GraspsBody, settings) -> tuple[Scene, np.ndarray]:
    """Send the body's cloud to perception; returns the scene and the points."""
    from ..deps import get_perception

    perception = await get_perception(request)
    points = convert._as_points(body.points, "points")
    req = RecognizeRequest(
        points=points,
        colors=None if body.colors is None else convert._as_points(body.colors, "colors"),
        labels=None if body.labels is None else np.asarray(body.labels, dtype=np.int64),
        viewpoint=None if body.viewpoint is None else np.asarray(body.viewpoint),
        workspace=None
        if body.workspace is None
        else Workspace(min=body.workspace.min, max=body.workspace.max),
        options=body.recognize.to_domain(has_labels=body.labels is not None),
    )
    msg = convert.recognize_request_to_proto(req)
    if msg.ByteSize() > settings.grpc_max_message_bytes:
        raise HTTPError(
            413,
            f"points: the cloud needs {msg.ByteSize()} bytes on the wire; the limit is "
            f"{settings.grpc_max_message_bytes} bytes",
            "points",
        )
    response = await perception.Recognize(msg, **_call_kwargs(request, settings))
    request.state.backend = "grasp"
    return convert.scene_from_proto(response.scene), points


@router.post(
    "/grasps",
    response_model=GraspsResponse,
    operation_id="grasp-plan",
    summary="Plan grasps on recognized objects (or on a point cloud)",
    responses={
        400: {"description": "Bad input (names the field)"},
        404: {"description": "target_id is not a (recognized) object id"},
        503: {"description": "Grasp (or perception) service unavailable"},
        504: {"description": "A backend did not answer within the deadline"},
    },
)
async def plan_grasps(
    request: Request, body: GraspsBody, grasp: GraspDep, settings: SettingsDep
) -> GraspsResponse:
    """Antipodal (Algorithm 1) or rule-based (B.5 / C.3) grasps, collision-checked against the
    support plane, ``boxes`` and the other objects and checked by the Panda IK, ranked by
    ``-z^T z_t`` (minus ``beta u`` for ``score: "uncertainty"``)."""
    if (body.objects is None) == (body.points is None):
        raise HTTPError(422, "body: give either objects or points (a cloud), not both", "body")
    options = body.options.to_domain()
    gripper = body.gripper.to_domain() if body.gripper is not None else None
    boxes = tuple(b.to_domain(f"boxes[{i}]") for i, b in enumerate(body.boxes))
    plane_given = "support_plane" in body.model_fields_set
    recognized: list[RecognizedObject] | None = None
    cloud = None
    if body.objects is not None:
        objects = [
            RecognizedObject(
                id=o.id,
                parts=[p.to_domain(f"objects[{i}].parts[{j}]") for j, p in enumerate(o.parts)],
                point_indices=np.asarray(o.point_indices or [], dtype=np.int64),
            )
            for i, o in enumerate(body.objects)
        ]
        plane = (
            (body.support_plane.normal, body.support_plane.offset) if body.support_plane else None
        )
        if not plane_given:
            plane = ((0.0, 0.0, 1.0), 0.0)
    else:
        scene, cloud = await _recognize(request, body, settings)
        objects = recognized = list(scene.objects)
        sp = scene.support_plane
        plane = None if sp is None else (tuple(sp.normal), float(sp.offset))
        if plane_given:
            plane = (
                None
                if body.support_plane is None
                else (body.support_plane.normal, body.support_plane.offset)
            )
    ids = [o.id for o in objects]
    if body.target_id is not None:
        if body.target_id not in ids:
            raise NotFoundError(f"target_id: no object with id {body.target_id} (objects: {ids})")
        targets = [body.target_id]
    else:
        targets = ids
    try:
        env = Environment(
            support_normal=None if plane is None else tuple(plane[0]),
            support_offset=0.0 if plane is None else float(plane[1]),
            boxes=boxes,
        )
    except ValidationError as exc:
        raise ValidationError(f"support_plane: {exc.message}") from None
    observed_all = None
    if body.observed_points is not None:
        if len(targets) != 1:
            raise ValidationError("observed_points: give target_id too (they belong to one object)")
        observed_all = convert._as_points(body.observed_points, "observed_points")
    base = convert.plan_grasps_request_to_proto(
        objects[0].parts, environment=env, gripper=gripper, options=options,
        check_reachability=body.options.check_reachability,
    )  # fmt: skip
    base.ClearField("objects")
    base.objects.extend(convert.recognized_object_to_proto(o) for o in objects)
    results = []
    for tid in targets:
        msg = grasp_pb2.PlanGraspsRequest()
        msg.CopyFrom(base)
        msg.target_id = tid
        observed = observed_all
        if observed is None and cloud is not None:
            idx = np.asarray(objects[ids.index(tid)].point_indices, dtype=np.int64)
            if idx.size:
                observed = cloud[idx]
        if observed is not None:
            msg.observed_points.CopyFrom(convert.cloud_to_proto(observed))
        request.state.backend = "grasp"
        response = await grasp.Plan(msg, **_call_kwargs(request, settings))
        results.append(target_grasps_out(tid, convert.plan_result_from_proto(response)))
    return GraspsResponse(
        targets=results,
        objects=None if recognized is None else [object_out(o) for o in recognized],
        support_plane=None
        if plane is None
        else SupportPlaneOut(normal=tuple(float(v) for v in plane[0]), offset=float(plane[1])),
    )
