"""The viewer's side panel: status, timings, and the actions that go through the gateway.

Every action calls the gateway with the Python SDK (``sqmanip_client.Client``) on one action
thread, so a GUI callback returns at once and a slow call never stalls the scene worker. What the
services publish comes back through the Zenoh streams (a recognized scene, a simulator frame,
episode events); what is not streamed (an uploaded cloud, ranked grasps, search maps) is handed
to the worker with :meth:`Viewer.submit`.
"""

from __future__ import annotations

import concurrent.futures
import logging
import tempfile
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .decode import CloudUpdate, GraspsUpdate, Redraw, SearchMapsUpdate, subsample

if TYPE_CHECKING:
    from .app import Viewer

log = logging.getLogger("sqmanip.viewer.controls")

MPC_KINDS = ("moving", "singulation", "grasping_clutter", "grasping_large", "interactive_moving")


def part_dict(sq) -> dict[str, Any]:
    """A domain :class:`Superquadric` -> the gateway's part JSON."""
    from sqmanip_client.sim import pose_json

    return {
        "kind": sq.kind, "size": [float(v) for v in sq.size],
        "shape": [float(v) for v in sq.shape], "taper": float(sq.taper),
        "bend": float(sq.bend), "bend_direction": float(sq.bend_direction),
        "pose": pose_json(np.asarray(sq.pose)),
    }  # fmt: skip


