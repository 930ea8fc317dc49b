"""Pushing tuples ``(s, a, s')`` (Ch. 4.3, 4.5) on disk and in memory.

On-disk format (``FORMAT``, version ``VERSION``): a split is a directory holding shard files
``shard-00000.npz, shard-00001.npz, ...`` and a ``manifest.json``. Every shard stores ``S``
tuples padded to ``M = max_objects`` objects:

====================  ===============  =========================================================
array                 shape / dtype    meaning
====================  ===============  =========================================================
``poses``             (S, M, 4, 4) f8  object-to-world poses ``T_i`` before the push (m)
``params``            (S, M, 9) f8     packed superquadric parameters (``geometry.PARAM_NAMES``)
``kinds``             (S, M) i1        superquadric kind (0 superellipsoid, 1 paraboloid, 2 toroid)
``mask``              (S, M) bool      real objects (padding rows are identity poses, zero params)
``action_p``          (S, 3) f8        push start point ``p`` in the world frame (m)
``action_v``          (S, 3) f8        push displacement ``v``: the tip moves to ``p + v`` (m)
``next_poses``        (S, M, 4, 4) f8  poses ``T'_i`` after the push
``object_ids``        (S, M) i4        catalogue id of each object (-1: unknown / padding)
``sequence``, ``step``  (S,) i8, i4    sequence index and push index within it (-1: unknown)
``cloud``             (S, P, 3) f4     optional observed cloud before the push (world frame, m)
``cloud_labels``      (S, P) i1        object index per cloud point (-1: table, -2: padding)
====================  ===============  =========================================================

``manifest.json``: ``{"format", "version", "max_objects", "count", "shards": [{"file",
"count"}], "meta": {...}}``; ``meta`` is free-form (generator settings, seeds, camera). Shards are
written atomically (temporary file, then rename) and named by index, so a generator running in
several processes writes its own shard indices and :func:`finalize_split` rebuilds the manifest
from whatever shards exist: generation can stop and resume at shard granularity.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sqmanip.geometry.superquadric import N_PARAMS

FORMAT = "sqmanip.push_tuples"
VERSION = 1
MANIFEST = "manifest.json"
_SHARD_RE = re.compile(r"^shard-(\d{5,})\.npz$")

__all__ = [
    "FORMAT",
    "VERSION",
    "PushBatch",
    "PushTensors",
    "PushTuple",
    "PushTupleWriter",
    "existing_shards",
    "finalize_split",
    "iter_tuples",
    "load_split",
    "read_manifest",
    "shard_path",
    "stack_tuples",
    "tensors_from_tuples",
    "write_tuples",
    "synthetic_tuples",
    "write_shard",
]


# --- one tuple ------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class PushTuple:
    """One pushing sample ``(s, a, s')`` with ``N`` objects (unpadded, numpy, world frame)."""

    poses: np.ndarray
    """``(N, 4, 4)`` object-to-world poses before the push."""
    params: np.ndarray
    """``(N, 9)`` packed superquadric parameters (object frame)."""
    kinds: np.ndarray
    """``(N,)`` superquadric kinds (int)."""
    action_p: np.ndarray
    """``(3,)`` push start point (m)."""
    action_v: np.ndarray
    """``(3,)`` push displacement (m)."""
    next_poses: np.ndarray
    """``(N, 4, 4)`` poses after the push."""
    object_ids: np.ndarray | None = None
    """``(N,)`` catalogue ids, or None."""
    cloud: np.ndarray | None = None
    """``(P, 3)`` observed points before the push, or None."""
    cloud_labels: np.ndarray | None = None
    """``(P,)`` object index per cloud point (-1: none); required with ``cloud``."""
    sequence: int = -1
    step: int = -1

    def __post_init__(self) -> None:
        poses = np.asarray(self.poses, dtype=np.float64)
        n = poses.shape[0] if poses.ndim == 3 else -1
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise ValueError(f"poses must have shape (N, 4, 4), got {poses.shape}")
        fields: dict[str, np.ndarray | None] = {
            "poses": poses,
            "params": np.asarray(self.params, dtype=np.float64),
            "kinds": np.asarray(self.kinds, dtype=np.int64),
            "action_p": np.asarray(self.action_p, dtype=np.float64),
            "action_v": np.asarray(self.action_v, dtype=np.float64),
            "next_poses": np.asarray(self.next_poses, dtype=np.float64),
        }
        expected = {
            "params": (n, N_PARAMS),
            "kinds": (n,),
            "action_p": (3,),
            "action_v": (3,),
            "next_poses": (n, 4, 4),
        }
        for name, shape in expected.items():
            if fields[name].shape != shape:
                raise ValueError(f"{name} must have shape {shape}, got {fields[name].shape}")
        for name in ("poses", "params", "action_p", "action_v", "next_poses"):
            if not np.isfinite(fields[name]).all():
                raise ValueError(f"{name} must be finite")
        if self.object_ids is not None:
            ids = np.asarray(self.object_ids, dtype=np.int64)
            if ids.shape != (n,):
                raise ValueError(f"object_ids must have shape ({n},), got {ids.shape}")
            fields["object_ids"] = ids
        if (self.cloud is None) != (self.cloud_labels is None):
            raise ValueError("cloud and cloud_labels must be given together")
        if self.cloud is not None:
            cloud = np.asarray(self.cloud, dtype=np.float32)
            labels = np.asarray(self.cloud_labels, dtype=np.int64)
            if cloud.ndim != 2 or cloud.shape[1] != 3:
                raise ValueError(f"cloud must have shape (P, 3), got {cloud.shape}")
            if labels.shape != (cloud.shape[0],):
                raise ValueError(
                    f"cloud_labels must have shape ({cloud.shape[0]},), got {labels.shape}"
                )
            if labels.size and (labels.min() < -1 or labels.max() >= n):
                raise ValueError(f"cloud_labels must lie in [-1, {n - 1}]")
            fields["cloud"], fields["cloud_labels"] = cloud, labels
        for name, value in fields.items():
            object.__setattr__(self, name, value)

    @property
    def num_objects(self) -> int:
        return int(self.poses.shape[0])


# --- writing --------------------------------------------------------------------------------------


def shard_path(root: str | Path, index: int) -> Path:
    """``root/shard-{index:05d}.npz``."""
    if index < 0:
        raise ValueError(f"index must be >= 0, got {index}")
    return Path(root) / f"shard-{index:05d}.npz"


def existing_shards(root: str | Path) -> list[int]:
    """Indices of the complete shards under ``root`` (sorted); temporary files are ignored."""
    root = Path(root)
    if not root.is_dir():
        return []
    found = (_SHARD_RE.match(p.name) for p in root.iterdir())
    return sorted(int(m.group(1)) for m in found if m)


def stack_tuples(tuples: Sequence[PushTuple], max_objects: int) -> dict[str, np.ndarray]:
    """Pad ``S`` tuples to ``max_objects`` and stack them into the shard arrays (module doc)."""
    s, m = len(tuples), max_objects
    for k, t in enumerate(tuples):
        if t.num_objects > m:
            raise ValueError(f"tuple {k} has {t.num_objects} objects, more than max_objects={m}")
    eye = np.broadcast_to(np.eye(4), (s, m, 4, 4))
    out: dict[str, np.ndarray] = {
        "poses": eye.copy(),
        "params": np.zeros((s, m, N_PARAMS)),
        "kinds": np.zeros((s, m), dtype=np.int8),
        "mask": np.zeros((s, m), dtype=bool),
        "action_p": np.zeros((s, 3)),
        "action_v": np.zeros((s, 3)),
        "next_poses": eye.copy(),
        "object_ids": np.full((s, m), -1, dtype=np.int32),
        "sequence": np.full(s, -1, dtype=np.int64),
        "step": np.full(s, -1, dtype=np.int32),
    }
    with_cloud = [t.cloud is not None for t in tuples]
    if any(with_cloud) and not all(with_cloud):
        raise ValueError("either every tuple of a shard has a cloud or none has")
    if s and all(with_cloud):
        p = max(t.cloud.shape[0] for t in tuples)  # type: ignore[union-attr]
        out["cloud"] = np.zeros((s, p, 3), dtype=np.float32)
        out["cloud_labels"] = np.full((s, p), -2, dtype=np.int8)
    for k, t in enumerate(tuples):
        n = t.num_objects
        out["poses"][k, :n] = t.poses
        out["params"][k, :n] = t.params
        out["kinds"][k, :n] = t.kinds
        out["mask"][k, :n] = True
        out["action_p"][k] = t.action_p
        out["action_v"][k] = t.action_v
        out["next_poses"][k, :n] = t.next_poses
        if t.object_ids is not None:
            out["object_ids"][k, :n] = t.object_ids
        out["sequence"][k], out["step"][k] = t.sequence, t.step
        if "cloud" in out:
            c = t.cloud.shape[0]  # type: ignore[union-attr]
            out["cloud"][k, :c] = t.cloud
            out["cloud_labels"][k, :c] = t.cloud_labels
    return out


def write_shard(
    root: str | Path, index: int, tuples: Sequence[PushTuple], max_objects: int
) -> Path:
    """Write one shard atomically (``.tmp`` then rename) and return its path."""
    path = shard_path(root, index)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = stack_tuples(tuples, max_objects)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
    os.replace(tmp, path)
    return path


def finalize_split(
    root: str | Path, max_objects: int, meta: dict[str, Any] | None = None
) -> dict[str, Any]:
    """(Re)write ``manifest.json`` from the shards present under ``root`` and return it."""
    root = Path(root)
    shards = []
    for index in existing_shards(root):
        path = shard_path(root, index)
        with np.load(path) as z:
            count = int(z["mask"].shape[0])
            if z["mask"].shape[1] != max_objects:
                raise ValueError(
                    f"{path.name} is padded to {z['mask'].shape[1]} objects, "
                    f"max_objects is {max_objects}"
                )
        shards.append({"file": path.name, "count": count})
    manifest = {
        "format": FORMAT,
        "version": VERSION,
        "max_objects": max_objects,
        "count": sum(s["count"] for s in shards),
        "shards": shards,
        "meta": meta or {},
    }
    tmp = root / (MANIFEST + ".tmp")
    tmp.write_text(json.dumps(manifest, indent=2) + "\n")
    os.replace(tmp, root / MANIFEST)
    return manifest


class PushTupleWriter:
    """Sequential writer: buffers tuples, writes a shard every ``shard_size`` and the manifest on
    :meth:`close`. Re-opening a directory appends after the shards already there (resume).

    >>> with PushTupleWriter(root, max_objects=4) as w:   # doctest: +SKIP
    ...     w.write(push_tuple)
    """

    def __init__(
        self,
        root: str | Path,
        max_objects: int = 4,
        shard_size: int = 1000,
        meta: dict[str, Any] | None = None,
    ) -> None:
        if max_objects < 1:
            raise ValueError(f"max_objects must be >= 1, got {max_objects}")
        if shard_size < 1:
            raise ValueError(f"shard_size must be >= 1, got {shard_size}")
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.max_objects = max_objects
        self.shard_size = shard_size
        self.meta = meta
        shards = existing_shards(self.root)
        self.next_index = shards[-1] + 1 if shards else 0
        self._buffer: list[PushTuple] = []

    def write(self, item: PushTuple) -> None:
        if item.num_objects > self.max_objects:
            raise ValueError(
                f"tuple has {item.num_objects} objects, more than max_objects={self.max_objects}"
            )
        self._buffer.append(item)
        if len(self._buffer) >= self.shard_size:
            self.flush()

    def flush(self) -> None:
        if self._buffer:
            write_shard(self.root, self.next_index, self._buffer, self.max_objects)
            self.next_index += 1
            self._buffer = []

    def close(self) -> dict[str, Any]:
        self.flush()
        return finalize_split(self.root, self.max_objects, self.meta)

    def __enter__(self) -> PushTupleWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --- reading --------------------------------------------------------------------------------------


def read_manifest(root: str | Path) -> dict[str, Any]:
    path = Path(root) / MANIFEST
    if not path.is_file():
        raise FileNotFoundError(f"no {MANIFEST} in {root}; run finalize_split on it first")
    manifest = json.loads(path.read_text())
    if manifest.get("format") != FORMAT or manifest.get("version") != VERSION:
        raise ValueError(
            f"{path} has format {manifest.get('format')!r} v{manifest.get('version')}, "
            f"expected {FORMAT!r} v{VERSION}"
        )
    return manifest


def _load_arrays(root: str | Path, with_cloud: bool) -> tuple[dict[str, np.ndarray], dict]:
    manifest = read_manifest(root)
    parts: list[dict[str, np.ndarray]] = []
    for shard in manifest["shards"]:
        with np.load(Path(root) / shard["file"]) as z:
            parts.append({k: z[k] for k in z.files if with_cloud or not k.startswith("cloud")})
    if not parts:
        empty = stack_tuples([], manifest["max_objects"])
        return empty, manifest
    if with_cloud and any("cloud" in p for p in parts):
        if not all("cloud" in p for p in parts):
            raise ValueError(f"some shards of {root} have clouds and some do not")
        width = max(p["cloud"].shape[1] for p in parts)
        for p in parts:
            pad = width - p["cloud"].shape[1]
            p["cloud"] = np.pad(p["cloud"], ((0, 0), (0, pad), (0, 0)))
            p["cloud_labels"] = np.pad(p["cloud_labels"], ((0, 0), (0, pad)), constant_values=-2)
    arrays = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return arrays, manifest


def iter_tuples(root: str | Path) -> Iterator[PushTuple]:
    """The tuples of a split, unpadded, in shard order."""
    manifest = read_manifest(root)
    for shard in manifest["shards"]:
        with np.load(Path(root) / shard["file"]) as z:
            a = {k: z[k] for k in z.files}
        for k in range(a["mask"].shape[0]):
            n = int(a["mask"][k].sum())
            cloud = labels = None
            if "cloud" in a:
                keep = a["cloud_labels"][k] >= -1
                cloud, labels = a["cloud"][k][keep], a["cloud_labels"][k][keep]
            yield PushTuple(
                poses=a["poses"][k, :n],
                params=a["params"][k, :n],
                kinds=a["kinds"][k, :n],
                action_p=a["action_p"][k],
                action_v=a["action_v"][k],
                next_poses=a["next_poses"][k, :n],
                object_ids=a["object_ids"][k, :n],
                cloud=cloud,
                cloud_labels=labels,
                sequence=int(a["sequence"][k]),
                step=int(a["step"][k]),
            )


# --- tensors for training -------------------------------------------------------------------------


@dataclasses.dataclass
class PushBatch:
    """A batch of ``B`` tuples padded to ``M`` objects, as tensors (world frame, metres)."""

    poses: torch.Tensor
    """``(B, M, 4, 4)``"""
    params: torch.Tensor
    """``(B, M, 9)``"""
    kinds: torch.Tensor
    """``(B, M)`` long"""
    mask: torch.Tensor
    """``(B, M)`` bool: real objects"""
    action_p: torch.Tensor
    """``(B, 3)``"""
    action_v: torch.Tensor
    """``(B, 3)``"""
    next_poses: torch.Tensor
    """``(B, M, 4, 4)``"""

    def __len__(self) -> int:
        return int(self.poses.shape[0])

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None):
        def conv(x: torch.Tensor) -> torch.Tensor:
            if x.is_floating_point() and dtype is not None:
                x = x.to(dtype)
            return x.to(device) if device is not None else x

        return PushBatch(**{f.name: conv(getattr(self, f.name)) for f in dataclasses.fields(self)})


