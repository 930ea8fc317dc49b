"""Multi-object scene dataset for the segmentation network (Appendix C.1), from the simulator.

C.1: ``N`` = 2..8 random boxes and cylinders are placed on the shelf (random position and yaw,
settled by physics); the shelf camera's depth image is back-projected with the A.1 noise
(``x + m v``, ``m ~ N(0, 1 mm)``, done by :meth:`sqmanip.sim.Simulator.observe`); the shelf,
robot and background points are removed and the rest is up/down-sampled to 2048 points with its
instance labels; every object gets 512 ground-truth surface points. The thesis collects
5000 / 100 train / validation tuples per ``N`` (35000 / 700 in all); ``--per-n`` scales that.

Layout: ``OUT/scene/N{n}_{block:04d}.npz`` shards of ``scenes_per_shard`` scenes, written
atomically, so an interrupted run resumes by skipping finished shards. Scene ``i`` of ``N``
objects is simulated from its own seed ``(seed, n, i)``: the same index gives the same scene at
any ``--per-n``. The last ``val_fraction`` of each ``N``'s scene indices are the validation split.

Arrays per shard (``S`` scenes): ``points (S, 2048, 3)`` float32; ``labels (S, 2048)`` int8,
the object's index in the scene (-1 everywhere when no object is visible); ``n_objects (S,)``;
``params (S, 8, 9)`` and ``poses (S, 8, 4, 4)``, world-frame superquadrics, zero-padded;
``gt (S, 8, 512, 3)``; ``visible (S, 8)`` bool; ``camera (S, 4, 4)``; ``scene_idx (S,)``;
``val (S,)`` bool; ``n_requested (S,)``; ``layout``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing as mp
import os
import time
from pathlib import Path

import numpy as np
import torch

from sqmanip.geometry.sampling import sample_surface

from .datasets import resample_labelled

__all__ = ["SceneGenSpec", "add_cli", "generate_scenes", "load_scenes", "make_scene_shard"]

MAX_OBJECTS = 8
N_POINTS = 2048
N_GT = 512


@dataclasses.dataclass(frozen=True)
class SceneGenSpec:
    """What to generate: ``per_n`` scenes for each object count in ``[n_min, n_max]``."""

    out: str
    per_n: int = 100
    n_min: int = 2
    n_max: int = 8
    layout: str = "shelf"
    seed: int = 0
    n_points: int = N_POINTS
    n_gt: int = N_GT
    val_fraction: float = 100 / 5100
    """C.1: 100 validation scenes per 5000 training scenes."""
    scenes_per_shard: int = 10

    def __post_init__(self) -> None:
        if not 1 <= self.n_min <= self.n_max <= MAX_OBJECTS:
            raise ValueError(
                f"need 1 <= n_min <= n_max <= {MAX_OBJECTS}, got n_min={self.n_min}, "
                f"n_max={self.n_max}"
            )
        if self.per_n < 1 or self.scenes_per_shard < 1:
            raise ValueError(
                f"per_n and scenes_per_shard must be >= 1, got {self.per_n} and "
                f"{self.scenes_per_shard}"
            )
        if self.layout not in ("shelf", "tabletop"):
            raise ValueError(f"layout must be 'shelf' or 'tabletop', got {self.layout!r}")
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in [0, 1), got {self.val_fraction}")


@dataclasses.dataclass(frozen=True)
class _Job:
    spec: SceneGenSpec
    n: int
    block: int
    indices: tuple[int, ...]

    @property
    def path(self) -> Path:
        return Path(self.spec.out) / "scene" / f"N{self.n}_{self.block:04d}.npz"


def _jobs(spec: SceneGenSpec) -> list[_Job]:
    out = []
    for n in range(spec.n_min, spec.n_max + 1):
        idx = list(range(spec.per_n))
        for b in range(0, len(idx), spec.scenes_per_shard):
            out.append(_Job(spec, n, b // spec.scenes_per_shard,
                            tuple(idx[b : b + spec.scenes_per_shard])))  # fmt: skip
    return out


def _n_val(spec: SceneGenSpec) -> int:
    return int(round(spec.val_fraction * spec.per_n)) if spec.per_n >= 2 else 0


def make_scene_shard(job: _Job, sim=None) -> dict[str, np.ndarray]:
    """Simulate and observe the scenes of one shard (deterministic in the spec's seed)."""
    from sqmanip.sim import Simulator

    spec = job.spec
    own = sim is None
    sim = sim or Simulator()
    camera = "shelf" if spec.layout == "shelf" else "overview"
    S, M = len(job.indices), MAX_OBJECTS
    out = {
        "points": np.zeros((S, spec.n_points, 3), np.float32),
        "labels": np.full((S, spec.n_points), -1, np.int8),
        "n_objects": np.zeros(S, np.int8),
        "params": np.zeros((S, M, 9), np.float32),
        "poses": np.tile(np.eye(4, dtype=np.float32), (S, M, 1, 1)),
        "gt": np.zeros((S, M, spec.n_gt, 3), np.float32),
        "visible": np.zeros((S, M), bool),
        "camera": np.zeros((S, 4, 4), np.float32),
        "scene_idx": np.asarray(job.indices, np.int32),
        "val": np.asarray([i >= spec.per_n - _n_val(spec) for i in job.indices]),
        "n_requested": np.full(S, job.n, np.int8),
    }
    try:
        for s, index in enumerate(job.indices):
            seed = int(np.random.SeedSequence([spec.seed, job.n, index]).generate_state(1)[0])
            sim.reset(seed=seed, n_objects=job.n, kind=spec.layout)
            obs = sim.observe(camera)
            keep = obs.point_labels >= 0
            pts, lab = obs.points[keep], obs.point_labels[keep].astype(np.int64)
            rng = np.random.default_rng(seed)
            if len(pts):
                pts, lab = resample_labelled(pts, lab, spec.n_points, rng)
                out["points"][s] = pts
                out["labels"][s] = lab
            g = torch.Generator().manual_seed(seed)
            objs = [o for o in obs.objects if o.superquadric is not None][:M]
            out["n_objects"][s] = len(objs)
            for j, o in enumerate(objs):
                sq = o.superquadric
                out["params"][s, j] = sq.params()
                out["poses"][s, j] = sq.pose
                local, _ = sample_surface(torch.as_tensor(sq.params()), spec.n_gt, generator=g)
                out["gt"][s, j] = local.numpy() @ sq.pose[:3, :3].T + sq.pose[:3, 3]
                out["visible"][s, j] = bool((out["labels"][s] == o.id).any())
            out["camera"][s] = obs.camera_pose
    finally:
        if own:
            sim.close()
    return out


def _run(job: _Job) -> str:
    path = job.path
    if path.exists():
        return str(path)
    torch.set_num_threads(1)
    data = make_scene_shard(job)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + f".tmp{os.getpid()}.npz")
    np.savez(tmp, layout=np.asarray(job.spec.layout), **data)
    os.replace(tmp, path)
    return str(path)


