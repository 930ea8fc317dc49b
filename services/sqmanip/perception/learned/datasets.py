"""Synthetic primitive and object datasets for the recognition networks (Appendix A.1, Tables A.1-A.2).

Shapes are written as (deformable) superquadrics, so ground truth, rendering and IoU all use the
geometry core:

- box ``B`` (w, d, h): ``a = (w, d, h) / 2``, ``e = (0.2, 0.2)``;
- ellipsoid ``E`` (a, b, c semi-axes): ``e = (1, 1)``;
- cylinder ``CY`` (r, h): ``a = (r, r, h / 2)``, ``e = (0.2, 1)``;
- cone ``C`` (base radius r, h): a cylinder tapered with ``k = -0.9`` (the network's bound of
  Table 3.1, so the target is representable): ``a1 = a2 = r / 1.9`` gives radius ``r`` at the
  base and ``0.1 a1`` (~5 % of ``r``) at the tip;
- truncated cone ``TC`` (base R, top r, h): ``a1 = a2 = (R + r) / 2``, ``k = (r - R) / (R + r)``
  (in [-0.67, -0.11] for Table A.1's ranges);
- truncated torus ``TT`` (tube r, ring R, c): a cylinder bent with ``b = 1 / R``, ``a3 = R c``.
  ``c`` is read as the *half* angle of the arc (arc ``2c``): the padlock's shackle (c in
  [1.37, 1.77], arc ~ pi) then is the U of a real padlock and the mug handle a C.

Objects (Table A.2) are assemblies of these parts with touching or slightly overlapping parts.
Every shape gets a uniformly random orientation and is seen from 16 directions (a Fibonacci
sphere) by a pinhole camera 0.3-0.7 m beyond its bounding sphere, zoomed so the sphere fills the
image (:func:`render_view`). Partial clouds are the exact first ray hits (:mod:`geometry.render`),
re-rendered at twice the resolution while too few points are seen, then randomly down-sampled (or
up-sampled on local tangent planes, 3.5.3) to 300 points per primitive / 1000 per object (with
part labels), and get the noise of A.1 (``x + m v``, ``m ~ N(0, 1 mm)``, ``v`` on ``S^2``).
Ground truth: 1500 near-uniform surface points per part (:func:`geometry.sampling.sample_surface`).

Views that show a single plane are excluded (A.1): :func:`is_single_plane` fits a plane to the
noise-free cloud (PCA) and flags the view when 90 % of the points lie within 2 % of the cloud's
extent of it (one face of a box, or a cylinder's cap, seen within ~5 degrees of head-on).

Layout: ``OUT/{primitive,object}/{TYPE}_{block:04d}.npz`` shards of ``SHAPES_PER_SHARD`` shapes,
written atomically, so an interrupted run resumes by skipping finished shards. Each shape's
parameters come from its own seed ``(seed, dataset, type, index)``: the same index gives the same
shape at any ``--scale``. The last 10 % of each type's shape indices form the test split (by
shape, so no test shape is seen from another view in training).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import multiprocessing as mp
import os
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from sqmanip.geometry.iou import shapes_bounds
from sqmanip.geometry.render import PinholeCamera, render_point_cloud
from sqmanip.geometry.sampling import sample_surface
from sqmanip.geometry.transforms import quat_to_matrix
from sqmanip.geometry.types import Superquadric

from .models import NormalizedFrame, PCANormalizer

__all__ = [
    "DATASETS",
    "OBJECT_TYPES",
    "PRIMITIVE_TYPES",
    "GenerationSpec",
    "ObjectPartDataset",
    "PrimitiveDataset",
    "SQBatch",
    "SegBatch",
    "SegmentationDataset",
    "add_cli",
    "generate",
    "is_single_plane",
    "load_dataset",
    "object_parts",
    "primitive_parts",
    "render_view",
]

PRIMITIVE_TYPES = ("B", "E", "CY", "C", "TC", "TT")
MULTI_PART_TYPES = ("bottle", "hammer", "mug", "dumbbell", "padlock", "screwdriver")
OBJECT_TYPES = PRIMITIVE_TYPES + MULTI_PART_TYPES
DATASETS = ("primitive", "object")
MAX_PARTS = 3
N_VIEWS = 16
N_GT = 1500
N_PARTIAL = {"primitive": 300, "object": 1000}
SHAPES_PER_SHARD = 5
CONE_TAPER = -0.9
NOISE_STD = 0.001
"""A.1 / B.2: zero-mean Gaussian noise magnitude (m) along a uniformly random direction."""


def shapes_per_type(dataset: str, type_name: str, scale: float) -> int:
    """A.1: 100 shapes per type, 300 for the primitive truncated torus (balances bending)."""
    base = 300 if (dataset == "primitive" and type_name == "TT") else 100
    return max(1, int(round(base * scale)))


def n_test(n: int) -> int:
    """Test shapes of a type with ``n`` shapes: 10 %, at least one when ``n >= 2``."""
    return 0 if n < 2 else max(1, int(round(0.1 * n)))


# --- shape parameters (Tables A.1, A.2) ----------------------------------------------------------


def _pose(R: np.ndarray | None = None, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    T[:3, 3] = t
    return T


def box(w: float, d: float, h: float, pose=None) -> Superquadric:
    return Superquadric((w / 2, d / 2, h / 2), (0.2, 0.2), _pose() if pose is None else pose)


def ellipsoid(a: float, b: float, c: float, pose=None) -> Superquadric:
    return Superquadric((a, b, c), (1.0, 1.0), _pose() if pose is None else pose)


def cylinder(r: float, h: float, pose=None) -> Superquadric:
    return Superquadric((r, r, h / 2), (0.2, 1.0), _pose() if pose is None else pose)


def cone(r: float, h: float, pose=None) -> Superquadric:
    a = r / (1.0 - CONE_TAPER)
    return Superquadric(
        (a, a, h / 2), (0.2, 1.0), _pose() if pose is None else pose, taper=CONE_TAPER
    )


def truncated_cone(R: float, r: float, h: float, pose=None) -> Superquadric:
    a = (R + r) / 2
    return Superquadric(
        (a, a, h / 2), (0.2, 1.0), _pose() if pose is None else pose, taper=(r - R) / (R + r)
    )


def truncated_torus(r: float, R: float, c: float, pose=None) -> Superquadric:
    """Tube radius ``r``, ring radius ``R``, half arc angle ``c``; the arc's midpoint is the
    origin, its tangent the z axis, and the ring's centre at ``(R, 0, 0)`` (bend toward +x)."""
    return Superquadric((r, r, R * c), (0.2, 1.0), _pose() if pose is None else pose, bend=1.0 / R)


