"""Zenoh streams: one router per stack, services and users connect to it.

Topology (launcher and compose alike): a small router process, ``python -m sqmanip.streams
--listen tcp/127.0.0.1:7447`` (``StackSettings.zenoh_endpoint``), is the only listener; every
service opens a ``client``-mode session that connects to that endpoint, and so does any user
subscriber (``sqmanip.streams.subscribe``). Multicast scouting is off everywhere, so nothing
leaks onto the LAN and tests on free ports never see each other.

Keys are ``sqmanip/<service>/<stream>`` (e.g. ``sqmanip/perception/scene``); payloads are
serialized protobuf messages put with ``Encoding.APPLICATION_PROTOBUF``.

Rules (ARCHITECTURE.md): open sessions only after any fork (servers open them in ``main`` after
start-up); Zenoh callbacks run on Zenoh threads, so :func:`subscribe` only enqueues; publishing
never blocks the event loop (congestion control DROP, put from a worker thread).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import queue
import signal
import sys
import threading
from typing import Any

import zenoh

from sqmanip.settings import StackSettings, get_settings

log = logging.getLogger("sqmanip.streams")

SCENE_KEY = "sqmanip/perception/scene"


def make_config(
    mode: str, *, listen: list[str] | None = None, connect: list[str] | None = None
) -> zenoh.Config:
    """Zenoh config: ``mode`` (router | peer | client), explicit endpoints, no multicast scouting."""
    if mode not in ("router", "peer", "client"):
        raise ValueError(f"mode must be router, peer or client, got {mode!r}")
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    if listen is not None:
        cfg.insert_json5("listen/endpoints", json.dumps(listen))
    if connect is not None:
        cfg.insert_json5("connect/endpoints", json.dumps(connect))
    return cfg


class Publisher:
    """Publishes serialized protobuf messages on one key from any thread, best effort.

    :meth:`open` connects in a background thread and retries until the router answers, so a
    service that starts before its router (launcher, compose) still streams once it is up.
    Until then, and whenever a put fails, :meth:`publish` drops the message: gRPC answered
    already, and a slow subscriber must never stall a service (congestion control DROP).
    """

    def __init__(self, key: str, retry_s: float = 1.0) -> None:
        self.key = key
        self._retry_s = retry_s
        self._session: zenoh.Session | None = None
        self._pub: Any = None
        self._closed = threading.Event()

    @property
    def connected(self) -> bool:
        return self._pub is not None

    def open(self, settings: StackSettings | None = None) -> None:
        """Connect (now or later, in a daemon thread); a no-op when Zenoh is disabled."""
        settings = settings or get_settings()
        if settings.zenoh_enabled:
            threading.Thread(
                target=self._connect,
                args=(settings.zenoh_endpoint,),
                name="zenoh-connect",
                daemon=True,
            ).start()

    def _connect(self, endpoint: str) -> None:
        warned = False
        while not self._closed.is_set():
            try:
                session = zenoh.open(make_config("client", connect=[endpoint]))
            except zenoh.ZError as exc:
                if not warned:
                    log.warning("zenoh router %s unreachable, retrying: %s", endpoint, exc)
                    warned = True
                self._closed.wait(self._retry_s)
                continue
            self._session = session
            self._pub = session.declare_publisher(
                self.key,
                encoding=zenoh.Encoding.APPLICATION_PROTOBUF,
                congestion_control=zenoh.CongestionControl.DROP,
            )
            log.info("publishing on zenoh key %s via %s", self.key, endpoint)
            return

    def publish(self, message: Any) -> None:
        """Serialize a protobuf ``message`` and put it (dropped when not connected)."""
        pub = self._pub
        if pub is None:
            return
        try:
            pub.put(zenoh.ZBytes(message.SerializeToString()))
        except Exception:  # noqa: BLE001 - streaming is best effort
            log.debug("zenoh put on %s failed", self.key, exc_info=True)

    def close(self) -> None:
        self._closed.set()
        if self._session is not None:
            with contextlib.suppress(Exception):
                self._session.close()


class Subscription:
    """Samples of a key expression, queued by the Zenoh callback and read with :meth:`get`."""

    def __init__(self, session: zenoh.Session, key_expr: str, maxsize: int = 64) -> None:
        self._queue: queue.Queue[tuple[str, bytes]] = queue.Queue(maxsize=maxsize)
        self._sub = session.declare_subscriber(key_expr, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:  # Zenoh thread: enqueue only
        with contextlib.suppress(queue.Full):
            self._queue.put_nowait((str(sample.key_expr), sample.payload.to_bytes()))

    def get(self, timeout: float | None = None) -> tuple[str, bytes]:
        """Next ``(key, payload bytes)``; raises ``queue.Empty`` after ``timeout`` seconds."""
        return self._queue.get(timeout=timeout)

    def close(self) -> None:
        self._sub.undeclare()


def subscribe(
    key_expr: str, settings: StackSettings | None = None
) -> tuple[zenoh.Session, Subscription]:
    """Connect to the stack's router and subscribe (the caller closes both)."""
    settings = settings or get_settings()
    session = zenoh.open(make_config("client", connect=[settings.zenoh_endpoint]))
    return session, Subscription(session, key_expr)


def run_router(listen: str) -> int:
    """Run a Zenoh router listening on ``listen`` until SIGTERM/SIGINT."""
    session = zenoh.open(make_config("router", listen=[listen]))
    log.info("zenoh router listening on %s", listen)
    done = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: done.set())
    done.wait()
    session.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m sqmanip.streams", description="Run the stack's Zenoh router."
    )
    parser.add_argument(
        "--listen", default=None, help="endpoint (default: settings.zenoh_endpoint)"
    )
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    return run_router(args.listen or get_settings().zenoh_endpoint)


if __name__ == "__main__":
    sys.exit(main())