def reduce_maps(maps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """SDK ``SearchMaps`` -> ``grid_xy (P, 2)``, ``f (P,)``, ``f * g (P,)`` per grid cell (max
    over the orientations of an SE(2) grid, C.2)."""
    shape = tuple(maps.shape)
    f, fg = np.asarray(maps.f, np.float64), np.asarray(maps.f, np.float64) * maps.g
    xy = np.asarray(maps.grid_xy, np.float64)
    if len(shape) == 3:
        xy = xy.reshape(*shape, 2)[:, :, 0].reshape(-1, 2)
        return xy, f.reshape(shape).max(-1).reshape(-1), fg.reshape(shape).max(-1).reshape(-1)
    return xy, f.reshape(-1), fg.reshape(-1)


class Controls:
    def __init__(self, viewer: Viewer) -> None:
        self.viewer = viewer
        gui = viewer.server.gui
        self._pool = concurrent.futures.ThreadPoolExecutor(1, "viewer-action")
        self._client = None
        self._maps_busy = threading.Lock()

        with gui.add_folder("Status"):
            self.status = gui.add_markdown("`scene=0 objects=0 ids=- points=0`")
            self.details = gui.add_markdown("_waiting for the streams_")
        with gui.add_folder("Recognize"):
            self.upload = gui.add_upload_button(
                "Upload PLY / NPY cloud", hint="recognized through the gateway", icon=None
            )
            self.recognize_view = gui.add_button("Recognize the simulator's view")
        with gui.add_folder("Simulator"):
            self.sim_kind = gui.add_dropdown("Scene", ("tabletop", "shelf"))
            self.sim_seed = gui.add_number("Seed", 0, min=0, step=1)
            self.sim_n = gui.add_number("Objects", 4, min=0, max=20, step=1)
            self.sim_reset = gui.add_button("Reset scene")
        with gui.add_folder("Episodes", expand_by_default=False):
            self.mpc_kind = gui.add_dropdown("Push task", MPC_KINDS)
            self.mpc_start = gui.add_button("Start push episode (MPC)")
            self.search_n = gui.add_number("Shelf objects", 6, min=1, max=12, step=1)
            self.search_start = gui.add_button("Start search episode")
        with gui.add_folder("Display", expand_by_default=False):
            self._color_by = gui.add_dropdown("Cloud colour", ("rgb", "label"))
            self._color_parts = gui.add_checkbox("Shade parts", True)
            self._top_k = gui.add_number("Grasps shown (top k)", 10, min=0, max=100, step=1)
            self._auto_grasps = gui.add_checkbox("Plan grasps on new scene", False)
            self.grasp_button = gui.add_button("Plan grasps")
            self._map_layer = gui.add_dropdown("Search map", ("fg", "f", "none"))

        self.upload.on_upload(lambda e: self._do(self._upload, e.target.value))
        self.recognize_view.on_click(lambda _: self._do(self._recognize_view))
        self.sim_reset.on_click(lambda _: self._do(self._reset))
        self.mpc_start.on_click(lambda _: self._do(self._start_mpc))
        self.search_start.on_click(lambda _: self._do(self._start_search))
        self.grasp_button.on_click(lambda _: self.plan_grasps())
        self._color_by.on_update(lambda _: viewer.submit(Redraw()))
        self._color_parts.on_update(lambda _: viewer.submit(Redraw()))
        self._map_layer.on_update(lambda _: self._show_layer())

    # -- options read by the worker ----------------------------------------------------------------

    @property
    def color_by(self) -> str:
        return str(self._color_by.value)

    @property
    def color_parts(self) -> bool:
        return bool(self._color_parts.value)

    @property
    def top_k(self) -> int:
        return int(self._top_k.value)

    @property
    def auto_grasps(self) -> bool:
        return bool(self._auto_grasps.value)

    @property
    def map_layer(self) -> str:
        return str(self._map_layer.value)

    def _show_layer(self) -> None:
        for name in ("f", "fg"):
            handle = self.viewer.server.scene.get_handle_by_name(f"/search/{name}")
            if handle is not None:
                handle.visible = self.map_layer == name

    # -- actions (action thread) ---------------------------------------------------------------------

    @property
    def client(self):
        if self._client is None:
            from sqmanip_client import Client

            self._client = Client(self.viewer.gateway_url, timeout=120.0)
        return self._client

    def _do(self, fn, *args) -> concurrent.futures.Future:
        def run() -> None:
            try:
                fn(*args)
            except Exception as exc:  # noqa: BLE001 - shown in the panel, the viewer goes on
                log.warning("%s failed: %s", fn.__name__.strip("_"), exc)
                self.viewer.submit(f"{fn.__name__.strip('_')} failed: {exc}")

        return self._pool.submit(run)

    def _upload(self, file) -> None:
        from sqmanip.io.clouds import read_cloud

        suffix = Path(file.name).suffix.lower()
        with tempfile.NamedTemporaryFile(suffix=suffix) as tmp:
            tmp.write(file.content)
            tmp.flush()
            cloud = read_cloud(tmp.name)
        pts = np.asarray(cloud.points, np.float32)
        rgb = None if cloud.colors is None else np.round(255 * cloud.colors).astype(np.uint8)
        idx = subsample(len(pts))
        self.viewer.submit(CloudUpdate(pts[idx], None, None if rgb is None else rgb[idx],
                                       source=f"upload/{file.name}"))  # fmt: skip
        self.viewer.submit(f"recognizing {file.name} ({len(pts)} points)")
        self.client.recognize(pts, cloud.colors)  # the scene comes back on the Zenoh stream

    def _recognize_view(self) -> None:
        obs = self.client.sim_observe()  # also published: the cloud shows
        lo, hi = _workspace(self.viewer.state.shelf)
        self.client.recognize(
            obs.points, viewpoint=obs.camera_pose.position, workspace=(lo, hi),
            deformable=False,
        )  # fmt: skip

    def _reset(self) -> None:
        kind = str(self.sim_kind.value)
        self.client.sim_reset(seed=int(self.sim_seed.value), n_objects=int(self.sim_n.value),
                              kind=kind)  # fmt: skip
        self.client.sim_observe("shelf" if kind == "shelf" else "default", arrays=False)

    def _start_mpc(self) -> None:
        eid = self.client.start_mpc_episode(str(self.mpc_kind.value), 0,
                                            int(self.sim_seed.value))  # fmt: skip
        self.viewer.submit(f"push episode {eid} started")

    def _start_search(self) -> None:
        eid = self.client.start_search_episode(
            n_objects=int(self.search_n.value), seed=int(self.sim_seed.value)
        )
        self.viewer.submit(f"search episode {eid} started")

    def plan_grasps(self) -> None:
        """Ranked grasps on the current scene (gateway ``/grasps``), drawn top-k."""
        scene = self.viewer.state.scene
        if scene is None or not scene.objects:
            self.viewer.submit("no recognized objects to grasp")
            return
        objects = [{"id": int(o.id), "parts": [part_dict(p) for p in o.parts]}
                   for o in scene.objects if o.parts]  # fmt: skip

        def run() -> None:
            plan = self.client.plan_grasps(objects, max_results=max(self.top_k, 1))
            ranked = sorted((g for t in plan.targets for g in t.grasps), key=lambda g: -g.score)
            timings: dict[str, float] = {}
            for t in plan.targets:
                for k, v in (t.stats.get("timings_ms") or {}).items():
                    timings[k] = timings.get(k, 0.0) + float(v)
            self.viewer.submit(
                GraspsUpdate([(g.pose.matrix(), float(g.width)) for g in ranked], timings)
            )

        run.__name__ = "plan_grasps"
        self._do(run)

    def evaluate_search_maps(self) -> None:
        """f and f*g of the simulator's current shelf objects (the target, last in the scene
        spec, excluded; 5.5.1) via the gateway's ``/search/evaluate``: the search events carry
        only |f| and |f g|, not the maps. Skipped while an evaluation is still running."""
        shapes = self.viewer.state.shapes
        if not shapes or not self._maps_busy.acquire(blocking=False):
            return
        parts = [part_dict(shapes[i]) for i in sorted(shapes)[:-1]]

        def run() -> None:
            try:
                maps = self.client.evaluate_search(parts)
                xy, f, fg = reduce_maps(maps)
                self.viewer.submit(SearchMapsUpdate(xy, f, fg, maps.resolution, maps.objective))
            finally:
                self._maps_busy.release()

        run.__name__ = "search_maps"
        self._do(run)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
        if self._client is not None:
            self._client.close()


def _workspace(shelf: bool) -> tuple[list[float], list[float]]:
    """The crop box of a simulator view: inside the shelf, or above the table (4.6.1)."""
    if shelf:
        from sqmanip.search.shelf import ShelfSpec

        lo, hi = ShelfSpec().inner_bounds()
        return [float(v) for v in lo], [float(v) for v in hi]
    from sqmanip.planning.scenarios import sim_table

    t = sim_table()
    return [float(t.lo[0]), float(t.lo[1]), t.height - 0.02], [
        float(t.hi[0]), float(t.hi[1]), t.height + 0.25,
    ]  # fmt: skip