def primitive_parts(type_name: str, rng: np.random.Generator) -> list[Superquadric]:
    """One primitive of Table A.1 in its own frame (the list holds one part)."""
    u = rng.uniform
    if type_name == "B":
        return [box(u(0.02, 0.3), u(0.02, 0.3), u(0.02, 0.3))]
    if type_name == "E":
        return [ellipsoid(u(0.03, 0.07), u(0.03, 0.07), u(0.03, 0.07))]
    if type_name == "CY":
        return [cylinder(u(0.01, 0.075), u(0.03, 0.3))]
    if type_name == "C":
        return [cone(u(0.02, 0.07), u(0.03, 0.15))]
    if type_name == "TC":
        R = u(0.025, 0.1)  # r in [0.02, 0.8 R] needs R >= 0.025
        return [truncated_cone(R, u(0.02, 0.8 * R), u(0.02, 0.3))]
    if type_name == "TT":
        return [truncated_torus(u(0.01, 0.015), u(0.02, 0.075), u(math.pi / 3, 2 * math.pi / 3))]
    raise ValueError(f"Unknown primitive type {type_name!r}. Available: {list(PRIMITIVE_TYPES)}")


_RY90 = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])  # local z -> world x


def object_parts(type_name: str, rng: np.random.Generator) -> list[Superquadric]:
    """Parts of one object of Table A.2 in the object frame (label = list index)."""
    if type_name in PRIMITIVE_TYPES:
        return primitive_parts(type_name, rng)
    u = rng.uniform
    if type_name == "bottle":
        r1, h1 = u(0.02, 0.07), u(0.06, 0.15)
        r, h = u(0.01, 0.04), u(0.02, 0.1)
        r = min(r, 0.95 * r1)  # the shoulder narrows from the body
        r2, h2 = u(r, max(r, 0.02)), u(0.01, 0.04)  # "r2 in [r, 0.02]"; r2 = r when r > 0.02
        return [
            cylinder(r1, h1, _pose(t=(0, 0, h1 / 2))),
            truncated_cone(r1, r, h, _pose(t=(0, 0, h1 + h / 2))),
            cylinder(r2, h2, _pose(t=(0, 0, h1 + h + h2 / 2))),
        ]
    if type_name == "hammer":
        r1, h1 = u(0.025, 0.06), u(0.09, 0.2)
        r2, h2 = u(0.012, 0.02), u(0.05, 0.3)
        return [
            cylinder(r1, h1, _pose(_RY90)),  # head along x
            cylinder(r2, h2, _pose(t=(0, 0, -(0.8 * r1 + h2 / 2)))),  # handle into the head
        ]
    if type_name == "mug":
        r, h = u(0.03, 0.06), u(0.08, 0.15)
        rt, R, c = u(0.003, 0.01), u(0.03, 0.05), u(1.27, 2.09)
        R = min(R, 0.45 * h / math.sin(c))  # the handle's ends stay on the wall
        xc = r - 0.5 * rt - R * math.cos(c)  # ring centre: arc ends at angle +-c meet the wall
        Rz180 = np.diag([-1.0, -1.0, 1.0])  # local +x (ring centre) -> world -x
        return [cylinder(r, h), truncated_torus(rt, R, c, _pose(Rz180, (xc + R, 0, 0)))]
    if type_name == "dumbbell":
        r1, h1 = u(0.02, 0.04), u(0.02, 0.05)
        r2, h2 = u(0.012, 0.018), u(0.09, 0.11)
        z = h2 / 2 + h1 / 2
        return [
            cylinder(r1, h1, _pose(t=(0, 0, z))),
            cylinder(r2, h2),
            cylinder(r1, h1, _pose(t=(0, 0, -z))),
        ]
    if type_name == "padlock":
        w, d, h = u(0.015, 0.03), u(0.03, 0.045), u(0.04, 0.06)
        rt, R, c = u(0.003, 0.005), u(0.01, 0.02), u(1.37, 1.77)
        R = min(R, d / 2 - rt)  # shackle ends on the top face
        zc = h / 2 - 0.5 * rt - R * math.cos(c)
        # local x (ring centre) -> world -z, local z (tangent at the apex) -> world y
        Rs = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])
        return [box(w, d, h), truncated_torus(rt, R, c, _pose(Rs, (0, 0, zc + R)))]
    if type_name == "screwdriver":
        r1, h1 = u(0.0025, 0.004), u(0.08, 0.12)
        r2, h2 = u(0.01, 0.02), u(0.06, 0.1)
        return [
            cylinder(r1, h1, _pose(t=(0, 0, h2 + h1 / 2 - 0.005))),  # shaft, 5 mm in the handle
            cylinder(r2, h2, _pose(t=(0, 0, h2 / 2))),
        ]
    raise ValueError(f"Unknown object type {type_name!r}. Available: {list(OBJECT_TYPES)}")


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Uniform random rotation (normalised Gaussian quaternion)."""
    q = rng.normal(size=4)
    return quat_to_matrix(torch.as_tensor(q / np.linalg.norm(q))).numpy()


def place(parts: Sequence[Superquadric], T: np.ndarray) -> list[Superquadric]:
    return [p.with_pose(T @ p.pose) for p in parts]


def fibonacci_directions(n: int) -> np.ndarray:
    """``n`` near-uniform unit directions ``(n, 3)`` (golden-angle spiral)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = i * math.pi * (3 - math.sqrt(5))
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


