"""Start the stack as local processes: Zenoh router, gRPC services, gateway.

``sqmanip up`` (CLI) and :func:`running_stack` (tests, benchmarks) use the same code:

- every process is ``python -m <module>`` with the stack's settings passed as ``SQMANIP_*``
  environment variables, so the children and the launcher agree on every port;
- the Zenoh router starts first (when enabled): it is the one listener on
  ``settings.zenoh_endpoint`` and every service connects to it as a client (see
  :mod:`sqmanip.streams`);
- each gRPC service is ready when its standard health service answers SERVING
  (grpcio-health-checking), the gateway when ``GET /healthz`` answers;
- everything is stopped (SIGTERM, then SIGKILL after a grace period) on Ctrl-C/SIGTERM, when
  the ``with`` block ends, or when a process dies; with ``restart=True`` a dead service is
  restarted with exponential back-off instead (logged), which the fault tests rely on.

Adding a service is one line in :data:`SERVICE_MODULES`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from collections.abc import Iterator, Sequence
from pathlib import Path

from sqmanip.settings import SERVICES, StackSettings, get_settings

log = logging.getLogger("sqmanip.launch")

SERVICE_MODULES: dict[str, str] = {
    "perception": "sqmanip.perception.server",
    "sim": "sqmanip.sim.server",
    "grasp": "sqmanip.grasping.server",
    "dynamics": "sqmanip.dynamics.server",
    "mpc": "sqmanip.planning.server",
    "search": "sqmanip.search.server",
    # later services: one line each
}
"""Service name (a ``StackSettings`` port prefix) -> module run as ``python -m module --port P``."""

GATEWAY_MODULE = "sqmanip.gateway"
ZENOH_MODULE = "sqmanip.streams"
VIEWER_MODULE = "sqmanip.viewer"
"""The viewer (``services=(..., "viewer")``): an HTTP service, ready when ``GET /`` answers."""

_PORT_FIELDS = ("gateway_port", "viewer_port", *(f"{s}_port" for s in SERVICES))


# --- ports ----------------------------------------------------------------------------------------


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free a moment ago (bind to port 0, read it, close)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def free_ports(n: int, host: str = "127.0.0.1") -> list[int]:
    """``n`` distinct free ports (sockets held open together so they differ)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind((host, 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def settings_on_free_ports(base: StackSettings | None = None, **overrides) -> StackSettings:
    """Copy of ``base`` with every port (and the Zenoh endpoint) on free loopback ports."""
    base = base or StackSettings()
    ports = free_ports(len(_PORT_FIELDS) + 1)
    update = dict(zip(_PORT_FIELDS, ports, strict=False))
    update["zenoh_endpoint"] = f"tcp/127.0.0.1:{ports[-1]}"
    update["host"] = update_host = "127.0.0.1"
    update["gateway_host"] = update_host
    update.update(overrides)
    return base.model_copy(update=update)


def with_port_offset(settings: StackSettings, offset: int) -> StackSettings:
    """Shift every port (and the Zenoh endpoint's port) by ``offset``."""
    if offset == 0:
        return settings
    update = {f: getattr(settings, f) + offset for f in _PORT_FIELDS}
    head, _, port = settings.zenoh_endpoint.rpartition(":")
    if port.isdigit():
        update["zenoh_endpoint"] = f"{head}:{int(port) + offset}"
    return settings.model_copy(update=update)


def settings_env(settings: StackSettings) -> dict[str, str]:
    """``SQMANIP_*`` variables that reproduce ``settings`` in a child process."""
    env = {}
    for name, value in settings.model_dump().items():
        if isinstance(value, list | tuple | dict):
            import json

            env[f"SQMANIP_{name.upper()}"] = json.dumps(value)
        elif isinstance(value, bool):
            env[f"SQMANIP_{name.upper()}"] = "true" if value else "false"
        elif value is not None:
            env[f"SQMANIP_{name.upper()}"] = str(value)
    return env


# --- processes ------------------------------------------------------------------------------------


def _set_pdeathsig() -> None:  # pragma: no cover - runs in the child
    """Linux: the child gets SIGTERM if the launcher dies without cleaning up."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except Exception:  # noqa: BLE001 - best effort, not available off Linux
        pass


@dataclasses.dataclass
class Proc:
    name: str
    argv: list[str]
    ready: str
    """``grpc:host:port``, ``http:URL`` or ``tcp:host:port``."""
    popen: subprocess.Popen | None = None
    restarts: int = 0
    log_path: Path | None = None

    def alive(self) -> bool:
        return self.popen is not None and self.popen.poll() is None


def _is_ready(ready: str, timeout: float = 1.0) -> bool:
    kind, _, target = ready.partition(":")
    if kind == "grpc":
        from sqmanip.rpc.health_probe import check

        return check(target, timeout=timeout) == "SERVING"
    if kind == "http":
        try:
            with urllib.request.urlopen(target, timeout=timeout) as resp:  # noqa: S310 - loopback
                return resp.status == 200
        except OSError:
            return False
    host, _, port = target.rpartition(":")
    with contextlib.suppress(OSError), socket.create_connection((host, int(port)), timeout):
        return True
    return False


class Stack:
    """The running processes of one stack; see the module docstring."""

    def __init__(
        self,
        settings: StackSettings,
        services: Sequence[str] = tuple(SERVICE_MODULES),
        *,
        gateway: bool = True,
        zenoh: bool | None = None,
        restart: bool = False,
        log_dir: str | Path | None = None,
        python: str = sys.executable,
    ) -> None:
        unknown = [s for s in services if s not in SERVICE_MODULES and s != "viewer"]
        if unknown:
            raise ValueError(f"services: unknown {unknown}; available: {sorted(SERVICE_MODULES)}")
        self.settings = settings.model_copy(
            update={"zenoh_enabled": settings.zenoh_enabled if zenoh is None else zenoh}
        )
        self.services = tuple(services)
        self.restart = restart
        self.log_dir = Path(log_dir) if log_dir is not None else None
        self._stopping = threading.Event()
        self._spawn_lock = threading.Lock()
        """Held while the supervisor restarts a process and while :meth:`stop` sets
        ``_stopping``: a restart never starts a process after ``stop`` has signalled the rest."""
        s = self.settings
        backends = [n for n in services if n != "viewer"]
        env_extra = {"SQMANIP_GATEWAY_SERVICES": "[" + ",".join(f'"{n}"' for n in backends) + "]"}
        self._env = {**os.environ, **settings_env(s), **env_extra, "PYTHONUNBUFFERED": "1"}
        self.procs: list[Proc] = []
        if s.zenoh_enabled:
            endpoint = s.zenoh_endpoint
            hostport = endpoint.split("/", 1)[-1]
            self.procs.append(
                Proc("zenoh", [python, "-m", ZENOH_MODULE, "--listen", endpoint], f"tcp:{hostport}")
            )
        for name in backends:
            port = s.port(name)
            argv = [python, "-m", SERVICE_MODULES[name], "--host", s.host, "--port", str(port)]
            self.procs.append(Proc(name, argv, f"grpc:{s.host}:{port}"))
        if gateway:
            argv = [python, "-m", GATEWAY_MODULE, "--host", s.gateway_host]
            argv += ["--port", str(s.gateway_port), "--log-level", "warning"]
            self.procs.append(Proc("gateway", argv, f"http:{self.gateway_url}/healthz"))
        if "viewer" in self.services:
            argv = [python, "-m", VIEWER_MODULE, "--host", s.gateway_host]
            argv += ["--port", str(s.viewer_port), "--log-level", "warning"]
            self.procs.append(Proc("viewer", argv, f"http:{self.viewer_url}/"))

    # -- addresses
    @property
    def gateway_url(self) -> str:
        return f"http://{self.settings.gateway_host}:{self.settings.gateway_port}"

    @property
    def viewer_url(self) -> str:
        return f"http://{self.settings.gateway_host}:{self.settings.viewer_port}"

    def address(self, name: str) -> str:
        """``host:port`` of a gRPC service."""
        return self.settings.address(name)

    def urls(self) -> dict[str, str]:
        out = {"gateway": self.gateway_url, "docs": f"{self.gateway_url}/docs"}
        if "viewer" in self.services:
            out["viewer"] = self.viewer_url
        out.update({n: f"grpc://{self.address(n)}" for n in self.services if n != "viewer"})
        if self.settings.zenoh_enabled:
            out["zenoh"] = self.settings.zenoh_endpoint
        return out

    # -- lifecycle
    def _spawn(self, proc: Proc) -> None:
        out = None
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            proc.log_path = self.log_dir / f"{proc.name}.log"
            out = open(proc.log_path, "ab")  # noqa: SIM115 - handed to the child
        try:
            proc.popen = subprocess.Popen(
                proc.argv,
                env=self._env,
                stdout=out,
                stderr=subprocess.STDOUT if out is not None else None,
                start_new_session=True,  # Ctrl-C reaches the launcher only; it stops the rest
                preexec_fn=_set_pdeathsig if sys.platform.startswith("linux") else None,
            )
        finally:
            if out is not None:
                out.close()
        log.info("started %s (pid %d): %s", proc.name, proc.popen.pid, " ".join(proc.argv[1:]))

    def _wait_ready(self, proc: Proc, deadline: float) -> None:
        while time.monotonic() < deadline:
            if self._stopping.is_set():
                raise RuntimeError(f"{proc.name}: the stack is stopping")
            if not proc.alive():
                code = proc.popen.returncode if proc.popen else None
                raise RuntimeError(
                    f"{proc.name} exited with code {code} during start-up{self._tail(proc)}"
                )
            if _is_ready(proc.ready, timeout=0.5):
                return
            time.sleep(0.1)
        raise TimeoutError(
            f"{proc.name} not ready ({proc.ready}) before the timeout{self._tail(proc)}"
        )

    def _tail(self, proc: Proc, n: int = 3000) -> str:
        if proc.log_path is None or not proc.log_path.exists():
            return ""
        return (
            "\n--- "
            + proc.name
            + " log tail ---\n"
            + proc.log_path.read_text(errors="replace")[-n:]
        )

    def start(self, timeout: float = 60.0) -> Stack:
        """Start every process in order and wait until each is ready (``timeout`` in total)."""
        deadline = time.monotonic() + timeout
        try:
            for proc in self.procs:
                self._spawn(proc)
            for proc in self.procs:
                self._wait_ready(proc, deadline)
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self, grace: float = 5.0) -> None:
        """SIGTERM every process (gateway first), SIGKILL whatever is left after ``grace``."""
        with self._spawn_lock:
            self._stopping.set()
        for proc in reversed(self.procs):
            if proc.alive():
                with contextlib.suppress(ProcessLookupError):
                    proc.popen.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + grace
        for proc in reversed(self.procs):
            if proc.popen is None:
                continue
            try:
                proc.popen.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("%s did not stop within %.0f s: killing", proc.name, grace)
                with contextlib.suppress(ProcessLookupError):
                    proc.popen.kill()
                proc.popen.wait()

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        """Send ``sig`` to one process (fault tests)."""
        proc = self._proc(name)
        if proc.alive():
            proc.popen.send_signal(sig)

    def _proc(self, name: str) -> Proc:
        for p in self.procs:
            if p.name == name:
                return p
        raise KeyError(f"no process named {name!r}; have {[p.name for p in self.procs]}")

    def supervise(
        self, *, poll_s: float = 0.5, max_backoff_s: float = 30.0, ready_timeout: float = 60.0
    ) -> int:
        """Watch the processes until :meth:`stop` is called (returns 0) or, without ``restart``,
        one dies (returns 1 after stopping the rest). With ``restart``, a dead process is
        restarted after a back-off of 1, 2, 4, ... s (at most ``max_backoff_s``), reset after
        60 s of healthy running."""
        next_try: dict[str, float] = {}
        started_at: dict[str, float] = {p.name: time.monotonic() for p in self.procs}
        while not self._stopping.wait(poll_s):
            for proc in self.procs:
                if proc.alive():
                    if proc.restarts and time.monotonic() - started_at[proc.name] > 60:
                        proc.restarts = 0
                    continue
                code = proc.popen.returncode if proc.popen else None
                if not self.restart:
                    log.error("%s exited with code %s: stopping the stack", proc.name, code)
                    self.stop()
                    return 1
                now = time.monotonic()
                if proc.name not in next_try:
                    delay = min(max_backoff_s, 2.0**proc.restarts)
                    next_try[proc.name] = now + delay
                    log.warning(
                        "%s exited with code %s: restart %d in %.0f s",
                        proc.name, code, proc.restarts + 1, delay,
                    )  # fmt: skip
                elif now >= next_try[proc.name]:
                    del next_try[proc.name]
                    with self._spawn_lock:
                        if self._stopping.is_set():
                            break
                        proc.restarts += 1
                        self._spawn(proc)
                    started_at[proc.name] = time.monotonic()
                    try:
                        self._wait_ready(proc, time.monotonic() + ready_timeout)
                        log.warning(
                            "%s restarted (pid %d) and ready %.1f s after the restart",
                            proc.name, proc.popen.pid, time.monotonic() - started_at[proc.name],
                        )  # fmt: skip
                    except (RuntimeError, TimeoutError) as exc:
                        if self._stopping.is_set():
                            break
                        log.error("%s restart failed: %s", proc.name, exc)
        return 0

    def __enter__(self) -> Stack:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


@contextlib.contextmanager
def running_stack(
    settings: StackSettings | None = None,
    services: Sequence[str] = ("perception",),
    *,
    zenoh: bool | None = None,
    restart: bool = False,
    timeout: float = 90.0,
    log_dir: str | Path | None = None,
) -> Iterator[Stack]:
    """Start a stack (default: on free loopback ports), yield it, always tear it down.

    ``with running_stack(services=("perception",)) as stack: stack.gateway_url``. Process
    output goes to ``log_dir`` (a temporary directory by default; the start-up error quotes
    the failing process's log). With ``restart``, a supervisor thread restarts dead services.
    """
    settings = settings or settings_on_free_ports()
    with contextlib.ExitStack() as cleanup:
        if log_dir is None:
            log_dir = cleanup.enter_context(tempfile.TemporaryDirectory(prefix="sqmanip-stack-"))
        stack = Stack(settings, services, zenoh=zenoh, restart=restart, log_dir=log_dir)
        cleanup.callback(stack.stop)
        stack.start(timeout)
        if restart:
            thread = threading.Thread(target=stack.supervise, name="supervisor", daemon=True)
            thread.start()
            cleanup.callback(thread.join, 10)
            # Runs first (LIFO): without it the join above waits its full 10 s, because the
            # supervisor only returns once ``_stopping`` is set.
            cleanup.callback(stack._stopping.set)
        yield stack


# --- CLI ------------------------------------------------------------------------------------------


def add_parser(subparsers) -> None:
    """Register ``sqmanip up`` on the CLI's sub-parsers."""
    p = subparsers.add_parser(
        "up",
        help="start the gateway and the services as local processes",
        description="Start the Zenoh router, the gRPC services and the gateway; wait for health; "
        "stop everything on Ctrl-C/SIGTERM or when a process dies (unless --restart).",
    )
    p.add_argument(
        "--services",
        default=",".join([*SERVICE_MODULES, "viewer"]),
        help="comma-separated services to start (default: all available: "
        f"{','.join([*SERVICE_MODULES, 'viewer'])})",
    )
    p.add_argument("--port-offset", type=int, default=0, help="add to every configured port")
    p.add_argument("--no-zenoh", action="store_true", help="do not start the Zenoh router")
    p.add_argument("--restart", action="store_true", help="restart dead services with back-off")
    p.add_argument("--timeout", type=float, default=120.0, help="start-up timeout (s)")
    p.add_argument("--log-dir", default=None, help="write each process's output to DIR/<name>.log")
    p.set_defaults(func=cmd_up)


def cmd_up(args) -> int:
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    services = [s.strip() for s in args.services.split(",") if s.strip()]
    settings = with_port_offset(get_settings(), args.port_offset)
    stack = Stack(
        settings, services, zenoh=False if args.no_zenoh else None, restart=args.restart,
        log_dir=args.log_dir,
    )  # fmt: skip

    def on_signal(signum, _frame) -> None:
        log.info("received %s: stopping", signal.Signals(signum).name)
        stack._stopping.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    try:
        stack.start(args.timeout)
    except (RuntimeError, TimeoutError) as exc:
        print(f"sqmanip up: {exc}", file=sys.stderr)
        return 1
    print("SQManip stack is up:")
    for name, url in stack.urls().items():
        print(f"  {name:<11} {url}")
    print("Stop with Ctrl-C.", flush=True)
    code = stack.supervise()
    stack.stop()
    return code
