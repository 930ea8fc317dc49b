"""The composed stack (compose/docker-compose.yml) for the tests in this directory (issue 11).

One stack per session, on a unique compose project name with free 127.0.0.1 ports for the
gateway and the Zenoh router, brought up with whichever compose is installed (v2 ``docker
compose up -d --wait``; v1 ``docker-compose up -d``, which waits for the dependencies' health
itself, then polling every container's health) and always torn down with ``down -v``.

The tests skip, and the reason is printed at the end of the run, only when Docker cannot run at
all (no client, no daemon, no permission, no compose) or the image is not built (run
``compose/build.sh`` or ``.ci/docker.sh``). Once Docker runs, a stack that does not come up is a
failure with the containers' logs, never a skip.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import socket
import subprocess
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
COMPOSE_FILE = REPO / "compose" / "docker-compose.yml"
IMAGE = os.environ.get("SQMANIP_IMAGE", "sqmanip:latest")
UP_TIMEOUT_S = 420.0
"""Generous: on a busy 2-core machine eight containers importing torch take minutes."""
SERVICES = ("zenoh", "perception", "grasp", "dynamics", "mpc", "search", "sim", "gateway")

_skip_reason: list[str] = []


def _run(cmd: list[str], timeout: float = 60.0, **kw) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, **kw)


def compose_command() -> list[str] | None:
    """``["docker", "compose"]`` (v2) if available, else ``["docker-compose"]`` (v1), else None."""
    if shutil.which("docker"):
        try:
            if _run(["docker", "compose", "version"], timeout=20).returncode == 0:
                return ["docker", "compose"]
        except (OSError, subprocess.TimeoutExpired):
            pass
    if shutil.which("docker-compose"):
        return ["docker-compose"]
    return None


def docker_unavailable_reason() -> str | None:
    """Why the compose tests cannot run here, or None when they can."""
    if shutil.which("docker") is None:
        return "no docker client (run .ci/docker.sh)"
    try:
        info = _run(["docker", "info", "--format", "{{.ServerVersion}}"], timeout=30)
    except subprocess.TimeoutExpired:
        return "docker info timed out"
    if info.returncode != 0:
        return f"docker daemon not usable: {(info.stderr or info.stdout).strip()[:200]}"
    if compose_command() is None:
        return "neither `docker compose` (v2) nor `docker-compose` (v1) is installed"
    if _run(["docker", "image", "inspect", IMAGE], timeout=30).returncode != 0:
        return f"image {IMAGE} is not built (run compose/build.sh)"
    return None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclasses.dataclass
class ComposeStack:
    compose: list[str]
    project: str
    env: dict[str, str]
    gateway_port: int
    zenoh_port: int
    up_seconds: float = 0.0

    @property
    def gateway_url(self) -> str:
        return f"http://127.0.0.1:{self.gateway_port}"

    @property
    def zenoh_endpoint(self) -> str:
        return f"tcp/127.0.0.1:{self.zenoh_port}"

    def run(self, *args: str, timeout: float = 120.0, check: bool = True):
        cmd = [*self.compose, "-p", self.project, "-f", str(COMPOSE_FILE), *args]
        res = _run(cmd, timeout=timeout, env=self.env)
        if check and res.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed ({res.returncode}): {res.stderr[-2000:]}")
        return res

    def containers(self) -> dict[str, str]:
        """Service name -> container id, for every container of the project (running or not)."""
        res = _run(
            ["docker", "ps", "-a", "--filter", f"label=com.docker.compose.project={self.project}",
             "--format", '{{.ID}} {{.Label "com.docker.compose.service"}}'],
        )  # fmt: skip
        return {svc: cid for cid, svc in (line.split() for line in res.stdout.split("\n") if line)}

    def container(self, service: str) -> str:
        return self.containers()[service]

    def inspect(self, service: str) -> dict:
        res = _run(["docker", "inspect", self.container(service)])
        return json.loads(res.stdout)[0]

    def health(self) -> dict[str, str]:
        """Service -> health status (healthy | starting | unhealthy | <state> when no check)."""
        out = {}
        for svc, cid in self.containers().items():
            fmt = "{{if .State.Health}}{{.State.Health.Status}}{{else}}{{.State.Status}}{{end}}"
            out[svc] = _run(["docker", "inspect", "-f", fmt, cid]).stdout.strip()
        return out

    def wait_healthy(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        health: dict[str, str] = {}
        while time.monotonic() < deadline:
            health = self.health()
            if set(health) >= set(SERVICES) and all(h == "healthy" for h in health.values()):
                return
            if any(h in ("unhealthy", "exited", "dead") for h in health.values()):
                break
            time.sleep(1.0)
        raise RuntimeError(f"stack not healthy: {health}\n{self.logs()}")

    def up(self) -> None:
        t0 = time.monotonic()
        try:
            if self.compose == ["docker", "compose"]:
                self.run("up", "-d", "--wait", timeout=UP_TIMEOUT_S)
            else:  # v1: `up -d` waits for the dependencies' health, not the last service's
                self.run("up", "-d", timeout=UP_TIMEOUT_S)
                self.wait_healthy(UP_TIMEOUT_S - (time.monotonic() - t0))
        except (RuntimeError, subprocess.TimeoutExpired) as exc:
            raise RuntimeError(
                f"compose stack did not come up: {exc}\nhealth: {self.health()}\n{self.logs()}"
            ) from None
        self.up_seconds = time.monotonic() - t0

    def logs(self, tail: int = 40) -> str:
        return self.run("logs", "--no-color", f"--tail={tail}", timeout=60, check=False).stdout

    def down(self) -> None:
        self.run("down", "-v", "--remove-orphans", "-t", "5", timeout=180, check=False)


def pytest_terminal_summary(terminalreporter) -> None:
    if _skip_reason:
        terminalreporter.write_line(f"tests/compose skipped: {_skip_reason[0]}", yellow=True)


@pytest.fixture(scope="session")
def compose_stack() -> Iterator[ComposeStack]:
    reason = docker_unavailable_reason()
    if reason is not None:
        _skip_reason.append(reason)
        pytest.skip(f"compose tests need Docker: {reason}")
    compose = compose_command()
    assert compose is not None
    gateway_port, zenoh_port, viewer_port = free_port(), free_port(), free_port()
    env = {
        **os.environ,
        "SQMANIP_IMAGE": IMAGE,
        "SQMANIP_GATEWAY_PUBLISH_PORT": str(gateway_port),
        "SQMANIP_ZENOH_PUBLISH_PORT": str(zenoh_port),
        "SQMANIP_VIEWER_PUBLISH_PORT": str(viewer_port),
    }
    stack = ComposeStack(
        compose, f"sqmanip-test-{uuid.uuid4().hex[:8]}", env, gateway_port, zenoh_port
    )
    try:
        stack.up()
        print(
            f"\ncompose stack {stack.project} ({' '.join(compose)}) up in {stack.up_seconds:.0f} s"
        )
        yield stack
    finally:
        stack.down()