# --- views -----------------------------------------------------------------------------------------


def is_single_plane(points: np.ndarray, quantile: float = 0.9, rel_tol: float = 0.02) -> bool:
    """Whether a (noise-free) view shows a single plane (A.1: such views are excluded).

    A plane is fitted by PCA; the view is planar when ``quantile`` of the points lie within
    ``rel_tol * extent`` of it. The tolerance absorbs the slightly domed faces and rounded rims of
    ``e = 0.2`` boxes and cylinder caps (a box face seen head-on: 90 % within 1.5 % of the
    extent; 10 degrees off, where a side face shows: 2.1 %). Fewer than 3 points count as planar.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    if len(pts) < 3:
        return True
    extent = float(np.linalg.norm(pts.max(0) - pts.min(0)))
    c = pts.mean(0)
    _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
    d = np.abs((pts - c) @ vt[-1])
    return bool(np.quantile(d, quantile) <= rel_tol * extent)


def add_noise(points: np.ndarray, rng: np.random.Generator, std: float = NOISE_STD) -> np.ndarray:
    """A.1: ``x + m v`` with ``m ~ N(0, std)`` and ``v`` uniform on the unit sphere."""
    v = rng.normal(size=points.shape)
    v /= np.linalg.norm(v, axis=-1, keepdims=True).clip(1e-12)
    return points + rng.normal(0.0, std, size=(*points.shape[:-1], 1)) * v


def resample_labelled(
    points: np.ndarray, labels: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Exactly ``n`` points: a random subset, or tangent-plane up-sampling (3.5.3) with the
    label of each new point's nearest original point."""
    if len(points) >= n:
        keep = np.sort(rng.choice(len(points), n, replace=False))
        return points[keep], labels[keep]
    from sqmanip.perception.preprocess import resample

    up = resample(points, n, rng)
    _, nn = cKDTree(points).query(up[len(points) :])
    return up, np.concatenate([labels, labels[nn]])


