"""The guarded gateway: bearer token, loopback-only binding, 413 and per-client 429, and the
SDK's token (issue 11, item 6)."""

from __future__ import annotations

import asyncio
import subprocess
import sys

import httpx
import pytest
import sqmanip_client as sdk
from fastapi.testclient import TestClient
from pydantic import SecretStr
from sqmanip.gateway.__main__ import main as gateway_main
from sqmanip.gateway.app import create_app
from sqmanip.gateway.config import GatewaySettings
from sqmanip.gateway.limits import ConcurrencyLimit
from sqmanip.gateway.security import bind_error, is_loopback
from sqmanip.launch import free_port
from sqmanip.perception.synthetic import make_single_view

TOKEN = "s3cret-token-for-tests-0123456789"
BIN = {"content-type": "application/octet-stream"}


@pytest.fixture(scope="module")
def scene():
    return make_single_view("box", seed=3)


@pytest.fixture(scope="module")
def guarded(gateway_settings):
    """The real gateway app in front of the real perception server, with a token."""
    settings = gateway_settings.model_copy(update={"api_token": SecretStr(TOKEN)})
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


def test_requests_without_or_with_a_wrong_token_are_401(guarded, scene) -> None:
    body = scene.points.astype("<f4").tobytes()
    r = guarded.post("/recognize", content=body, headers=BIN)
    assert r.status_code == 401
    assert "bearer token" in r.json()["detail"] and r.json()["field"] == "authorization"
    assert r.headers["www-authenticate"].startswith("Bearer")
    for wrong in ("Bearer " + TOKEN[:-1] + "x", "Bearer", TOKEN, "Basic " + TOKEN):
        r = guarded.post("/recognize", content=body, headers={**BIN, "authorization": wrong})
        assert r.status_code == 401, wrong
        assert r.json()["detail"] == "invalid bearer token"
    assert guarded.get("/openapi.json").status_code == 401  # every route but /healthz
    assert guarded.get("/healthz").status_code == 200  # liveness probe stays open


def test_requests_with_the_token_are_served(guarded, scene) -> None:
    auth = {"authorization": f"Bearer {TOKEN}"}
    r = guarded.post(
        "/recognize",
        content=scene.points.astype("<f4").tobytes(),
        headers={**BIN, **auth},
        params={"method": "mvbb"},
    )
    assert r.status_code == 200, r.text
    assert len(r.json()["objects"]) == 1
    assert guarded.get("/openapi.json", headers=auth).status_code == 200


def test_413_applies_to_authenticated_requests(guarded) -> None:
    limit = guarded.app.state.settings.gateway_max_body_bytes
    headers = {**BIN, "authorization": f"Bearer {TOKEN}"}
    r = guarded.post("/recognize", content=bytes(limit + 12), headers=headers)
    assert r.status_code == 413 and str(limit) in r.json()["detail"]
    # unauthenticated: refused before the size is even looked at
    r = guarded.post("/recognize", content=bytes(limit + 12), headers=BIN)
    assert r.status_code == 401


def test_sdk_sends_the_token_from_the_argument_or_the_environment(
    guarded, scene, monkeypatch
) -> None:
    monkeypatch.delenv("SQMANIP_API_TOKEN", raising=False)
    guarded.headers.pop("authorization", None)
    with pytest.raises(sdk.AuthenticationError) as err:
        sdk.Client("http://testserver", http_client=guarded).recognize(scene.points)
    assert err.value.status == 401 and err.value.field == "authorization"
    result = sdk.Client("http://testserver", http_client=guarded, token=TOKEN).recognize(
        scene.points, method="mvbb"
    )
    assert len(result.objects) == 1
    guarded.headers.pop("authorization", None)
    monkeypatch.setenv("SQMANIP_API_TOKEN", TOKEN)
    result = sdk.Client("http://testserver", http_client=guarded).recognize(
        scene.points, method="mvbb"
    )
    assert len(result.objects) == 1
    guarded.headers.pop("authorization", None)
    # the SDK's own httpx client carries the header too
    assert sdk.Client("http://127.0.0.1:9")._http.headers["authorization"] == f"Bearer {TOKEN}"


def test_short_tokens_are_rejected() -> None:
    with pytest.raises(ValueError, match="at least 16 characters"):
        GatewaySettings(api_token="short")


def test_bind_rules() -> None:
    for host in ("127.0.0.1", "127.0.0.53", "localhost", "::1", "[::1]"):
        assert is_loopback(host) and bind_error(host, None, False) is None
    for host in ("0.0.0.0", "", "::", "192.168.1.10", "gateway"):
        assert not is_loopback(host)
        assert "SQMANIP_API_TOKEN" in bind_error(host, None, False)
        assert bind_error(host, TOKEN, False) is None
        assert bind_error(host, None, True) is None


def test_gateway_refuses_to_bind_all_interfaces_without_a_token(monkeypatch, capsys) -> None:
    monkeypatch.delenv("SQMANIP_API_TOKEN", raising=False)
    monkeypatch.delenv("SQMANIP_GATEWAY_INSECURE", raising=False)
    assert gateway_main(["--host", "0.0.0.0", "--port", str(free_port())]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "refusing to bind the gateway to '0.0.0.0'" in err[0]
    assert "--insecure" in err[0]


def test_gateway_process_exits_with_one_error_line() -> None:
    env = {k: v for k, v in __import__("os").environ.items() if not k.startswith("SQMANIP_")}
    proc = subprocess.run(
        [sys.executable, "-m", "sqmanip.gateway", "--host", "0.0.0.0", "--port", "1"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("sqmanip.gateway: refusing to bind")


async def test_concurrency_limit_is_per_client_with_a_global_cap() -> None:
    release = asyncio.Event()

    async def slow_app(scope, receive, send) -> None:
        await release.wait()
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"ok"})

    app = ConcurrencyLimit(slow_app, max_concurrent=3, max_per_client=2)

    def client(addr: str) -> httpx.AsyncClient:
        transport = httpx.ASGITransport(app=app, client=(addr, 1234))
        return httpx.AsyncClient(transport=transport, base_url="http://gw")

    async with client("10.0.0.1") as a, client("10.0.0.2") as b:
        held = [asyncio.create_task(a.get("/recognize")) for _ in range(2)]
        await asyncio.sleep(0.05)
        r = await a.get("/recognize")  # a's third: over its own limit
        assert r.status_code == 429 and "from 10.0.0.1" in r.json()["detail"]
        assert r.headers["retry-after"] == "1"
        held.append(asyncio.create_task(b.get("/recognize")))  # b is not starved by a
        await asyncio.sleep(0.05)
        assert app.in_flight == 3 and app.per_client == {"10.0.0.1": 2, "10.0.0.2": 1}
        r = await b.get("/recognize")  # b under its own limit, but the global cap is reached
        assert r.status_code == 429 and "limit 3" in r.json()["detail"]
        release.set()
        assert [t.status_code for t in await asyncio.gather(*held)] == [200, 200, 200]
    assert app.in_flight == 0 and app.per_client == {}


def test_app_wires_the_per_client_limit(gateway_settings) -> None:
    settings = gateway_settings.model_copy(update={"gateway_max_concurrent_per_client": 3})
    app = create_app(settings)
    (mw,) = [m for m in app.user_middleware if m.cls is ConcurrencyLimit]
    assert mw.kwargs == {"max_concurrent": 64, "max_per_client": 3}
