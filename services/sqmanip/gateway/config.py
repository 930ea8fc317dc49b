"""Gateway settings: the stack's settings plus HTTP limits (env ``SQMANIP_GATEWAY_*``)."""

from __future__ import annotations

from pydantic import Field, field_validator

from sqmanip.settings import SERVICES, StackSettings


class GatewaySettings(StackSettings):
    gateway_services: list[str] = ["perception"]
    """Backends the gateway dials (names in ``sqmanip.settings.SERVICES``); the launcher sets it
    to the services it started (env ``SQMANIP_GATEWAY_SERVICES='["perception"]'``)."""
    gateway_max_body_bytes: int = Field(128 * 1024 * 1024, ge=1024)
    """Largest request body (bytes), checked before the body is read: 413 beyond it. 2 M points
    are 24 MB as binary and about 70 MB as JSON."""
    gateway_max_concurrent_requests: int = Field(64, ge=1)
    """Requests handled at once; more are answered 429 at once instead of queueing."""
    gateway_health_timeout_s: float = Field(1.0, gt=0)
    """Per-backend timeout of the gRPC health checks behind ``GET /healthz``."""

    @field_validator("gateway_services")
    @classmethod
    def _known_services(cls, value: list[str]) -> list[str]:
        unknown = [s for s in value if s not in SERVICES]
        if unknown:
            raise ValueError(f"gateway_services: unknown {unknown}; expected names from {SERVICES}")
        return value