@dataclasses.dataclass(frozen=True)
class View:
    points: np.ndarray
    """``(n, 3)`` noisy world points (float32); empty when excluded for having no hits."""
    labels: np.ndarray
    """``(n,)`` part index of each point."""
    camera: np.ndarray
    """Camera-to-world pose ``(4, 4)``."""
    single_plane: bool
    n_hits: int
    """Visible points before resampling."""


def render_view(
    parts: Sequence[Superquadric],
    direction: np.ndarray,
    rng: np.random.Generator,
    n_points: int,
    *,
    resolution: int = 96,
    max_resolution: int = 384,
    noise: float = NOISE_STD,
) -> View:
    """Partial cloud of ``parts`` seen from ``direction`` (unit, from the shape toward the camera)."""
    lo, hi = shapes_bounds(parts, margin=0.0)
    centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2)
    dist = radius + rng.uniform(0.3, 0.7)
    eye = centre + dist * np.asarray(direction, dtype=np.float64)
    half_angle = math.asin(min(0.999, radius / dist))
    res = resolution
    while True:
        f = 0.5 * res / math.tan(half_angle)
        cam = PinholeCamera.look_at(
            eye, centre, fx=f, fy=f, cx=res / 2 - 0.5, cy=res / 2 - 0.5, width=res, height=res
        )
        pts, ids = render_point_cloud(parts, cam)
        if len(pts) >= n_points or res >= max_resolution:
            break
        res *= 2
    n_hits = len(pts)
    if n_hits == 0:
        return View(np.zeros((0, 3), np.float32), np.zeros(0, np.int8), cam.pose, True, 0)
    planar = is_single_plane(pts)
    pts, lab = resample_labelled(pts, ids.astype(np.int64), n_points, rng)
    pts = add_noise(pts, rng, noise) if noise > 0 else pts
    return View(pts.astype(np.float32), lab.astype(np.int8), cam.pose, planar, n_hits)


# --- generation ----------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class GenerationSpec:
    """What to generate. ``scale`` multiplies A.1's 100 (300 for TT) shapes per type."""

    out: str
    scale: float = 1.0
    seed: int = 0
    datasets: tuple[str, ...] = DATASETS
    types: tuple[str, ...] | None = None
    """Restrict to these types (default: all of the dataset's types)."""
    n_views: int = N_VIEWS
    n_gt: int = N_GT
    shapes: int | None = None
    """Override: this many shapes per type (ignores ``scale``)."""
    shapes_per_shard: int = SHAPES_PER_SHARD
    resolution: int = 96

    def __post_init__(self) -> None:
        for d in self.datasets:
            if d not in DATASETS:
                raise ValueError(f"Unknown dataset {d!r}. Available: {list(DATASETS)}")
        if self.scale <= 0:
            raise ValueError(f"scale must be positive, got {self.scale}")
        if not 1 <= self.n_views <= 64:
            raise ValueError(f"n_views must be in [1, 64], got {self.n_views}")


@dataclasses.dataclass(frozen=True)
class ShardJob:
    spec: GenerationSpec
    dataset: str
    type_name: str
    block: int
    indices: tuple[int, ...]
    n_total: int

    @property
    def path(self) -> Path:
        return Path(self.spec.out) / self.dataset / f"{self.type_name}_{self.block:04d}.npz"


def _types(dataset: str) -> tuple[str, ...]:
    return PRIMITIVE_TYPES if dataset == "primitive" else OBJECT_TYPES


