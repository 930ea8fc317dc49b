"""Who may use the gateway: loopback by default, a bearer token for anything else.

- :func:`bind_error`: the gateway binds ``127.0.0.1`` by default; binding any other address
  (``0.0.0.0``, a LAN address, a host name) is refused unless a token is configured
  (``SQMANIP_API_TOKEN``) or the operator says ``--insecure`` / ``SQMANIP_GATEWAY_INSECURE=true``
  on purpose (e.g. inside a container whose port is published on the host's loopback only).
- :class:`BearerAuth`: when a token is configured, every request except ``GET /healthz`` (the
  liveness probe of launchers and compose) must carry ``Authorization: Bearer <token>``; the
  comparison is constant-time (:func:`hmac.compare_digest`) so the answer time does not leak how
  much of a guess was right. Missing or wrong token -> 401 ``{"detail", "field"}`` with
  ``WWW-Authenticate: Bearer``.
"""

from __future__ import annotations

import hmac
import ipaddress

from starlette.types import ASGIApp, Receive, Scope, Send

from .limits import _send_json

AUTH_EXEMPT_PATHS = ("/healthz",)
MIN_TOKEN_CHARS = 16


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback IPs (``127.0.0.0/8``, ``::1``); False for ``0.0.0.0``,
    ``""`` (all interfaces), other IPs and other host names."""
    if host.strip().lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip().strip("[]")).is_loopback
    except ValueError:
        return False


def bind_error(host: str, token: str | None, insecure: bool) -> str | None:
    """Why the gateway must not bind ``host`` (one line), or None when it may."""
    if is_loopback(host) or token or insecure:
        return None
    return (
        f"refusing to bind the gateway to {host!r} (not loopback) without a token: set "
        f"SQMANIP_API_TOKEN (at least {MIN_TOKEN_CHARS} characters; clients send "
        f"'Authorization: Bearer <token>'), or pass --insecure (SQMANIP_GATEWAY_INSECURE=true) "
        f"to serve without authentication on purpose"
    )


class BearerAuth:
    """Pure-ASGI bearer-token check (see the module docstring); a no-op without a token."""

    def __init__(self, app: ASGIApp, token: str | None) -> None:
        self.app = app
        self._expected = f"Bearer {token}".encode() if token else None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if (
            self._expected is None
            or scope["type"] != "http"
            or scope.get("path") in AUTH_EXEMPT_PATHS
        ):
            await self.app(scope, receive, send)
            return
        given = b""
        for key, value in scope.get("headers", ()):
            if key == b"authorization":
                given = value
                break
        if not given:
            await _send_json(
                send,
                401,
                "missing bearer token: send 'Authorization: Bearer <token>' (SQMANIP_API_TOKEN)",
                "authorization",
                headers=[(b"www-authenticate", b"Bearer")],
            )
            return
        if not hmac.compare_digest(given, self._expected):
            await _send_json(
                send,
                401,
                "invalid bearer token",
                "authorization",
                headers=[(b"www-authenticate", b'Bearer error="invalid_token"')],
            )
            return
        await self.app(scope, receive, send)
