"""Inference with trained recognition networks: segments -> world-frame superquadrics.

:class:`NetworkRecognizer` wraps DSQNet / SQNet / DSQNet+ (3.3, 3.6.2): each segment is resampled
to the network's point count (random subset down, tangent-plane up-sampling of 3.5.3 up),
normalised (:class:`~.models.PCANormalizer`), predicted in one batch, and mapped back to the world
(the normaliser's inverse: pose ``T_w = F S T_n``, sizes times the scale, bending over it).
:class:`NetworkSegmenter` wraps the DGCNN segmentation network (A.2).

A model directory holds ``model.pt`` (state dict, loaded with ``weights_only=True``) and
``config.toml`` (written by :func:`~.train.save_model_dir`).
"""

from __future__ import annotations

import tomllib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from sqmanip.geometry.types import Superquadric

from .config import SQ_MODELS, ModelConfig, model_config
from .datasets import resample_labelled
from .models import PCANormalizer, SegNet, SuperquadricNet, build_model

__all__ = ["NetworkRecognizer", "NetworkSegmenter", "load_model", "to_superquadric"]


def to_superquadric(params: np.ndarray, pose: np.ndarray) -> Superquadric:
    """A superellipsoid :class:`Superquadric` from packed ``(9,)`` params and a ``(4, 4)`` pose."""
    p = np.asarray(params, dtype=np.float64)
    return Superquadric(
        size=(float(p[0]), float(p[1]), float(p[2])),
        shape=(float(p[3]), float(p[4])),
        pose=np.asarray(pose, dtype=np.float64),
        taper=float(p[5]),
        bend=float(p[6]),
        bend_direction=float(p[7]),
    )


def load_model(model_dir: str | Path, device: str | torch.device = "cpu"):
    """``(model, config)`` from a model directory (``model.pt`` + ``config.toml``), in eval mode."""
    d = Path(model_dir)
    cfg_path, w_path = d / "config.toml", d / "model.pt"
    for p in (cfg_path, w_path):
        if not p.exists():
            raise FileNotFoundError(f"model directory {d} lacks {p.name}")
    with cfg_path.open("rb") as fh:
        table = dict(tomllib.load(fh)["model"])
    name = table.pop("name")
    cfg: ModelConfig = model_config(
        name, **{k: tuple(v) if isinstance(v, list) else v for k, v in table.items()}
    )
    model = build_model(name, cfg)
    model.load_state_dict(torch.load(w_path, map_location="cpu", weights_only=True))
    return model.to(device).eval(), cfg


def _check_cloud(points, field: str) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{field} must have shape (n, 3), got {arr.shape}")
    if len(arr) == 0:
        raise ValueError(f"{field} must hold at least one point, got 0")
    if not np.isfinite(arr).all():
        raise ValueError(f"{field} must be finite")
    return arr