def shard_jobs(spec: GenerationSpec) -> list[ShardJob]:
    jobs = []
    for dataset in spec.datasets:
        for type_name in _types(dataset):
            if spec.types is not None and type_name not in spec.types:
                continue
            n = spec.shapes or shapes_per_type(dataset, type_name, spec.scale)
            for block, start in enumerate(range(0, n, spec.shapes_per_shard)):
                idx = tuple(range(start, min(n, start + spec.shapes_per_shard)))
                jobs.append(ShardJob(spec, dataset, type_name, block, idx, n))
    return jobs


def _shape_rng(seed: int, dataset: str, type_name: str, index: int) -> np.random.Generator:
    key = [seed, DATASETS.index(dataset), OBJECT_TYPES.index(type_name), index]
    return np.random.default_rng(np.random.SeedSequence(key))


def make_shard(job: ShardJob) -> dict[str, np.ndarray]:
    """All views of the shapes of one shard (deterministic in the spec's seed)."""
    spec, dataset = job.spec, job.dataset
    n_pts = N_PARTIAL[dataset]
    type_id = OBJECT_TYPES.index(job.type_name)
    dirs = fibonacci_directions(spec.n_views)
    S = len(job.indices)
    params = np.zeros((S, MAX_PARTS, 9), np.float32)
    poses = np.tile(np.eye(4, dtype=np.float32), (S, MAX_PARTS, 1, 1))
    gt = np.zeros((S, MAX_PARTS, spec.n_gt, 3), np.float32)
    n_parts = np.zeros(S, np.int8)
    test = np.zeros(S, bool)
    partial, labels, shape_idx, view_idx, cams, n_hits = [], [], [], [], [], []
    excluded = 0
    for s, index in enumerate(job.indices):
        rng = _shape_rng(spec.seed, dataset, job.type_name, index)
        local = object_parts(job.type_name, rng)
        parts = place(local, _pose(random_rotation(rng)))
        n_parts[s] = len(parts)
        test[s] = index >= job.n_total - n_test(job.n_total)
        g = torch.Generator().manual_seed(int(rng.integers(2**62)))
        for j, p in enumerate(parts):
            params[s, j] = p.params()
            poses[s, j] = p.pose
            pts, _ = sample_surface(torch.as_tensor(p.params()), spec.n_gt, generator=g)
            gt[s, j] = pts.numpy() @ p.pose[:3, :3].T + p.pose[:3, 3]
        for v in range(spec.n_views):
            view = render_view(parts, dirs[v], rng, n_pts, resolution=spec.resolution)
            if view.single_plane:
                excluded += 1
                continue
            partial.append(view.points)
            labels.append(view.labels)
            shape_idx.append(s)
            view_idx.append(v)
            cams.append(view.camera.astype(np.float32))
            n_hits.append(view.n_hits)
    M = len(partial)
    return {
        "partial": np.stack(partial) if M else np.zeros((0, n_pts, 3), np.float32),
        "labels": np.stack(labels) if M else np.zeros((0, n_pts), np.int8),
        "shape_idx": np.asarray(shape_idx, np.int32),
        "view_idx": np.asarray(view_idx, np.int8),
        "camera": np.stack(cams) if M else np.zeros((0, 4, 4), np.float32),
        "n_hits": np.asarray(n_hits, np.int32),
        "type_id": np.full(S, type_id, np.int8),
        "shape_id": np.asarray(job.indices, np.int32),
        "n_parts": n_parts,
        "params": params,
        "poses": poses,
        "gt": gt,
        "test": test,
        "n_excluded": np.asarray(excluded),
    }


def _worker_init() -> None:
    torch.set_num_threads(1)


def _run_job(job: ShardJob) -> tuple[str, int, int]:
    path = job.path
    if path.exists():
        with np.load(path) as z:
            return str(path), int(len(z["shape_idx"])), int(z["n_excluded"])
    data = make_shard(job)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + f".tmp{os.getpid()}.npz")
    np.savez(tmp, **data)
    os.replace(tmp, path)
    return str(path), int(len(data["shape_idx"])), int(data["n_excluded"])


