"""Zenoh payloads -> what the viewer draws (pure: no viser, no network; unit-tested).

Every stream of the stack is a serialized protobuf on a ``sqmanip/<service>/<stream>`` key
(ARCHITECTURE.md, Zenoh notes). :func:`decode` turns one ``(key, payload)`` into a typed update:

- ``sqmanip/perception/scene`` (``sqmanip.v1.Scene``) -> :class:`SceneUpdate` (the recognized
  superquadrics, the support plane, the timings; the cloud itself is not on this stream);
- ``sqmanip/sim/observation`` (``sqmanip.v1.Observation``) -> :class:`CloudUpdate` (the
  world-frame cloud with its segmentation labels and per-point colours from the RGB image, and the
  simulator's ground-truth objects, whose shapes the push ghosts and the search maps reuse);
- ``sqmanip/mpc/episode`` (``EpisodeEvent``) and ``sqmanip/search/episode`` (``SearchEvent``) ->
  :class:`EpisodeUpdate` (the JSON-ready dicts of :mod:`sqmanip.rpc.convert`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from sqmanip.perception.types import Scene
from sqmanip.rpc import convert
from sqmanip.sim.actions import ObjectState

SCENE_KEY = "sqmanip/perception/scene"
OBSERVATION_KEY = "sqmanip/sim/observation"
MPC_EPISODE_KEY = "sqmanip/mpc/episode"
SEARCH_EPISODE_KEY = "sqmanip/search/episode"
KEYS = (SCENE_KEY, OBSERVATION_KEY, MPC_EPISODE_KEY, SEARCH_EPISODE_KEY)

MAX_CLOUD_POINTS = 30_000
"""Points sent to the browser at most (a 640 x 576 frame has ~370 k): a seeded subsample keeps
the page interactive in software WebGL (headless Chromium renders 30 k points in ~0.1 s)."""


@dataclasses.dataclass(frozen=True)
class SceneUpdate:
    scene: Scene


@dataclasses.dataclass(frozen=True)
class CloudUpdate:
    """``points (N, 3)`` float32 world frame, ``labels (N,)`` int32 (-1 background, -2 static,
    -3 robot; or None), ``rgb (N, 3)`` uint8 (or None), ground-truth ``objects``, ``source``."""

    points: np.ndarray
    labels: np.ndarray | None
    rgb: np.ndarray | None
    objects: tuple[ObjectState, ...] = ()
    source: str = "sim"


@dataclasses.dataclass(frozen=True)
class EpisodeUpdate:
    """``kind`` ``mpc`` | ``search``; ``event`` the JSON-ready event dict (``result`` on the last)."""

    kind: str
    event: dict[str, Any]


@dataclasses.dataclass
class SearchMapsUpdate:
    """f and f*g over the target grid, reduced over orientations: ``grid_xy (P, 2)``, ``(P,)``."""

    grid_xy: np.ndarray
    f: np.ndarray
    fg: np.ndarray
    resolution: float
    objective: float


@dataclasses.dataclass
class GraspsUpdate:
    """Ranked ``(pose 4 x 4, width)`` best first, with the planner's timings."""

    ranked: list[tuple[np.ndarray, float]]
    timings_ms: dict[str, float]


class Redraw:
    """Re-draw the cloud and the objects with the current display options."""


Update = SceneUpdate | CloudUpdate | EpisodeUpdate | SearchMapsUpdate | GraspsUpdate | Redraw


def subsample(n: int, limit: int = MAX_CLOUD_POINTS, seed: int = 0) -> np.ndarray:
    """Sorted indices of at most ``limit`` of ``n`` points (all of them when ``n <= limit``)."""
    if limit < 1:
        raise ValueError(f"limit must be >= 1, got {limit}")
    if n <= limit:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, size=limit, replace=False))


