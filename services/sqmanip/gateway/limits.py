"""Pure-ASGI guards applied before any route reads the body.

``BodySizeLimit`` answers 413 from the ``Content-Length`` header alone when it is over the
limit, and stops a chunked/undeclared body as soon as the bytes received pass the limit (the
rest is never read). ``ConcurrencyLimit`` answers 429 at once when a client already has
``max_per_client`` requests in progress, or all clients together ``max_concurrent``
(``/healthz`` and the docs are exempt).
"""

from __future__ import annotations

import json
import logging
import time
import uuid

from starlette.types import ASGIApp, Message, Receive, Scope, Send

log = logging.getLogger("sqmanip.gateway")

EXEMPT_PATHS = ("/healthz", "/docs", "/openapi.json", "/redoc", "/")


async def _send_json(
    send: Send,
    status: int,
    detail: str,
    field: str | None = None,
    headers: list[tuple[bytes, bytes]] | None = None,
) -> None:
    body = json.dumps({"detail": detail, "field": field}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"connection", b"close"),
                *(headers or ()),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


class _TooLarge(Exception):
    pass


class BodySizeLimit:
    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app, self.max_bytes = app, max_bytes

    def _detail(self, size: str) -> str:
        return f"request body is {size} bytes; the limit is {self.max_bytes} bytes"

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for key, value in scope.get("headers", ()):
            if key == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    await _send_json(send, 400, "content-length header is not an integer")
                    return
                if declared > self.max_bytes:
                    await _send_json(send, 413, self._detail(str(declared)), "body")
                    return
        received = 0
        started = False

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise _TooLarge
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except BaseException as exc:  # also inside an ExceptionGroup from a task group
            too_large = isinstance(exc, _TooLarge) or (
                isinstance(exc, BaseExceptionGroup) and exc.subgroup(_TooLarge) is not None
            )
            if not too_large or started:
                raise
            await _send_json(send, 413, self._detail(f"more than {self.max_bytes}"), "body")


class RequestLog:
    """One INFO line per request (method, path, body size, status, latency, request id); the id
    (``x-request-id`` header or a new one) is in ``scope["state"]``, sent to the backends and
    returned in the response header."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope.get("headers", ()))
        rid = (headers.get(b"x-request-id", b"").decode("latin-1") or uuid.uuid4().hex[:12])[:64]
        scope.setdefault("state", {})["request_id"] = rid
        start = time.perf_counter()
        status = 500

        async def send_with_id(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
                message.setdefault("headers", [])
                message["headers"] = [*message["headers"], (b"x-request-id", rid.encode())]
            await send(message)

        try:
            await self.app(scope, receive, send_with_id)
        finally:
            log.info(
                "method=%s path=%s size=%s status=%d ms=%.1f rid=%s",
                scope.get("method"),
                scope.get("path"),
                headers.get(b"content-length", b"-").decode("latin-1"),
                status,
                (time.perf_counter() - start) * 1e3,
                rid,
            )


class ConcurrencyLimit:
    """At most ``max_per_client`` requests in progress per client address and
    ``max_concurrent`` in all; beyond either, 429 at once (with ``retry-after: 1``) instead of
    queueing, so one busy client cannot take every slot from the others.

    The client is the TCP peer address (``scope["client"]``); ``X-Forwarded-For`` is not trusted
    (anyone can send it). Behind a reverse proxy every request has the proxy's address, and the
    per-client limit acts as a second global one."""

    def __init__(
        self, app: ASGIApp, max_concurrent: int, max_per_client: int | None = None
    ) -> None:
        self.app, self.max_concurrent = app, max_concurrent
        self.max_per_client = max_per_client or max_concurrent
        self.in_flight = 0
        self.per_client: dict[str, int] = {}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope.get("path") in EXEMPT_PATHS:
            await self.app(scope, receive, send)
            return
        client = (scope.get("client") or ("unknown", 0))[0]
        busy = self.per_client.get(client, 0)
        if busy >= self.max_per_client:
            await _send_json(
                send,
                429,
                f"too many concurrent requests from {client} (limit {self.max_per_client} per "
                f"client); retry",
                headers=[(b"retry-after", b"1")],
            )
            return
        if self.in_flight >= self.max_concurrent:
            await _send_json(
                send,
                429,
                f"too many concurrent requests (limit {self.max_concurrent}); retry",
                headers=[(b"retry-after", b"1")],
            )
            return
        self.in_flight += 1
        self.per_client[client] = busy + 1
        try:
            await self.app(scope, receive, send)
        finally:
            self.in_flight -= 1
            left = self.per_client[client] - 1
            if left:
                self.per_client[client] = left
            else:
                del self.per_client[client]
