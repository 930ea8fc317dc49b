"""Exceptions raised by the SDK; every HTTP error carries ``status`` and the server's ``detail``."""

from __future__ import annotations

import builtins


class SQManipError(Exception):
    """Base class of every SDK error."""

    def __init__(self, message: str, *, status: int | None = None, detail: str = "",
                 field: str | None = None) -> None:  # fmt: skip
        super().__init__(message)
        self.status = status
        """HTTP status code, or None when no response arrived."""
        self.detail = detail or message
        """The server's explanation (names the field and the limit for 4xx)."""
        self.field = field
        """The request field at fault, when the server named one."""


class BadRequestError(SQManipError):
    """4xx: the request is wrong (bad shape, NaN, too many points, unsupported type, ...)."""


class NotFoundError(BadRequestError):
    """404: unknown id."""


class AuthenticationError(BadRequestError):
    """401: the gateway requires a bearer token (``Client(url, token=...)`` or
    ``$SQMANIP_API_TOKEN``) and none or a wrong one was sent."""


class TooManyRequestsError(BadRequestError):
    """429: the service is busy; retry later."""


class ServerError(SQManipError):
    """5xx: the server failed (500 carries a request id that is in the server's log)."""


class ServiceUnavailableError(ServerError):
    """503: a backend service is down or unreachable."""


class GatewayTimeoutError(ServerError, builtins.TimeoutError):
    """504: a backend did not answer within its deadline."""


class TimeoutError(SQManipError, builtins.TimeoutError):  # noqa: A001 - the SDK's own timeout
    """No response from the gateway within the client's ``timeout``."""


class ConnectionError(SQManipError, builtins.ConnectionError):  # noqa: A001
    """The gateway could not be reached."""


def from_response(status: int, payload: object, text: str) -> SQManipError:
    """Error for an HTTP error response (JSON ``{"detail", "field"}`` or plain text)."""
    detail, field = text, None
    if isinstance(payload, dict):
        detail = str(payload.get("detail", text))
        field = payload.get("field") if isinstance(payload.get("field"), str) else None
    cls: type[SQManipError]
    if status == 401:
        cls = AuthenticationError
    elif status == 404:
        cls = NotFoundError
    elif status == 429:
        cls = TooManyRequestsError
    elif 400 <= status < 500:
        cls = BadRequestError
    elif status == 503:
        cls = ServiceUnavailableError
    elif status == 504:
        cls = GatewayTimeoutError
    else:
        cls = ServerError
    return cls(f"HTTP {status}: {detail}", status=status, detail=detail, field=field)
