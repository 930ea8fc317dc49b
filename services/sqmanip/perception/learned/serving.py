"""Serving the learned recognition networks inside perception (``method = network | hybrid``,
``segmentation = network``).

- :func:`default_model_dir`: ``models/<name>`` under the working directory if it exists, else
  under the repository (the layout of the shipped checkpoints, like the dynamics service).
- :func:`get_recognizer` / :func:`get_segmenter`: each model directory is loaded at most once per
  process (thread-safe), on the CPU, with ``torch.load(weights_only=True)``; a missing or
  unreadable checkpoint is a :class:`~sqmanip.errors.PreconditionError` naming the path.
- :func:`predict_parts`: segments -> world-frame superquadrics with DSQNet (3.3) / SQNet /
  DSQNet+ (3.6.2), run with the service's torch thread count.
- :func:`segment_object`: an object's cloud -> part index arrays with the DGCNN segmentation
  network (A.2).

Nothing here is imported by perception until a request asks for a learned method, so the
training-free path never pays for loading networks.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sqmanip.errors import PreconditionError
from sqmanip.geometry import Superquadric

from ..threads import torch_threads
from .infer import NetworkRecognizer, NetworkSegmenter

__all__ = [
    "DEFAULT_RECOGNITION_MODEL",
    "DEFAULT_SEGMENTATION_MODEL",
    "REPO",
    "clear_cache",
    "default_model_dir",
    "get_recognizer",
    "get_segmenter",
    "predict_parts",
    "segment_object",
]

REPO = Path(__file__).resolve().parents[4]
DEFAULT_RECOGNITION_MODEL = "dsqnet_cpu"
"""Shipped DSQNet (reduced CPU config, ``models/dsqnet_cpu``); see its MODEL_CARD.md."""
DEFAULT_SEGMENTATION_MODEL = "segnet_cpu"
"""Where a trained segmentation network is expected (``models/segnet_cpu``); none is shipped."""

_LOCK = threading.Lock()
_CACHE: dict[tuple[str, Path], NetworkRecognizer | NetworkSegmenter] = {}


def default_model_dir(name: str) -> Path:
    """``models/<name>`` under the working directory if it exists, else under the repository."""
    local = Path.cwd() / "models" / name
    return local if local.is_dir() else REPO / "models" / name


def clear_cache() -> None:
    """Forget every loaded network (tests; a redeployed checkpoint is picked up again)."""
    with _LOCK:
        _CACHE.clear()


def _load(kind: str, model_dir: str | Path | None, default: str, what: str):
    path = Path(model_dir) if model_dir is not None else default_model_dir(default)
    key = (kind, path.resolve())
    with _LOCK:
        hit = _CACHE.get(key)
        if hit is not None:
            return hit
        missing = [f for f in ("config.toml", "model.pt") if not (path / f).is_file()]
        if missing:
            raise PreconditionError(
                f"{what} needs a trained checkpoint at {path} ({', '.join(missing)} missing); "
                f"train one with `sqmanip train ...` and set the model directory "
                f"(SQMANIP_PERCEPTION_{kind.upper()}_MODEL_DIR), or use a training-free method"
            )
        cls = NetworkRecognizer if kind == "network" else NetworkSegmenter
        try:
            model = cls.load(path, device="cpu")
        except (ValueError, RuntimeError, KeyError, OSError) as exc:
            raise PreconditionError(f"cannot load the {what} checkpoint at {path}: {exc}") from exc
        _CACHE[key] = model
        return model


def get_recognizer(model_dir: str | Path | None = None) -> NetworkRecognizer:
    """The process-wide :class:`NetworkRecognizer` of ``model_dir`` (default
    ``models/dsqnet_cpu``), loaded on first use."""
    return _load("network", model_dir, DEFAULT_RECOGNITION_MODEL, "options.method='network'")


def get_segmenter(model_dir: str | Path | None = None) -> NetworkSegmenter:
    """The process-wide :class:`NetworkSegmenter` of ``model_dir`` (default
    ``models/segnet_cpu``), loaded on first use."""
    return _load(
        "segmentation", model_dir, DEFAULT_SEGMENTATION_MODEL, "options.segmentation='network'"
    )


def predict_parts(
    segments: Sequence[np.ndarray],
    *,
    model_dir: str | Path | None = None,
    threads: int | None = 1,
    seed: int = 0,
    context: np.ndarray | None = None,
) -> list[Superquadric]:
    """One world-frame superquadric per segment ``(n_i, 3)`` predicted by the network in
    ``model_dir`` (one batched forward pass). ``context (M, 3)`` is the whole object's cloud
    for DSQNet+; deterministic for ``seed``."""
    rec = get_recognizer(model_dir)
    if not segments:
        return []
    with torch_threads(threads):
        rec.seed = seed
        return rec.predict(segments, context=context)


def segment_object(
    points: np.ndarray,
    *,
    model_dir: str | Path | None = None,
    threads: int | None = 1,
    seed: int = 0,
    min_points: int = 10,
) -> list[np.ndarray]:
    """Index arrays into ``points (N, 3)`` of the parts the segmentation network finds, largest
    first; parts with fewer than ``min_points`` points join the part of their nearest point."""
    seg = get_segmenter(model_dir)
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < max(2, min_points):
        return [np.arange(len(pts))] if len(pts) else []
    with torch_threads(threads):
        seg.seed = seed
        labels = seg.segment(pts)
    counts = np.bincount(labels)
    big = np.flatnonzero(counts >= min_points)
    if len(big) == 0:
        return [np.arange(len(pts))]
    small = ~np.isin(labels, big)
    if small.any():
        from scipy.spatial import cKDTree

        keep = np.flatnonzero(~small)
        _, nn = cKDTree(pts[keep]).query(pts[small])
        labels = labels.copy()
        labels[small] = labels[keep[nn]]
    order = sorted(big, key=lambda lab: -int((labels == lab).sum()))
    return [np.flatnonzero(labels == lab) for lab in order]