@dataclasses.dataclass
class PushTensors:
    """A whole split in memory; :meth:`batches` yields :class:`PushBatch` slices."""

    batch: PushBatch
    cloud: torch.Tensor | None = None
    """``(S, P, 3)`` or None"""
    cloud_labels: torch.Tensor | None = None
    """``(S, P)`` long or None (-1: table, -2: padding)"""
    meta: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.batch)

    def select(self, index: torch.Tensor | slice) -> PushBatch:
        b = self.batch
        return PushBatch(**{f.name: getattr(b, f.name)[index] for f in dataclasses.fields(b)})

    def batches(
        self, batch_size: int, *, shuffle: bool = False, generator: torch.Generator | None = None
    ) -> Iterator[PushBatch]:
        n = len(self)
        order = torch.randperm(n, generator=generator) if shuffle else torch.arange(n)
        for start in range(0, n, batch_size):
            yield self.select(order[start : start + batch_size])

    def num_batches(self, batch_size: int) -> int:
        return math.ceil(len(self) / batch_size)


def _to_tensors(arrays: dict[str, np.ndarray], dtype: torch.dtype, meta: dict) -> PushTensors:
    def f(name: str) -> torch.Tensor:
        return torch.as_tensor(arrays[name], dtype=dtype)

    batch = PushBatch(
        poses=f("poses"),
        params=f("params"),
        kinds=torch.as_tensor(arrays["kinds"], dtype=torch.long),
        mask=torch.as_tensor(arrays["mask"], dtype=torch.bool),
        action_p=f("action_p"),
        action_v=f("action_v"),
        next_poses=f("next_poses"),
    )
    cloud = labels = None
    if "cloud" in arrays:
        cloud = torch.as_tensor(arrays["cloud"], dtype=dtype)
        labels = torch.as_tensor(arrays["cloud_labels"], dtype=torch.long)
    return PushTensors(batch, cloud, labels, meta)