def generate(spec: GenerationSpec, workers: int = 1, progress: bool = True) -> dict:
    """Write every missing shard of ``spec`` (resumable, parallel); returns a summary dict."""
    from tqdm import tqdm

    out = Path(spec.out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = shard_jobs(spec)
    todo = [j for j in jobs if not j.path.exists()]
    t0 = time.time()
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), disable=not progress, unit="shard")
    if workers <= 1:
        _worker_init()
        for j in todo:
            _run_job(j)
            bar.update()
    else:
        ctx = mp.get_context("spawn")
        with ctx.Pool(workers, initializer=_worker_init) as pool:
            for _ in pool.imap_unordered(_run_job, todo):
                bar.update()
    bar.close()
    counts = {d: {"items": 0, "excluded": 0, "shards": 0} for d in spec.datasets}
    for j in jobs:
        with np.load(j.path) as z:
            c = counts[j.dataset]
            c["items"] += int(len(z["shape_idx"]))
            c["excluded"] += int(z["n_excluded"])
            c["shards"] += 1
    summary = {
        "spec": {k: v for k, v in dataclasses.asdict(spec).items() if k != "out"},
        "counts": counts,
        "seconds": round(time.time() - t0, 1),
        "generated_shards": len(todo),
    }
    (out / "manifest.json").write_text(json.dumps(summary, indent=2))
    return summary


# --- loading -----------------------------------------------------------------------------------


def load_dataset(root: str | Path, dataset: str) -> dict[str, np.ndarray]:
    """Concatenate every shard of ``dataset`` under ``root`` (shape indices made global)."""
    if dataset not in DATASETS:
        raise ValueError(f"Unknown dataset {dataset!r}. Available: {list(DATASETS)}")
    files = sorted((Path(root) / dataset).glob("*.npz"))
    files = [f for f in files if ".tmp" not in f.name]
    if not files:
        raise FileNotFoundError(f"no {dataset} shards under {Path(root) / dataset}")
    per_item = ("partial", "labels", "shape_idx", "view_idx", "camera", "n_hits")
    per_shape = ("type_id", "shape_id", "n_parts", "params", "poses", "gt", "test")
    acc: dict[str, list[np.ndarray]] = {k: [] for k in per_item + per_shape}
    offset = 0
    for f in files:
        with np.load(f) as z:
            for k in per_item + per_shape:
                acc[k].append(z[k] + offset if k == "shape_idx" else z[k])
            offset += len(z["type_id"])
    return {k: np.concatenate(v) for k, v in acc.items()}


def _split_items(data: dict[str, np.ndarray], split: str) -> np.ndarray:
    if split not in ("train", "test", "all"):
        raise ValueError(f"split must be 'train', 'test' or 'all', got {split!r}")
    if split == "all":
        return np.arange(len(data["shape_idx"]))
    is_test = data["test"][data["shape_idx"]]
    return np.nonzero(is_test if split == "test" else ~is_test)[0]


@dataclasses.dataclass
class SQBatch:
    """A batch for the superquadric networks, everything in the normalised frame except ``gt_*``.

    ``x (B, N, C)`` network input; ``gt (B, N_g, 3)`` ground-truth surface points and ``gt_z (B, 3)``
    the ground-truth z axis (normalised frame); ``frame`` undoes the normalisation;
    ``gt_params (B, 9)`` / ``gt_pose (B, 4, 4)`` the world-frame ground truth; ``type_id (B,)``.
    """

    x: torch.Tensor
    gt: torch.Tensor
    gt_z: torch.Tensor
    frame: NormalizedFrame
    gt_params: torch.Tensor
    gt_pose: torch.Tensor
    type_id: torch.Tensor

    def to(self, device) -> SQBatch:
        fr = NormalizedFrame(
            self.frame.center.to(device),
            self.frame.rotation.to(device),
            self.frame.scale.to(device),
        )
        return SQBatch(
            self.x.to(device),
            self.gt.to(device),
            self.gt_z.to(device),
            fr,
            self.gt_params.to(device),
            self.gt_pose.to(device),
            self.type_id.to(device),
        )


@dataclasses.dataclass
class SegBatch:
    x: torch.Tensor
    """``(B, N, 3)`` normalised object clouds."""
    labels: torch.Tensor
    """``(B, N)`` part labels (long)."""

    def to(self, device) -> SegBatch:
        return SegBatch(self.x.to(device), self.labels.to(device))


class _Base:
    """Items held in memory; :meth:`batch` gathers and normalises a list of indices."""

    normalizer = PCANormalizer()

    def __len__(self) -> int:
        return len(self.items)

    def _subsample(self, n_have: int, n: int, b: int, g: torch.Generator) -> torch.Tensor:
        if n >= n_have:
            return torch.arange(n_have).expand(b, n_have)
        return torch.rand(b, n_have, generator=g).argsort(-1)[:, :n]


