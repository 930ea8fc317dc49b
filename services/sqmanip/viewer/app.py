"""The viewer: a viser server whose scene tree follows the stack's Zenoh streams.

Threads: Zenoh callbacks only enqueue (:mod:`.feeds`); ONE worker thread decodes samples and
updates the scene and the status panel (:meth:`Viewer.apply`), so viser handles are never touched
from two threads at once; GUI actions that call the gateway run on a separate action thread
(:mod:`.controls`) and hand their results back through :meth:`Viewer.submit`.

The status line (``scene=<n> objects=<k> ids=... points=<m> drawn=<unix s>``, GUI "Status") is written
after the nodes it counts, so a browser that shows the line has received the scene (the browser
test waits on it).
"""

from __future__ import annotations

import dataclasses
import logging
import queue
import threading
import time
from typing import Any

import numpy as np

from sqmanip.geometry.types import Superquadric
from sqmanip.perception.types import Scene
from sqmanip.settings import StackSettings

from . import draw
from .controls import Controls
from .decode import (
    CloudUpdate,
    EpisodeUpdate,
    GraspsUpdate,
    Redraw,
    SceneUpdate,
    SearchMapsUpdate,
    Update,
    decode,
)
from .feeds import Feed

log = logging.getLogger("sqmanip.viewer")


@dataclasses.dataclass
class ViewState:
    """What the scene shows now (read by the status panel, the controls and the tests)."""

    scene_count: int = 0
    scene: Scene | None = None
    scene_ids: list[int] = dataclasses.field(default_factory=list)
    scene_time: float = 0.0
    """Wall-clock time (s) the latest scene was drawn (in the status line: latency checks)."""
    scene_draw_ms: float = 0.0
    """Decoded scene -> nodes sent to the browsers (meshing included)."""
    cloud_points: int = 0
    cloud_source: str = ""
    shapes: dict[int, Superquadric] = dataclasses.field(default_factory=dict)
    """Ground-truth shapes of the simulator's objects (id = scene-spec index)."""
    shelf: bool = False
    episode_kind: str = ""
    episode_step: int | None = None
    episode_status: str = ""
    episode_timings: dict[str, float] = dataclasses.field(default_factory=dict)
    pushes: list[list[float]] = dataclasses.field(default_factory=list)
    grasps_drawn: int = 0
    grasp_timings: dict[str, float] = dataclasses.field(default_factory=dict)
    maps_objective: float | None = None
    message: str = ""