def observation_update(payload: bytes, limit: int = MAX_CLOUD_POINTS) -> CloudUpdate:
    """An ``Observation`` -> its cloud (subsampled to ``limit``), labels, colours and objects."""
    from sqmanip.v1 import sim_pb2

    msg = sim_pb2.Observation.FromString(payload)
    points, _, labels = convert.cloud_from_proto(msg.cloud)
    idx = subsample(points.shape[0], limit)
    rgb = None
    h, w = int(msg.height), int(msg.width)
    n = points.shape[0]
    if msg.rgb and len(msg.rgb) == 3 * h * w and len(msg.point_pixels) == 4 * n:
        image = np.frombuffer(msg.rgb, dtype=np.uint8).reshape(h * w, 3)
        pixels = np.frombuffer(msg.point_pixels, dtype="<i4")[idx]
        rgb = image[np.clip(pixels, 0, h * w - 1)]
    objects = tuple(convert.object_state_from_proto(o) for o in msg.objects)
    return CloudUpdate(
        points=points[idx],
        labels=None if labels is None else labels[idx],
        rgb=rgb,
        objects=objects,
        source=f"sim/{msg.camera or 'default'}",
    )


def decode(key: str, payload: bytes) -> Update:
    """One Zenoh sample -> its update; ``ValueError`` for a key the viewer does not know."""
    if key == SCENE_KEY:
        from sqmanip.v1 import common_pb2

        return SceneUpdate(convert.scene_from_proto(common_pb2.Scene.FromString(payload)))
    if key == OBSERVATION_KEY:
        return observation_update(payload)
    if key == MPC_EPISODE_KEY:
        from sqmanip.v1 import planner_pb2

        msg = planner_pb2.EpisodeEvent.FromString(payload)
        return EpisodeUpdate("mpc", convert.episode_event_from_proto(msg))
    if key == SEARCH_EPISODE_KEY:
        from sqmanip.v1 import search_pb2

        msg = search_pb2.SearchEvent.FromString(payload)
        return EpisodeUpdate("search", convert.search_event_from_proto(msg))
    raise ValueError(f"key: expected one of {KEYS}, got {key!r}")


# --- colours ---------------------------------------------------------------------------------------

PALETTE = np.array(
    [
        [230, 25, 75], [60, 180, 75], [0, 130, 200], [245, 130, 48], [145, 30, 180],
        [70, 240, 240], [240, 50, 230], [210, 245, 60], [250, 190, 212], [0, 128, 128],
        [220, 190, 255], [170, 110, 40], [255, 225, 25], [128, 0, 0], [128, 128, 0],
    ],
    dtype=np.uint8,
)  # fmt: skip
"""Distinct object colours (Sasha Trubetskoy's list), indexed by object id modulo its length."""

_BACKGROUND = {-1: (185, 185, 185), -2: (165, 165, 160), -3: (90, 90, 90)}


def object_color(object_id: int) -> tuple[int, int, int]:
    r, g, b = PALETTE[int(object_id) % len(PALETTE)]
    return int(r), int(g), int(b)


def label_colors(labels: np.ndarray) -> np.ndarray:
    """``labels (N,)`` -> ``(N, 3)`` uint8: the palette for ids >= 0, greys for the rest."""
    labels = np.asarray(labels)
    if labels.ndim != 1:
        raise ValueError(f"labels must have shape (N,), got {labels.shape}")
    out = PALETTE[np.mod(labels, len(PALETTE))].copy()
    for value, grey in _BACKGROUND.items():
        out[labels == value] = grey
    out[labels < -3] = _BACKGROUND[-1]
    return out


_RAMP = np.array(
    [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], dtype=np.float64
)


def colormap(values: np.ndarray, vmax: float | None = None) -> np.ndarray:
    """``values (N,)`` >= 0 -> ``(N, 3)`` uint8 on a viridis-like ramp over ``[0, vmax]``
    (``vmax`` default: the maximum; all-zero maps are the ramp's bottom colour)."""
    v = np.nan_to_num(np.asarray(values, dtype=np.float64).reshape(-1), nan=0.0)
    top = float(np.max(v)) if vmax is None and v.size else float(vmax or 0.0)
    t = np.clip(v / top, 0.0, 1.0) if top > 0 else np.zeros_like(v)
    x = t * (len(_RAMP) - 1)
    i = np.minimum(np.floor(x).astype(int), len(_RAMP) - 2)
    f = (x - i)[:, None]
    return np.round(_RAMP[i] * (1 - f) + _RAMP[i + 1] * f).astype(np.uint8)
