"""``GET /healthz`` (each backend's gRPC health) and the ``/`` landing page."""

from __future__ import annotations

import asyncio
import html

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse

from sqmanip.rpc.health_probe import check_async

from ..deps import SettingsDep
from ..schemas import HealthOut, ServiceHealth

router = APIRouter(tags=["health"])

_INDEX = """<!doctype html>
<html><head><meta charset="utf-8"><title>SQManip gateway</title></head>
<body style="font-family: sans-serif; max-width: 40em; margin: 2em auto">
<h1>SQManip gateway</h1>
<p>Superquadric recognition, grasping, pushing and shelf search behind one HTTP API.</p>
<ul>
<li><a href="/docs">API documentation (OpenAPI / Swagger UI)</a></li>
<li><a href="/openapi.json">OpenAPI schema</a></li>
<li><a href="/healthz">Health of the backends</a></li>
<li><a href="{viewer}">3D viewer</a> (live scenes, grasps, pushes and shelf search; started by
<code>sqmanip up</code>)</li>
</ul>
</body></html>
"""


@router.get("/healthz", operation_id="health-healthz")
async def healthz(settings: SettingsDep) -> HealthOut:
    """The gateway is up; ``services`` gives each backend's gRPC health (``degraded`` if any is
    not SERVING). Always 200 while the gateway itself runs."""
    names = list(settings.gateway_services)
    addresses = [settings.address(n) for n in names]
    statuses = await asyncio.gather(
        *(check_async(a, timeout=settings.gateway_health_timeout_s) for a in addresses)
    )
    services = {
        n: ServiceHealth(address=a, status=s)
        for n, a, s in zip(names, addresses, statuses, strict=True)
    }
    ok = all(s.status == "SERVING" for s in services.values())
    return HealthOut(status="ok" if ok else "degraded", services=services)


@router.get("/", response_class=HTMLResponse, include_in_schema=False)
async def index(request: Request, settings: SettingsDep) -> str:
    """Landing page: links to the docs, the health and the viewer (same host, viewer port)."""
    host = request.url.hostname or settings.gateway_host
    host = f"[{host}]" if ":" in host else host
    viewer = f"http://{host}:{settings.viewer_port}/"
    return _INDEX.replace("{viewer}", html.escape(viewer, quote=True))
