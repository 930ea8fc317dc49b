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


def open_session(settings: StackSettings | None = None) -> zenoh.Session | None:
    """A client session connected to the stack's router, or None when Zenoh is disabled or the
    router cannot be reached (logged; the service keeps answering gRPC without streaming)."""
    settings = settings or get_settings()
    if not settings.zenoh_enabled:
        return None
    try:
        return zenoh.open(make_config("client", connect=[settings.zenoh_endpoint]))
    except zenoh.ZError as exc:
        log.warning("zenoh router %s unreachable, streaming off: %s", settings.zenoh_endpoint, exc)
        return None


class Publisher:
    """Publishes serialized protobuf messages on one key; ``publish`` never blocks for long
    (congestion control DROP: a slow subscriber loses samples instead of stalling a service)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.key = key
        self._pub = session.declare_publisher(
            key,
            encoding=zenoh.Encoding.APPLICATION_PROTOBUF,
            congestion_control=zenoh.CongestionControl.DROP,
        )

    def publish(self, message: Any) -> None:
        """Serialize a protobuf ``message`` and put it."""
        self._pub.put(zenoh.ZBytes(message.SerializeToString()))

    def close(self) -> None:
        self._pub.undeclare()


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