class PrimitiveDataset(_Base):
    """DSQNet / SQNet training items: one segment per item (A.2: 300 points).

    From the primitive dataset every item is one primitive. From the object dataset
    (``dataset="object"``) every visible part of every view is an item, cut out by its label
    and resampled to ``n_points`` (as the pipeline feeds segments at inference).
    """

    def __init__(
        self,
        root: str | Path,
        split: str = "train",
        *,
        dataset: str = "primitive",
        n_points: int = 300,
        n_gt: int = 512,
        min_points: int = 10,
        seed: int = 0,
        data: dict[str, np.ndarray] | None = None,
    ) -> None:
        self.data = data if data is not None else load_dataset(root, dataset)
        self.n_points, self.n_gt = n_points, n_gt
        items = _split_items(self.data, split)
        if dataset == "primitive":
            self.items = np.stack([items, np.zeros_like(items)], -1)
            self.points = self.data["partial"]
        else:
            pairs, pts = [], []
            rng = np.random.default_rng(seed)
            for i in items:
                lab = self.data["labels"][i]
                for p in range(int(self.data["n_parts"][self.data["shape_idx"][i]])):
                    sel = self.data["partial"][i][lab == p]
                    if len(sel) >= min_points:
                        pts.append(resample_labelled(sel, np.zeros(len(sel)), n_points, rng)[0])
                        pairs.append((i, p))
            self.items = np.asarray(pairs, np.int64).reshape(-1, 2)
            self.points = np.asarray(pts, np.float32).reshape(-1, n_points, 3)
            self._own_points = True
        self.dataset = dataset

    def batch(self, idx: Sequence[int], g: torch.Generator | None = None) -> SQBatch:
        g = g if g is not None else torch.Generator().manual_seed(0)
        idx = np.asarray(idx)
        item, part = self.items[idx, 0], self.items[idx, 1]
        rows = item if self.dataset == "primitive" else idx
        pts = torch.as_tensor(self.points[rows], dtype=torch.float32)
        pick = self._subsample(pts.shape[1], self.n_points, len(idx), g)
        pts = torch.gather(pts, 1, pick.unsqueeze(-1).expand(-1, -1, 3))
        x, fr = self.normalizer(pts)
        return _sq_batch(self.data, item, part, x, fr, self.n_gt, g)


def _sq_batch(data, item, part, x, fr: NormalizedFrame, n_gt: int, g) -> SQBatch:
    s = data["shape_idx"][item]
    gt = torch.as_tensor(data["gt"][s, part], dtype=torch.float32)  # (B, N_gt, 3)
    pick = torch.rand(gt.shape[:2], generator=g).argsort(-1)[:, : min(n_gt, gt.shape[1])]
    gt = torch.gather(gt, 1, pick.unsqueeze(-1).expand(-1, -1, 3))
    pose = torch.as_tensor(data["poses"][s, part], dtype=torch.float32)
    return SQBatch(
        x=x,
        gt=fr.apply(gt),
        gt_z=fr.apply_vectors(pose[:, :3, 2]),
        frame=fr,
        gt_params=torch.as_tensor(data["params"][s, part], dtype=torch.float32),
        gt_pose=pose,
        type_id=torch.as_tensor(data["type_id"][s], dtype=torch.long),
    )


