"""The FastAPI gateway: HTTP/JSON in front of the gRPC services.

``create_app(settings)`` builds an app (nothing is built at import). For uvicorn use factory
mode, ``uvicorn sqmanip.gateway.app:create_app --factory``, or ``python -m sqmanip.gateway``;
the module attribute ``app`` is built lazily on first access for tools that need an instance.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import AsyncIterator

import grpc
from fastapi import FastAPI
from fastapi.routing import APIRoute

from sqmanip.rpc.server import grpc_options

from . import errors
from .config import GatewaySettings
from .limits import BodySizeLimit, ConcurrencyLimit, RequestLog
from .routes import api_router
from .security import BearerAuth

log = logging.getLogger("sqmanip.gateway")


def _operation_id(route: APIRoute) -> str:
    return f"{route.tags[0]}-{route.name}" if route.tags else route.name


def create_app(settings: GatewaySettings | None = None) -> FastAPI:
    """Build the gateway for ``settings`` (default: from the environment)."""
    settings = settings or GatewaySettings()

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        opts = grpc_options(settings)
        app.state.channels = {
            name: grpc.aio.insecure_channel(settings.address(name), options=opts)
            for name in settings.gateway_services
        }
        try:
            yield
        finally:
            for ch in app.state.channels.values():
                await ch.close()

    app = FastAPI(
        title="SQManip gateway",
        version="0.1.0",
        description="Superquadric recognition, grasping, pushing and shelf search (HTTP <-> gRPC).",
        lifespan=lifespan,
        generate_unique_id_function=_operation_id,
    )
    app.state.settings = settings
    app.state.channels = {}
    errors.install(app)
    app.include_router(api_router)

    # Outermost first: request log, bearer token (when configured: nothing unauthenticated
    # reaches the limits or a route), body size, concurrency.
    app.add_middleware(
        ConcurrencyLimit,
        max_concurrent=settings.gateway_max_concurrent_requests,
        max_per_client=settings.gateway_max_concurrent_per_client,
    )
    app.add_middleware(BodySizeLimit, max_bytes=settings.gateway_max_body_bytes)
    app.add_middleware(BearerAuth, token=settings.token())
    app.add_middleware(RequestLog)
    return app


def __getattr__(name: str) -> FastAPI:
    if name == "app":
        global app
        app = create_app()
        return app
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
