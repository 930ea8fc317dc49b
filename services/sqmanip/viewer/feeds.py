"""The viewer's Zenoh input: one client session on the stack's router, callbacks only enqueue.

Zenoh callbacks run on Zenoh threads (ARCHITECTURE.md): :class:`Feed` puts ``(key, payload)``
into a bounded queue and returns; the viewer's worker thread takes samples with :meth:`Feed.take`,
which keeps only the newest scene and observation of a burst (older ones would be overdrawn at
once anyway) and every episode event, so a slow browser never makes the viewer lag behind.
The session connects in a daemon thread and retries until the router answers, so the viewer may
start before the router (launcher, compose).
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading

import zenoh

from sqmanip.settings import StackSettings
from sqmanip.streams import make_config

from .decode import MPC_EPISODE_KEY, SEARCH_EPISODE_KEY

log = logging.getLogger("sqmanip.viewer.feeds")

KEY_EXPR = "sqmanip/**"
_KEEP_ALL = (MPC_EPISODE_KEY, SEARCH_EPISODE_KEY)


class Feed:
    """Subscribes to ``key_expr`` on ``settings.zenoh_endpoint`` (client mode, no scouting)."""

    def __init__(
        self,
        settings: StackSettings,
        key_expr: str = KEY_EXPR,
        maxsize: int = 256,
        retry_s: float = 1.0,
    ) -> None:
        self.endpoint = settings.zenoh_endpoint
        self.key_expr = key_expr
        self._queue: queue.Queue[tuple[str, bytes]] = queue.Queue(maxsize=maxsize)
        self._retry_s = retry_s
        self._closed = threading.Event()
        self._session: zenoh.Session | None = None
        self._sub = None
        self.connected = threading.Event()

    def start(self) -> Feed:
        threading.Thread(target=self._connect, name="viewer-zenoh", daemon=True).start()
        return self

    def _connect(self) -> None:
        warned = False
        while not self._closed.is_set():
            try:
                session = zenoh.open(make_config("client", connect=[self.endpoint]))
            except zenoh.ZError as exc:
                if not warned:
                    log.warning("zenoh router %s unreachable, retrying: %s", self.endpoint, exc)
                    warned = True
                self._closed.wait(self._retry_s)
                continue
            self._session = session
            self._sub = session.declare_subscriber(self.key_expr, self._on_sample)
            self.connected.set()
            log.info("subscribed to %s via %s", self.key_expr, self.endpoint)
            return

    def _on_sample(self, sample: zenoh.Sample) -> None:  # Zenoh thread: enqueue only
        with contextlib.suppress(queue.Full):
            self._queue.put_nowait((str(sample.key_expr), sample.payload.to_bytes()))

    def put(self, key: str, payload: bytes) -> None:
        """Inject a sample (the GUI's own uploads and tests use the same path)."""
        with contextlib.suppress(queue.Full):
            self._queue.put_nowait((key, payload))

    def take(self, timeout: float) -> list[tuple[str, bytes]]:
        """Block up to ``timeout`` s for one sample, then drain the queue: the newest sample of
        each coalescable key plus every episode event, in arrival order."""
        try:
            first = self._queue.get(timeout=timeout)
        except queue.Empty:
            return []
        batch = [first]
        with contextlib.suppress(queue.Empty):
            while True:
                batch.append(self._queue.get_nowait())
        last = {key: i for i, (key, _) in enumerate(batch)}
        return [(k, p) for i, (k, p) in enumerate(batch) if k in _KEEP_ALL or last[k] == i]

    def close(self) -> None:
        self._closed.set()
        if self._sub is not None:
            with contextlib.suppress(Exception):
                self._sub.undeclare()
        if self._session is not None:
            with contextlib.suppress(Exception):
                self._session.close()
