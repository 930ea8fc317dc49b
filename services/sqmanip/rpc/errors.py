"""One grpc.aio server interceptor: domain exceptions -> gRPC status codes, one log line per call.

Servicer methods contain no try/except: :class:`sqmanip.errors.SQManipError` subclasses become the
status named by their ``code`` (``ValidationError`` -> INVALID_ARGUMENT, ...), a plain
``ValueError`` becomes INVALID_ARGUMENT, ``KeyError`` NOT_FOUND, ``TimeoutError``
DEADLINE_EXCEEDED, ``NotImplementedError`` UNIMPLEMENTED; anything else is logged with its
traceback and a request id and answered INTERNAL with only that id (no internals leak).
Clients map statuses back with :func:`error_from_status`.
"""

from __future__ import annotations

import asyncio
import logging
import time
import uuid
from collections.abc import Awaitable, Callable
from typing import Any

import grpc

from sqmanip import errors

log = logging.getLogger("sqmanip.rpc")

REQUEST_ID_KEY = "x-request-id"
_QUIET_PREFIX = "/grpc.health.v1.Health/"  # probes every 0.1-10 s: DEBUG, not INFO

_ERRORS_BY_CODE: dict[str, type[errors.SQManipError]] = {
    "INVALID_ARGUMENT": errors.ValidationError,
    "NOT_FOUND": errors.NotFoundError,
    "FAILED_PRECONDITION": errors.PreconditionError,
    "RESOURCE_EXHAUSTED": errors.ResourceExhaustedError,
    "UNAVAILABLE": errors.UnavailableError,
    "UNIMPLEMENTED": errors.UnimplementedError,
    "DEADLINE_EXCEEDED": errors.DeadlineExceededError,
}


def status_for(exc: BaseException) -> tuple[grpc.StatusCode, str]:
    """The gRPC status and message for a domain exception (INTERNAL for unexpected ones)."""
    if isinstance(exc, errors.SQManipError):
        code = getattr(grpc.StatusCode, exc.code, grpc.StatusCode.INTERNAL)
        return code, exc.message
    if isinstance(exc, KeyError):
        return grpc.StatusCode.NOT_FOUND, f"not found: {exc.args[0] if exc.args else exc}"
    if isinstance(exc, ValueError):
        return grpc.StatusCode.INVALID_ARGUMENT, str(exc) or type(exc).__name__
    if isinstance(exc, TimeoutError):
        return grpc.StatusCode.DEADLINE_EXCEEDED, str(exc) or "deadline exceeded"
    if isinstance(exc, NotImplementedError):
        return grpc.StatusCode.UNIMPLEMENTED, str(exc) or "not implemented"
    return grpc.StatusCode.INTERNAL, "internal error"


def error_from_status(code: grpc.StatusCode, message: str) -> errors.SQManipError:
    """Client side: a status back into the matching domain exception (base class if unknown)."""
    cls = _ERRORS_BY_CODE.get(code.name, errors.SQManipError)
    err = cls(message)
    if cls is errors.SQManipError:
        err.code = code.name
    return err


def _request_id(context: grpc.aio.ServicerContext) -> str:
    for key, value in context.invocation_metadata() or ():
        if key == REQUEST_ID_KEY and value:
            return str(value)[:64]
    return uuid.uuid4().hex[:12]


def _size(message: Any) -> int:
    try:
        return int(message.ByteSize())
    except Exception:  # noqa: BLE001 - size is informative only
        return -1


class _Undecodable:
    """Stands in for a request whose bytes are not the method's protobuf message: the handler
    answers INVALID_ARGUMENT instead of grpc's own UNKNOWN ("Unexpected DecodeError")."""

    def __init__(self, error: str) -> None:
        self.error = error

    def ByteSize(self) -> int:  # noqa: N802 - protobuf's name, for the request log
        return -1


def _safe_deserializer(deserializer: Callable[[bytes], Any] | None):
    if deserializer is None:
        return None

    def deserialize(data: bytes) -> Any:
        try:
            return deserializer(data)
        except Exception as exc:  # noqa: BLE001 - DecodeError and friends: a client's bad bytes
            return _Undecodable(f"{type(exc).__name__}: {exc}")

    return deserialize


class ErrorMappingInterceptor(grpc.aio.ServerInterceptor):
    """Wraps every unary-unary handler: maps exceptions to statuses and logs one INFO line
    ``method=... size=... status=... ms=... rid=...`` per request."""

    async def intercept_service(
        self,
        continuation: Callable[[grpc.HandlerCallDetails], Awaitable[grpc.RpcMethodHandler]],
        handler_call_details: grpc.HandlerCallDetails,
    ) -> grpc.RpcMethodHandler:
        handler = await continuation(handler_call_details)
        if handler is None or handler.unary_unary is None:
            return handler  # streaming (health Watch, reflection): passed through untouched
        inner = handler.unary_unary
        method = handler_call_details.method

        async def wrapper(request: Any, context: grpc.aio.ServicerContext) -> Any:
            start = time.perf_counter()
            rid = _request_id(context)
            status = "OK"
            try:
                if isinstance(request, _Undecodable):
                    raise errors.ValidationError(
                        f"request: not a valid message for {method} ({request.error})"
                    )
                result = inner(request, context)
                if asyncio.iscoroutine(result):
                    result = await result
                return result
            except (asyncio.CancelledError, grpc.aio.AbortError):
                status = "CANCELLED/ABORTED"
                raise
            except Exception as exc:  # noqa: BLE001 - this is the one mapping point
                code, message = status_for(exc)
                status = code.name
                if code is grpc.StatusCode.INTERNAL:
                    log.exception("unhandled error in %s rid=%s", method, rid)
                    message = f"internal error (request id {rid})"
                await context.abort(code, message)
            finally:
                log.log(
                    logging.DEBUG if method.startswith(_QUIET_PREFIX) else logging.INFO,
                    "method=%s size=%d status=%s ms=%.1f rid=%s",
                    method,
                    _size(request),
                    status,
                    (time.perf_counter() - start) * 1e3,
                    rid,
                )

        return grpc.unary_unary_rpc_method_handler(
            wrapper,
            request_deserializer=_safe_deserializer(handler.request_deserializer),
            response_serializer=handler.response_serializer,
        )
