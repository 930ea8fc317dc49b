"""``POST /recognize``: a point cloud in, recognized superquadric objects out.

Bodies (by ``Content-Type``):

- ``application/json``: ``{"points": [[x,y,z],...], "colors", "labels", "viewpoint",
  "workspace": {"min","max"}, "options": {...}}``;
- ``application/octet-stream``: N x 3 float32 little-endian (12 N bytes), options as query
  parameters (``viewpoint=x,y,z``, ``workspace=x0,y0,z0,x1,y1,z1``, ``method=...``);
- ``application/ply`` / ``model/ply`` (or a ``multipart/form-data`` upload with a ``file`` part):
  PLY ascii or binary_little_endian with ``x y z [red green blue]``, options as query parameters.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from fastapi import APIRouter, Query, Request, Response
from pydantic import ValidationError as PydanticValidationError

from sqmanip.perception.types import RecognizeRequest, Workspace
from sqmanip.rpc import convert
from sqmanip.rpc.errors import REQUEST_ID_KEY

from ..deps import PerceptionDep, SettingsDep
from ..errors import HTTPError
from ..ply import parse_ply
from ..schemas import RecognizeBody, RecognizeOptionsIn, RecognizeResponse, scene_to_response

router = APIRouter(tags=["perception"])

JSON_TYPES = ("application/json",)
BINARY_TYPES = ("application/octet-stream",)
PLY_TYPES = ("application/ply", "model/ply", "application/x-ply", "text/ply")
MULTIPART_TYPES = ("multipart/form-data",)
ACCEPTED = JSON_TYPES + BINARY_TYPES + PLY_TYPES + MULTIPART_TYPES

_BODY_DOC = {
    "requestBody": {
        "required": True,
        "content": {
            "application/json": {"schema": {"$ref": "#/components/schemas/RecognizeBody"}},
            "application/octet-stream": {
                "schema": {"type": "string", "format": "binary"},
                "description": "N x 3 float32 little-endian; options as query parameters.",
            },
            "application/ply": {"schema": {"type": "string", "format": "binary"}},
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "properties": {"file": {"type": "string", "format": "binary"}},
                    "required": ["file"],
                }
            },
        },
    }
}


def _floats(text: str | None, n: int, name: str) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise HTTPError(422, f"{name}: expected {n} comma-separated numbers", name) from None
    if len(values) != n or not all(np.isfinite(values)):
        raise HTTPError(422, f"{name}: expected {n} finite comma-separated numbers", name)
    return values


def _mime(request: Request) -> str:
    return request.headers.get("content-type", "").split(";")[0].strip().lower()


async def _json_request(body: bytes) -> RecognizeRequest:
    try:
        parsed = RecognizeBody.model_validate_json(body)
    except PydanticValidationError as exc:
        first = exc.errors()[0]
        if first["type"] == "json_invalid":
            raise HTTPError(400, f"body: not valid JSON ({first['msg']})", "body") from None
        if first["type"] == "model_type":
            raise HTTPError(422, "body: expected a JSON object", "body") from None
        field = ".".join(str(p) for p in first["loc"][:1]) or "body"
        raise HTTPError(422, f"{field}: {first['msg']}", field) from None
    points = convert._as_points(parsed.points, "points")  # shape check with the field named
    has_labels = parsed.labels is not None
    return RecognizeRequest(
        points=points,
        colors=None if parsed.colors is None else convert._as_points(parsed.colors, "colors"),
        labels=None if parsed.labels is None else np.asarray(parsed.labels, dtype=np.int64),
        viewpoint=None if parsed.viewpoint is None else np.asarray(parsed.viewpoint),
        workspace=None
        if parsed.workspace is None
        else Workspace(min=parsed.workspace.min, max=parsed.workspace.max),
        options=parsed.options.to_domain(has_labels=has_labels),
    )


async def _ply_bytes(request: Request, mime: str, body: bytes) -> bytes:
    if mime not in MULTIPART_TYPES:
        return body
    form = await request.form()
    upload = form.get("file")
    if upload is None or isinstance(upload, str):
        raise HTTPError(422, "file: expected a PLY file in the multipart part 'file'", "file")
    return await upload.read()


@router.post(
    "/recognize",
    response_model=RecognizeResponse,
    operation_id="perception-recognize",
    summary="Recognize objects as superquadrics",
    openapi_extra=_BODY_DOC,
    responses={
        400: {"description": "Bad input (names the field and the limit)"},
        413: {"description": "Body or cloud too large"},
        415: {"description": "Unsupported content type"},
        503: {"description": "Perception service unavailable"},
        504: {"description": "Perception did not answer within the deadline"},
    },
)
async def recognize(
    request: Request,
    perception: PerceptionDep,
    settings: SettingsDep,
    method: Literal["optimization", "network", "hybrid", "mvbb"] = "optimization",
    segmentation: Literal["clustering", "color", "labels", "network"] | None = None,
    points_per_segment: int = Query(300, ge=1, le=2**32 - 1),
    remove_support: bool = True,
    amodal: bool = True,
    deformable: bool = True,
    seed: int = Query(0, ge=-(2**63), le=2**63 - 1),
    viewpoint: str | None = Query(None, description="x,y,z sensor origin (binary/PLY bodies)"),
    workspace: str | None = Query(None, description="x0,y0,z0,x1,y1,z1 crop box (binary/PLY)"),
) -> RecognizeResponse:
    """Segment the cloud and fit (deformable) superquadrics to each object (thesis 3.5).

    Query options apply to binary and PLY bodies; a JSON body carries its own ``options``.
    """
    mime = _mime(request)
    if mime not in ACCEPTED:
        raise HTTPError(
            415,
            f"content-type {mime or '(none)'!r} is not supported; use one of {list(ACCEPTED)}",
            "content-type",
        )
    body = await request.body()
    if mime in JSON_TYPES:
        req = await _json_request(body)
    else:
        if mime in BINARY_TYPES:
            if len(body) % 12:
                raise HTTPError(
                    400,
                    f"body: expected N x 3 float32 little-endian (12 bytes per point), "
                    f"got {len(body)} bytes",
                    "body",
                )
            points, colors = np.frombuffer(body, dtype="<f4").reshape(-1, 3), None
        else:
            cloud = parse_ply(await _ply_bytes(request, mime, body))
            points, colors = cloud.points, cloud.colors
        box = _floats(workspace, 6, "workspace")
        opts = RecognizeOptionsIn(
            method=method,
            segmentation=segmentation,
            points_per_segment=points_per_segment,
            remove_support=remove_support,
            amodal=amodal,
            deformable=deformable,
            seed=seed,
        )
        vp = _floats(viewpoint, 3, "viewpoint")
        req = RecognizeRequest(
            points=points,
            colors=colors,
            viewpoint=None if vp is None else np.asarray(vp),
            workspace=None if box is None else Workspace(min=box[:3], max=box[3:]),
            options=opts.to_domain(has_labels=False),
        )
    msg = convert.recognize_request_to_proto(req)
    size = msg.ByteSize()
    if size > settings.grpc_max_message_bytes:
        raise HTTPError(
            413,
            f"points: the cloud needs {size} bytes on the wire; the limit is "
            f"{settings.grpc_max_message_bytes} bytes (about "
            f"{settings.grpc_max_message_bytes // 12} points without colors)",
            "points",
        )
    response = await perception.Recognize(
        msg,
        timeout=settings.request_timeout_s,
        metadata=((REQUEST_ID_KEY, request.state.request_id),),
        wait_for_ready=False,
    )
    # Serialized here in one pass (pydantic-core): returning the model would have FastAPI dump
    # it to a dict, validate that against ``response_model`` again and JSON-encode it in Python,
    # several ms for the point indices of a 40,000-point cloud. The schema stays documented.
    scene = scene_to_response(convert.scene_from_proto(response.scene))
    return Response(scene.model_dump_json(), media_type="application/json")