class ObjectPartDataset(_Base):
    """DSQNet+ items (3.6.2): the whole object cloud with a 0/1 channel marking one part."""

    def __init__(
        self,
        root: str | Path,
        split: str = "train",
        *,
        n_points: int = 1000,
        n_gt: int = 512,
        min_points: int = 10,
        data: dict[str, np.ndarray] | None = None,
    ) -> None:
        self.data = data if data is not None else load_dataset(root, "object")
        self.n_points, self.n_gt = n_points, n_gt
        pairs = []
        for i in _split_items(self.data, split):
            lab = self.data["labels"][i]
            for p in range(int(self.data["n_parts"][self.data["shape_idx"][i]])):
                if (lab == p).sum() >= min_points:
                    pairs.append((i, p))
        self.items = np.asarray(pairs, np.int64).reshape(-1, 2)

    def batch(self, idx: Sequence[int], g: torch.Generator | None = None) -> SQBatch:
        g = g if g is not None else torch.Generator().manual_seed(0)
        idx = np.asarray(idx)
        item, part = self.items[idx, 0], self.items[idx, 1]
        pts = torch.as_tensor(self.data["partial"][item], dtype=torch.float32)
        mask = torch.as_tensor(self.data["labels"][item].astype(np.int64) == part[:, None])
        # a random n_points subset with the segment/context ratio of the full cloud
        n_keep = self.n_points
        n_seg = mask.sum(1)
        ratio = (n_seg.float() / pts.shape[1] * n_keep).round().long().clamp(1, n_keep)
        seg_rank = torch.rand(pts.shape[:2], generator=g).masked_fill(~mask, 2.0).argsort(-1)
        ctx_rank = torch.rand(pts.shape[:2], generator=g).masked_fill(mask, 2.0).argsort(-1)
        cols = torch.arange(n_keep).expand(len(idx), -1)
        take_seg = cols < ratio[:, None]
        pick = torch.where(
            take_seg,
            torch.gather(seg_rank, 1, cols.clamp_max(pts.shape[1] - 1)),
            torch.gather(ctx_rank, 1, (cols - ratio[:, None]).clamp(0, pts.shape[1] - 1)),
        )
        pts = torch.gather(pts, 1, pick.unsqueeze(-1).expand(-1, -1, 3))
        m = torch.gather(mask, 1, pick)
        xn, fr = self.normalizer(pts, m)
        x = torch.cat([xn, m.unsqueeze(-1).float()], -1)
        return _sq_batch(self.data, item, part, x, fr, self.n_gt, g)


class SegmentationDataset(_Base):
    """Segmentation items (A.2): object clouds (normalised) with their part labels."""

    def __init__(
        self,
        root: str | Path,
        split: str = "train",
        *,
        n_points: int = 1000,
        data: dict[str, np.ndarray] | None = None,
    ) -> None:
        self.data = data if data is not None else load_dataset(root, "object")
        self.n_points = n_points
        self.items = _split_items(self.data, split)

    def batch(self, idx: Sequence[int], g: torch.Generator | None = None) -> SegBatch:
        g = g if g is not None else torch.Generator().manual_seed(0)
        item = self.items[np.asarray(idx)]
        pts = torch.as_tensor(self.data["partial"][item], dtype=torch.float32)
        lab = torch.as_tensor(self.data["labels"][item].astype(np.int64))
        pick = self._subsample(pts.shape[1], self.n_points, len(item), g)
        pts = torch.gather(pts, 1, pick.unsqueeze(-1).expand(-1, -1, 3))
        lab = torch.gather(lab, 1, pick)
        x, _ = self.normalizer(pts)
        return SegBatch(x, lab)


# --- CLI -------------------------------------------------------------------------------------------


def _run_cli(args: argparse.Namespace) -> int:
    spec = GenerationSpec(
        out=args.out,
        scale=args.scale,
        seed=args.seed,
        datasets=tuple(args.datasets),
        n_views=args.views,
        shapes=args.shapes,
    )
    summary = generate(spec, workers=args.workers)
    print(json.dumps(summary["counts"]), f"{summary['seconds']} s")
    return 0


def add_cli(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``recognition`` under a ``data`` command's sub-parsers (``sqmanip data recognition``)."""
    p = subparsers.add_parser(
        "recognition",
        help="generate the primitive and object datasets of Appendix A.1",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", required=True, help="output directory (resumes if it has shards)")
    p.add_argument("--scale", type=float, default=1.0,
                   help="fraction of A.1's 100 shapes per type (0.05 builds in a minute or two)")  # fmt: skip
    p.add_argument("--workers", type=int, default=max(1, (os.cpu_count() or 2) - 0))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--views", type=int, default=N_VIEWS, help="viewpoints per shape (A.1: 16)")
    p.add_argument("--shapes", type=int, default=None, help="shapes per type (overrides --scale)")
    p.add_argument("--datasets", nargs="+", default=list(DATASETS), choices=DATASETS)
    p.set_defaults(func=_run_cli)
    from .scenes import add_cli as add_scenes_cli  # C.1 scenes: ``sqmanip data scenes``

    add_scenes_cli(subparsers)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sqmanip.perception.learned.datasets")
    sub = parser.add_subparsers(dest="command", required=True)
    add_cli(sub)
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
