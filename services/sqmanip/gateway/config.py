"""Gateway settings: the stack's settings plus HTTP limits (env ``SQMANIP_GATEWAY_*``)."""

from __future__ import annotations

from pydantic import Field, SecretStr, field_validator

from sqmanip.settings import SERVICES, StackSettings


class GatewaySettings(StackSettings):
    gateway_services: list[str] = ["perception"]
    """Backends the gateway dials (names in ``sqmanip.settings.SERVICES``); the launcher sets it
    to the services it started (env ``SQMANIP_GATEWAY_SERVICES='["perception"]'``)."""
    gateway_max_body_bytes: int = Field(128 * 1024 * 1024, ge=1024)
    """Largest request body (bytes), checked before the body is read: 413 beyond it. 2 M points
    are 24 MB as binary and about 70 MB as JSON."""
    gateway_max_concurrent_requests: int = Field(64, ge=1)
    """Requests handled at once (all clients); more are answered 429 at once instead of
    queueing."""
    gateway_max_concurrent_per_client: int = Field(16, ge=1)
    """Requests handled at once for one client address; more are answered 429."""
    api_token: SecretStr | None = None
    """Bearer token (env ``SQMANIP_API_TOKEN``): when set, every route except ``/healthz``
    requires ``Authorization: Bearer <token>``; required to bind a non-loopback address."""
    gateway_insecure: bool = False
    """Serve on a non-loopback address without a token, on purpose (env
    ``SQMANIP_GATEWAY_INSECURE=true`` or ``--insecure``): e.g. inside a container whose port
    is published on the host's loopback only."""
    gateway_health_timeout_s: float = Field(1.0, gt=0)
    """Per-backend timeout of the gRPC health checks behind ``GET /healthz``."""

    @field_validator("api_token")
    @classmethod
    def _long_enough(cls, value: SecretStr | None) -> SecretStr | None:
        if value is not None and len(value.get_secret_value().strip()) < 16:
            raise ValueError("api_token (SQMANIP_API_TOKEN): expected at least 16 characters")
        return value

    def token(self) -> str | None:
        """The bearer token, or None when unset."""
        return None if self.api_token is None else self.api_token.get_secret_value().strip()

    @field_validator("gateway_services")
    @classmethod
    def _known_services(cls, value: list[str]) -> list[str]:
        unknown = [s for s in value if s not in SERVICES]
        if unknown:
            raise ValueError(f"gateway_services: unknown {unknown}; expected names from {SERVICES}")
        return value
