"""Ports, hosts and Zenoh endpoints for the whole stack, set in one place.

The launcher, compose file and tests read these; every value can be overridden with an
environment variable ``SQMANIP_<FIELD>`` (e.g. ``SQMANIP_PERCEPTION_PORT=6000``).
"""

from __future__ import annotations

from functools import lru_cache

from pydantic_settings import BaseSettings, SettingsConfigDict

SERVICES = ("perception", "grasp", "dynamics", "mpc", "search", "sim")


class StackSettings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="SQMANIP_", env_ignore_empty=True, extra="ignore")

    host: str = "127.0.0.1"
    """Address every gRPC service binds and the gateway dials."""
    service_hosts: dict[str, str] = {}
    """Per-service host to dial instead of ``host`` (compose: ``{"perception": "perception"}``,
    env ``SQMANIP_SERVICE_HOSTS='{"perception": "perception"}'``)."""
    gateway_host: str = "127.0.0.1"
    gateway_port: int = 8080
    viewer_port: int = 8081
    perception_port: int = 50051
    grasp_port: int = 50052
    dynamics_port: int = 50053
    mpc_port: int = 50054
    search_port: int = 50055
    sim_port: int = 50056
    zenoh_endpoint: str = "tcp/127.0.0.1:7447"
    """Zenoh endpoint the stack's sessions listen on / connect to."""
    zenoh_enabled: bool = True
    grpc_max_message_bytes: int = 64 * 1024 * 1024
    """gRPC max send/receive size on servers and channels (64 MiB ~ 2.7 M float32 points)."""
    request_timeout_s: float = 30.0
    torch_threads: int = 2

    def port(self, service: str) -> int:
        if service not in SERVICES:
            raise ValueError(f"unknown service {service!r}; expected one of {SERVICES}")
        return getattr(self, f"{service}_port")

    def address(self, service: str) -> str:
        return f"{self.service_hosts.get(service, self.host)}:{self.port(service)}"


@lru_cache
def get_settings() -> StackSettings:
    """Cached settings built from the environment (tests build their own ``StackSettings``)."""
    return StackSettings()
