"""One error hierarchy for every domain package; the gRPC interceptor maps ``code`` to a status.

Domain code raises these (never gRPC or HTTP errors), so the same code runs in-process and
behind a server. ``code`` is the name of a ``grpc.StatusCode`` member.
"""

from __future__ import annotations


class SQManipError(Exception):
    """Base class; ``code`` names the gRPC status this error becomes on the wire."""

    code = "INTERNAL"

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class ValidationError(SQManipError, ValueError):
    """Bad input: names the field and the limit (-> INVALID_ARGUMENT, HTTP 400)."""

    code = "INVALID_ARGUMENT"


class NotFoundError(SQManipError, KeyError):
    """Unknown id (object, episode, scene) (-> NOT_FOUND, HTTP 404)."""

    code = "NOT_FOUND"

    def __str__(self) -> str:  # KeyError would add quotes
        return self.message


class PreconditionError(SQManipError):
    """The request is valid but the state does not allow it, e.g. an unreachable pose
    (-> FAILED_PRECONDITION, HTTP 400)."""

    code = "FAILED_PRECONDITION"


class ResourceExhaustedError(SQManipError):
    """Too much at once: too many points or concurrent requests (-> RESOURCE_EXHAUSTED, 429)."""

    code = "RESOURCE_EXHAUSTED"


class UnavailableError(SQManipError):
    """A dependency (another service) cannot be reached (-> UNAVAILABLE, HTTP 503)."""

    code = "UNAVAILABLE"


class UnimplementedError(SQManipError):
    """A method or option this build does not provide (-> UNIMPLEMENTED, HTTP 501)."""

    code = "UNIMPLEMENTED"


class DeadlineExceededError(SQManipError, TimeoutError):
    """A call to another service ran past its deadline (-> DEADLINE_EXCEEDED, HTTP 504)."""

    code = "DEADLINE_EXCEEDED"
