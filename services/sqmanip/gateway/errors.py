"""HTTP error mapping (ARCHITECTURE.md): every error is JSON ``{"detail": str, "field": str|null}``.

gRPC INVALID_ARGUMENT / FAILED_PRECONDITION -> 400, request-model errors -> 422, body too large
-> 413, wrong content type -> 415, NOT_FOUND -> 404, RESOURCE_EXHAUSTED -> 429, UNIMPLEMENTED ->
501, UNAVAILABLE -> 503, DEADLINE_EXCEEDED -> 504, anything else -> 500 with a request id that is
also in the gateway log.
"""

from __future__ import annotations

import logging
import re
import uuid

import grpc
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from sqmanip.errors import SQManipError

log = logging.getLogger("sqmanip.gateway")

STATUS_BY_CODE = {
    "INVALID_ARGUMENT": 400,
    "FAILED_PRECONDITION": 400,
    "OUT_OF_RANGE": 400,
    "NOT_FOUND": 404,
    "ALREADY_EXISTS": 409,
    "RESOURCE_EXHAUSTED": 429,
    "UNIMPLEMENTED": 501,
    "UNAVAILABLE": 503,
    "DEADLINE_EXCEEDED": 504,
    "CANCELLED": 499,
}

_FIELD = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_.\[\]]*)\s*:")


class HTTPError(Exception):
    """Raised by routes for errors decided in the gateway itself (413, 415, 400 parse errors)."""

    def __init__(self, status: int, detail: str, field: str | None = None) -> None:
        super().__init__(detail)
        self.status, self.detail, self.field = status, detail, field


def field_of(message: str) -> str | None:
    """The field a domain message names (``"points: expected ..."`` -> ``points``)."""
    m = _FIELD.match(message)
    return m.group(1) if m else None


def error_response(status: int, detail: str, field: str | None = None, **headers: str):
    return JSONResponse({"detail": detail, "field": field}, status_code=status, headers=headers)


def _rid(request: Request) -> str:
    return getattr(request.state, "request_id", None) or uuid.uuid4().hex[:12]


def install(app: FastAPI) -> None:
    """Register the exception handlers on ``app``."""

    @app.exception_handler(HTTPError)
    async def _http_error(request: Request, exc: HTTPError):
        return error_response(exc.status, exc.detail, exc.field)

    @app.exception_handler(SQManipError)
    async def _domain_error(request: Request, exc: SQManipError):
        status = STATUS_BY_CODE.get(exc.code, 500)
        if status == 500:
            rid = _rid(request)
            log.error("unmapped domain error rid=%s: %s", rid, exc)
            return error_response(500, f"internal error (request id {rid})")
        return error_response(status, exc.message, field_of(exc.message))

    @app.exception_handler(grpc.aio.AioRpcError)
    async def _rpc_error(request: Request, exc: grpc.aio.AioRpcError):
        code = exc.code().name
        status = STATUS_BY_CODE.get(code, 500)
        details = exc.details() or ""
        backend = getattr(request.state, "backend", "backend")
        if status == 503:
            return error_response(503, f"{backend} service unavailable: {details}")
        if status == 504:
            return error_response(504, f"{backend} service did not answer within the deadline")
        if status >= 500 and status not in (501,):
            rid = _rid(request)
            log.error("backend %s failed rid=%s: %s %s", backend, rid, code, details)
            return error_response(500, f"internal error in {backend} (request id {rid})")
        return error_response(status, details, field_of(details))

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError):
        errs = exc.errors()
        first = errs[0] if errs else {}
        loc = [str(p) for p in first.get("loc", ()) if p not in ("body", "query")]
        field = ".".join(loc) or None
        msg = first.get("msg", "invalid request")
        return error_response(422, f"{field}: {msg}" if field else msg, field)

    @app.exception_handler(StarletteHTTPException)
    async def _starlette(request: Request, exc: StarletteHTTPException):
        return error_response(exc.status_code, str(exc.detail))

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception):
        rid = _rid(request)
        log.exception("unhandled error rid=%s", rid)
        return error_response(500, f"internal error (request id {rid})")