class Viewer:
    """``Viewer(settings, host, port).start()``; :meth:`close` stops everything."""

    def __init__(
        self,
        settings: StackSettings,
        *,
        host: str = "127.0.0.1",
        port: int = 8081,
        gateway_url: str | None = None,
    ) -> None:
        import viser

        self.settings = settings
        self.gateway_url = gateway_url or _gateway_url(settings)
        self.server = viser.ViserServer(host=host, port=port, label="SQManip", verbose=False)
        self.server.scene.set_up_direction("+z")
        # No HDRI environment: its prefiltering stalls a software-WebGL page (headless Chromium,
        # SwiftShader) for ~30 s on the first lit mesh; the default lights suffice.
        self.server.scene.configure_environment_map(hdri=None)
        self.server.scene.configure_default_lights(enabled=True, cast_shadow=False)
        self.server.scene.add_light_ambient("/lights/ambient", intensity=1.2)
        self.server.initial_camera.position = (0.2, -0.38, 0.42)
        self.server.initial_camera.look_at = (0.52, 0.0, 0.02)
        self.server.scene.add_grid("/ground", width=2.0, height=2.0, cell_size=0.1,
                                   section_size=0.5, position=(0.5, 0.0, -0.001))  # fmt: skip
        self.state = ViewState()
        self.feed = Feed(settings)
        self._local: queue.Queue[Update | Any] = queue.Queue()
        self._stop = threading.Event()
        self._worker = threading.Thread(target=self._run, name="viewer-worker", daemon=True)
        self._last_cloud: CloudUpdate | None = None
        self.controls = Controls(self)

    # -- lifecycle ---------------------------------------------------------------------------------

    def start(self) -> Viewer:
        self.feed.start()
        self._worker.start()
        self.refresh_status()
        return self

    def close(self) -> None:
        self._stop.set()
        self.feed.close()
        self.controls.close()
        if self._worker.is_alive():
            self._worker.join(5)
        self.server.stop()

    def submit(self, update: Any) -> None:
        """Queue an update for the worker (any thread)."""
        self._local.put(update)

    # -- worker ------------------------------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.is_set():
            for key, payload in self.feed.take(timeout=0.02):
                try:
                    self.apply(decode(key, payload))
                except Exception:  # noqa: BLE001 - one bad sample must not stop the viewer
                    log.exception("drawing a sample of %s failed", key)
            while True:
                try:
                    update = self._local.get_nowait()
                except queue.Empty:
                    break
                try:
                    self.apply(update)
                except Exception:  # noqa: BLE001
                    log.exception("drawing %s failed", type(update).__name__)

    def apply(self, update: Any) -> None:
        """Draw one update (worker thread only), then refresh the status panel."""
        s, srv = self.state, self.server
        if isinstance(update, SceneUpdate):
            t0 = time.perf_counter()
            self._draw_scene(update.scene)
            s.scene_draw_ms = 1e3 * (time.perf_counter() - t0)
            s.scene_time = time.time()
        elif isinstance(update, CloudUpdate):
            self._last_cloud = update
            self._draw_cloud()
            shapes = {o.id: o.superquadric for o in update.objects if o.superquadric is not None}
            if shapes:
                s.shapes = shapes
            s.cloud_points, s.cloud_source = int(update.points.shape[0]), update.source
            shelf = update.source.endswith("/shelf")
            if shelf != s.shelf:
                s.shelf = shelf
                self._draw_shelf()
        elif isinstance(update, EpisodeUpdate):
            self._episode(update)
        elif isinstance(update, GraspsUpdate):
            s.grasps_drawn = draw.grasps(srv, update.ranked, self.controls.top_k)
            s.grasp_timings = update.timings_ms
        elif isinstance(update, SearchMapsUpdate):
            from sqmanip.search.shelf import ShelfSpec

            draw.search_maps(srv, update.grid_xy, update.f, update.fg, update.resolution,
                             ShelfSpec().floor_z, self.controls.map_layer)  # fmt: skip
            s.maps_objective = update.objective
        elif isinstance(update, Redraw):
            self.redraw()
        elif isinstance(update, str):
            s.message = update
        self.refresh_status()

    def _draw_scene(self, scene: Scene) -> None:
        s = self.state
        s.scene = scene
        s.scene_ids = draw.objects(
            self.server, scene.objects, color_parts=self.controls.color_parts
        )
        centers = [p.pose[:3, 3] for o in scene.objects for p in o.parts]
        center = np.mean(centers, axis=0) if centers else None
        sp = scene.support_plane
        draw.support_plane(self.server, None if sp is None else sp.normal,
                           0.0 if sp is None else sp.offset, center)  # fmt: skip
        draw.clear(self.server, "/grasps")
        s.grasps_drawn = 0
        s.scene_count += 1
        if self.controls.auto_grasps:
            self.controls.plan_grasps()

    def _draw_cloud(self) -> None:
        c = self._last_cloud
        if c is not None:
            draw.cloud(self.server, c.points, labels=c.labels, rgb=c.rgb,
                       color_by=self.controls.color_by)  # fmt: skip

    def _draw_shelf(self) -> None:
        if self.state.shelf:
            from sqmanip.search.shelf import ShelfSpec

            draw.shelf(self.server, ShelfSpec())
        else:
            draw.clear(self.server, "/shelf")

    def _episode(self, update: EpisodeUpdate) -> None:
        s, ev = self.state, update.event
        if s.episode_kind != update.kind or ev.get("step") == 0:
            s.pushes = []
        s.episode_kind = update.kind
        if "result" in ev:
            r = ev["result"]
            s.episode_status = "result: " + ", ".join(
                f"{k}={v}" for k, v in r.items() if k not in ("scenario",) and v is not None
            )
            return
        s.episode_step = int(ev.get("step", 0))
        s.episode_timings = dict(ev.get("timings_ms", {}))
        if update.kind == "mpc":
            s.episode_status = f"{ev.get('status', '')}: {ev.get('message', '')}".strip(": ")
            if ev.get("action"):
                s.pushes.append(list(ev["action"]))
            draw.push_arrows(self.server, s.pushes)
            draw.push_ghosts(self.server, s.shapes, ev.get("predicted", {}), ev.get("observed", {}))
        else:
            s.episode_status = (
                f"{ev.get('action', '')} |f|={ev.get('f_sum', 0):.3g} "
                f"|fg|={ev.get('fg_sum', 0):.3g} visible={ev.get('visible')}"
            )
            if not s.shelf:
                s.shelf = True
                self._draw_shelf()
            params = ev.get("params") or {}
            if ev.get("action") == "push" and isinstance(params, dict):
                p, v = params.get("start"), params.get("displacement")  # search/episode.py
                if p is not None and v is not None and len(p) == 3 and len(v) == 3:
                    s.pushes.append([*map(float, p), *map(float, v)])
                    draw.push_arrows(self.server, s.pushes)
            self.controls.evaluate_search_maps()

    # -- display options (worker thread, via submit) -----------------------------------------------

    def redraw(self) -> None:
        self._draw_cloud()
        if self.state.scene is not None:
            self.state.scene_ids = draw.objects(
                self.server, self.state.scene.objects, color_parts=self.controls.color_parts
            )

    # -- status ------------------------------------------------------------------------------------

    def status_line(self) -> str:
        s = self.state
        ids = ",".join(str(i) for i in s.scene_ids) or "-"
        return (
            f"scene={s.scene_count} objects={len(s.scene_ids)} ids={ids} points={s.cloud_points} "
            f"drawn={s.scene_time:.3f}"
        )

    def refresh_status(self) -> None:
        s = self.state
        self.controls.status.content = f"`{self.status_line()}`"
        lines = []
        if s.scene is not None and s.scene.timings_ms:
            t = s.scene.timings_ms
            lines.append(
                "**Recognition (ms)**  \n" + _timings(t) + f"  \nviewer draw {s.scene_draw_ms:.0f}"
            )
        if s.grasp_timings:
            lines.append(f"**Grasps** top {s.grasps_drawn}  \n" + _timings(s.grasp_timings))
        if s.episode_kind:
            step = "-" if s.episode_step is None else s.episode_step
            lines.append(f"**{s.episode_kind.upper()} episode** step {step}  \n{s.episode_status}")
            if s.episode_timings:
                lines.append(_timings(s.episode_timings))
        if s.maps_objective is not None:
            lines.append(f"**Search maps** J = {s.maps_objective:.4g}")
        if s.cloud_source:
            lines.append(f"cloud: {s.cloud_points} points from {s.cloud_source}")
        if s.message:
            lines.append(f"_{s.message}_")
        self.controls.details.content = "\n\n".join(lines) or "_waiting for the streams_"


def _timings(t: dict[str, float]) -> str:
    return " · ".join(f"{k} {v:.0f}" for k, v in t.items())


def _gateway_url(settings: StackSettings) -> str:
    host = settings.gateway_host
    if host in ("0.0.0.0", "::", ""):
        host = "127.0.0.1"
    return f"http://{host}:{settings.gateway_port}"