def load_split(
    root: str | Path, *, dtype: torch.dtype = torch.float32, with_cloud: bool = False
) -> PushTensors:
    """Load every shard of a split into memory (12000 tuples are ~10 MB without clouds)."""
    arrays, manifest = _load_arrays(root, with_cloud)
    return _to_tensors(arrays, dtype, manifest.get("meta", {}))


def tensors_from_tuples(
    tuples: Sequence[PushTuple], max_objects: int, *, dtype: torch.dtype = torch.float32
) -> PushTensors:
    """In-memory :class:`PushTensors` without touching the disk (tests, small studies)."""
    return _to_tensors(stack_tuples(tuples, max_objects), dtype, {})


# --- synthetic tuples (tests, smoke runs) ---------------------------------------------------------


def _planar_pose(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = (x, y, z)
    return T


def synthetic_tuples(
    n: int,
    *,
    seed: int = 0,
    max_objects: int = 4,
    push_length: float = 0.08,
    pusher_radius: float = 0.01,
    spin: float = 4.0,
    workspace: float = 0.2,
) -> list[PushTuple]:
    """``n`` tuples from an analytic, SE(2)-equivariant push rule (not physics; for tests).

    Upright boxes (``e = 0.2``) and cylinders (``e1 = 0.2, e2 = 1``) with random sizes and yaws
    are placed without overlap; the action pushes one of them from one of 8 directions
    (as the 4.5 sampler). Each object whose disc (radius ``max(a1, a2)``) the pusher tip
    (a disc of ``pusher_radius``) reaches within ``push_length`` is translated by the remaining
    push distance along the push and turned by ``spin * offset * travel / radius`` (rad), where
    ``offset`` is its signed lateral distance from the push line. Objects do not push each other.
    """
    rng = np.random.default_rng(seed)
    out: list[PushTuple] = []
    while len(out) < n:
        count = int(rng.integers(1, max_objects + 1))
        centers: list[tuple[float, float, float]] = []
        params, kinds, poses = [], [], []
        for _ in range(200):
            if len(centers) == count:
                break
            a1, a2 = rng.uniform(0.02, 0.05, size=2)
            a3 = rng.uniform(0.02, 0.06)
            r = float(max(a1, a2))
            x, y = rng.uniform(-workspace, workspace, size=2)
            if any(math.hypot(x - cx, y - cy) < r + cr + 0.01 for cx, cy, cr in centers):
                continue
            cylinder = bool(rng.integers(2))
            if cylinder:
                a2 = a1
                r = float(a1)
            centers.append((float(x), float(y), r))
            params.append([a1, a2, a3, 0.2, 1.0 if cylinder else 0.2, 0.0, 0.0, 0.0, 0.0])
            kinds.append(0)
            poses.append(_planar_pose(x, y, a3, rng.uniform(-math.pi, math.pi)))
        target = int(rng.integers(len(centers)))
        cx, cy, cr = centers[target]
        ang = 2 * math.pi * int(rng.integers(8)) / 8 + rng.normal(0, 0.05)
        d = np.array([math.cos(ang), math.sin(ang)])
        lateral = rng.uniform(-0.8, 0.8) * cr
        start = np.array([cx, cy]) - (cr + pusher_radius + rng.uniform(0.0, 0.03)) * d
        start += lateral * np.array([-d[1], d[0]])
        height = rng.uniform(0.2, 0.8) * params[target][2] * 2
        p = np.array([start[0], start[1], height])
        v = np.array([d[0] * push_length, d[1] * push_length, 0.0])
        next_poses = []
        for (ox, oy, orad), T in zip(centers, poses, strict=True):
            rel = np.array([ox, oy]) - start
            along = float(rel @ d)
            off = float(rel @ np.array([-d[1], d[0]]))
            reach = orad + pusher_radius
            T2 = T.copy()
            if abs(off) < reach and along > 0:
                contact = along - math.sqrt(reach * reach - off * off)
                travel = push_length - max(contact, 0.0)
                if travel > 0:
                    dyaw = -spin * off * travel / orad
                    T2 = _planar_pose(ox + travel * d[0], oy + travel * d[1], T[2, 3], 0.0)
                    T2[:3, :3] = _planar_pose(0, 0, 0, dyaw)[:3, :3] @ T[:3, :3]
            next_poses.append(T2)
        out.append(
            PushTuple(
                poses=np.stack(poses),
                params=np.asarray(params),
                kinds=np.asarray(kinds),
                action_p=p,
                action_v=v,
                next_poses=np.stack(next_poses),
                sequence=len(out),
                step=0,
            )
        )
    return out


def write_tuples(
    root: str | Path,
    tuples: Iterable[PushTuple],
    *,
    max_objects: int = 4,
    shard_size: int = 1000,
    meta: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write ``tuples`` as a fresh split (shards + manifest) and return the manifest."""
    with PushTupleWriter(root, max_objects, shard_size, meta) as w:
        for t in tuples:
            w.write(t)
    return read_manifest(root)