def context_input(
    segment: np.ndarray, context: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """DSQNet+ input (3.6.2): ``n`` points of ``segment`` and ``context`` and their 0/1 segment
    mask. Context points that coincide with segment points (1e-9 m) count as the segment; the
    mix keeps the segment's share of the union (at least one segment point)."""
    if len(context):
        d, _ = cKDTree(segment).query(context)
        ctx = context[d > 1e-9]
    else:
        ctx = context
    pts = np.concatenate([segment, ctx])
    lab = np.concatenate([np.ones(len(segment), np.int64), np.zeros(len(ctx), np.int64)])
    if len(pts) < n:
        return resample_labelled(pts, lab, n, rng)
    n_seg = int(np.clip(round(len(segment) / len(pts) * n), 1, min(n, len(segment))))
    n_ctx = n - n_seg
    if n_ctx > len(ctx):
        n_ctx, n_seg = len(ctx), n - len(ctx)
    si = rng.choice(len(segment), n_seg, replace=False)
    ci = rng.choice(len(ctx), n_ctx, replace=False)
    out = np.concatenate([segment[si], ctx[ci]])
    return out, np.concatenate([np.ones(n_seg, np.int64), np.zeros(n_ctx, np.int64)])


class NetworkRecognizer:
    """Segments -> superquadrics with a trained DSQNet / SQNet / DSQNet+ (CPU-friendly, batched)."""

    def __init__(
        self, model: SuperquadricNet, device: str | torch.device = "cpu", seed: int = 0
    ) -> None:
        if not isinstance(model, SuperquadricNet):
            raise ValueError(f"model must be a SuperquadricNet, got {type(model).__name__}")
        self.model = model.eval()
        self.config = model.config
        self.device = torch.device(device)
        self.seed = seed
        self.normalizer = PCANormalizer()

    @classmethod
    def load(
        cls, model_dir: str | Path, device: str | torch.device = "cpu", seed: int = 0
    ) -> NetworkRecognizer:
        model, cfg = load_model(model_dir, device)
        if cfg.name not in SQ_MODELS:
            raise ValueError(
                f"{model_dir} holds a {cfg.name!r} model; NetworkRecognizer needs one of "
                f"{list(SQ_MODELS)}"
            )
        return cls(model, device, seed)

    @property
    def name(self) -> str:
        return self.config.name

    @torch.no_grad()
    def predict(
        self, segments: Sequence[np.ndarray], context: np.ndarray | None = None
    ) -> list[Superquadric]:
        """One world-frame :class:`Superquadric` per segment ``(n_i, 3)`` (object-to-world pose).

        ``context (M, 3)`` is the whole object's cloud for DSQNet+ (default: the union of the
        segments); the other networks ignore it. Deterministic for a given ``seed``.
        """
        segs = [_check_cloud(s, f"segments[{i}]") for i, s in enumerate(segments)]
        if not segs:
            return []
        rng = np.random.default_rng(self.seed)
        n = self.config.n_points
        if self.config.in_dim == 4:
            ctx = np.concatenate(segs) if context is None else _check_cloud(context, "context")
            cloud, mask = zip(*(context_input(s, ctx, n, rng) for s in segs), strict=True)
            pts = torch.as_tensor(np.stack(cloud), dtype=torch.float32, device=self.device)
            m = torch.as_tensor(np.stack(mask) > 0, device=self.device)
            xn, frame = self.normalizer(pts, m)
            x = torch.cat([xn, m.unsqueeze(-1).float()], -1)
        else:
            cloud = [resample_labelled(s, np.zeros(len(s), np.int64), n, rng)[0] for s in segs]
            pts = torch.as_tensor(np.stack(cloud), dtype=torch.float32, device=self.device)
            x, frame = self.normalizer(pts)
        pred = self.model(x)
        pose = frame.pose_to_world(pred.pose()).double().cpu().numpy()
        params = frame.params_to_world(pred.params()).double().cpu().numpy()
        return [to_superquadric(params[i], pose[i]) for i in range(len(segs))]


class NetworkSegmenter:
    """Object / scene cloud -> part labels with the DGCNN segmentation network (A.2)."""

    def __init__(self, model: SegNet, device: str | torch.device = "cpu", seed: int = 0) -> None:
        if not isinstance(model, SegNet):
            raise ValueError(f"model must be a SegNet, got {type(model).__name__}")
        self.model = model.eval()
        self.config = model.config
        self.device = torch.device(device)
        self.seed = seed
        self.normalizer = PCANormalizer()

    @classmethod
    def load(
        cls, model_dir: str | Path, device: str | torch.device = "cpu", seed: int = 0
    ) -> NetworkSegmenter:
        model, cfg = load_model(model_dir, device)
        if cfg.name != "segnet":
            raise ValueError(f"{model_dir} holds a {cfg.name!r} model, not 'segnet'")
        return cls(model, device, seed)

    @torch.no_grad()
    def segment(self, points: np.ndarray) -> np.ndarray:
        """Labels ``(N,)`` (consecutive from 0) for ``points (N, 3)``: the network labels a
        resampled cloud and every input point takes the label of its nearest sample."""
        pts = _check_cloud(points, "points")
        rng = np.random.default_rng(self.seed)
        sample, _ = resample_labelled(pts, np.zeros(len(pts), np.int64), self.config.n_points, rng)
        x, _ = self.normalizer(torch.as_tensor(sample[None], dtype=torch.float32))
        lab = self.model(x.to(self.device)).argmax(-1)[0].cpu().numpy()
        _, nn = cKDTree(sample).query(pts)
        _, out = np.unique(lab[nn], return_inverse=True)
        return out.reshape(-1).astype(np.int64)