def generate_scenes(spec: SceneGenSpec, workers: int = 1, progress: bool = True) -> dict:
    """Write every missing shard of ``spec`` (resumable, parallel); returns a summary dict."""
    from tqdm import tqdm

    out = Path(spec.out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = _jobs(spec)
    todo = [j for j in jobs if not j.path.exists()]
    t0 = time.time()
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), disable=not progress, unit="shard")
    if workers <= 1:
        for j in todo:
            _run(j)
            bar.update()
    else:
        with mp.get_context("spawn").Pool(workers) as pool:
            for _ in pool.imap_unordered(_run, todo):
                bar.update()
    bar.close()
    data = load_scenes(out)
    summary = {
        "spec": {k: v for k, v in dataclasses.asdict(spec).items() if k != "out"},
        "scenes": int(len(data["n_objects"])),
        "val": int(data["val"].sum()),
        "seconds": round(time.time() - t0, 1),
        "generated_shards": len(todo),
    }
    (out / "scene_manifest.json").write_text(json.dumps(summary, indent=2))
    return summary


def load_scenes(root: str | Path) -> dict[str, np.ndarray]:
    """Concatenate every shard under ``root/scene`` (sorted by file name)."""
    files = sorted((Path(root) / "scene").glob("N*_*.npz"))
    files = [f for f in files if ".tmp" not in f.name]
    if not files:
        raise FileNotFoundError(f"no scene shards under {Path(root) / 'scene'}")
    parts: dict[str, list[np.ndarray]] = {}
    for f in files:
        with np.load(f) as z:
            for k in z.files:
                if k != "layout":
                    parts.setdefault(k, []).append(z[k])
    return {k: np.concatenate(v) for k, v in parts.items()}


def _run_cli(args: argparse.Namespace) -> int:
    spec = SceneGenSpec(out=args.out, per_n=args.per_n, n_min=args.n_min, n_max=args.n_max,
                        layout=args.layout, seed=args.seed)  # fmt: skip
    summary = generate_scenes(spec, workers=args.workers)
    print(json.dumps({k: summary[k] for k in ("scenes", "val", "seconds")}))
    return 0


def add_cli(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``scenes`` under a ``data`` command (``sqmanip data scenes``)."""
    p = subparsers.add_parser(
        "scenes",
        help="generate the multi-object shelf/tabletop scenes of Appendix C.1 (simulator)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", required=True, help="output directory (resumes if it has shards)")
    p.add_argument("--per-n", type=int, default=100,
                   help="scenes per object count (C.1: 5100)")  # fmt: skip
    p.add_argument("--n-min", type=int, default=2)
    p.add_argument("--n-max", type=int, default=8)
    p.add_argument("--layout", choices=["shelf", "tabletop"], default="shelf")
    p.add_argument("--workers", type=int, default=max(1, os.cpu_count() or 1))
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_run_cli)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sqmanip.perception.learned.scenes")
    sub = parser.add_subparsers(dest="command", required=True)
    add_cli(sub)
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
