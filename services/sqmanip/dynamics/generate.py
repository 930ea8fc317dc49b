"""Pushing dataset generation in the simulator (Ch. 4.5, 4.6.2).

``sqmanip data pushing --out DIR [--scale S] [--workers W] [--ray-address ADDR]`` writes
``DIR/{train,val,test,unknown}/`` in the shard format of :mod:`.data`:

- objects: a catalogue of 18 boxes and 18 cylinders with seeded random sizes, 9/9 of each class
  known/unknown (:func:`make_catalogue`); train/val/test scenes use known objects, ``unknown``
  unknown ones (4.5, Fig. 4.5);
- a sequence places 1-4 objects (``unknown``: 300 tuples per object count at full size) upright
  at random non-overlapping poses and yaws in the 0.512 x 0.512 m workspace, then executes up
  to 20 pushes of the 4.5 sampler (:func:`.sampler.sample_push_actions`) with the simulated
  Panda; it stops (dropping that last tuple) as soon as an object tips over (tilt > 15 deg) or
  leaves the workspace (4.6.2). Pushes the robot cannot reach are redrawn (up to 10 times);
- each tuple holds ground-truth poses and shapes before and after the push, the action, the
  catalogue ids, and the observed wrist-camera cloud before the push (object points only,
  subsampled to ``cloud_points``; labels = object index).

Full size is 12000 / 1200 / 1200 + 1200 unknown tuples (4.6.2); ``--scale`` multiplies every
count (``--scale 0.01``: 156 tuples, a few minutes on 2 cores).

Determinism, sharding, resume: each split is cut into shards of ``shard_size`` tuples; shard
``j`` draws its sequences from ``numpy.random.default_rng([seed, split, j, sequence])`` and the
simulator is reset for each sequence (its physics, IK restarts and sensor noise are seeded by
the scene), so a shard's content depends only on ``(seed, split, j)``, not on the worker that
built it or on the worker count. Finished shards are skipped on a re-run; the manifest is
rebuilt at the end. Parallel over processes (``--workers``) or Ray tasks (``--ray-address``).

Cost: with the arm teleported between pushes (``push_transit``, the default here) a push is
the simulated descent, the 10-via-point push and the lift, ~0.2-0.3 s wall on one core
(~0.7 s when the arm drives home and back); the half-resolution observation adds ~0.25 s. The
full set (train without clouds: ``--splits train --no-cloud``, then ``--splits val test
unknown`` with them) took 39 + 24 minutes on 2 worker processes of a 2-core machine that was
also training and benchmarking, about 1.5 core-hours (it was 4-5 with the arm driven and every
tuple observed).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from .data import existing_shards, finalize_split, write_shard
from .sampler import sample_push_actions

__all__ = [
    "SPLITS",
    "CatalogueObject",
    "GenerationConfig",
    "ShardTask",
    "add_cli",
    "generate_dataset",
    "generate_shard",
    "make_catalogue",
    "plan_shards",
    "run_sequence",
]

log = logging.getLogger(__name__)

SPLITS: dict[str, int] = {"train": 12000, "val": 1200, "test": 1200, "unknown": 1200}
"""Full-size tuple counts (4.6.2); ``unknown`` is 300 per object count 1..4."""
_SPLIT_IDS = {"train": 0, "val": 1, "test": 2, "unknown": 3}


# --- objects --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class CatalogueObject:
    """One object of the 36-object catalogue (Fig. 4.5)."""

    id: int
    kind: str
    """``box`` or ``cylinder``."""
    size: tuple[float, float, float]
    """Full extents x, y, z (m); a cylinder's are ``(2r, 2r, height)``."""
    known: bool

    def spec(self, x: float, y: float, yaw: float, color: tuple[float, ...]) -> Any:
        """The simulator ``ObjectSpec`` standing upright at ``(x, y)`` with heading ``yaw``."""
        from sqmanip.sim import ObjectSpec

        q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
        pos = (x, y, self.size[2] / 2 + 1e-4)
        name = f"{self.kind}_{self.id}"
        if self.kind == "box":
            return ObjectSpec("box", position=pos, orientation=q, size=self.size, color=color,
                              name=name)  # fmt: skip
        return ObjectSpec("cylinder", position=pos, orientation=q, radius=self.size[0] / 2,
                          height=self.size[2], color=color, name=name)  # fmt: skip

    @property
    def footprint_radius(self) -> float:
        """Radius of the smallest disc holding the footprint (m)."""
        if self.kind == "box":
            return 0.5 * math.hypot(self.size[0], self.size[1])
        return self.size[0] / 2


def make_catalogue(
    seed: int = 0,
    per_class: int = 18,
    *,
    box_sides: tuple[float, float] = (0.04, 0.09),
    box_heights: tuple[float, float] = (0.04, 0.12),
    cyl_radii: tuple[float, float] = (0.02, 0.045),
    cyl_heights: tuple[float, float] = (0.04, 0.12),
    large_boxes: int = 0,
    large_box_sides: tuple[tuple[float, float], tuple[float, float]] = ((0.08, 0.16), (0.12, 0.36)),
    large_box_heights: tuple[float, float] = (0.025, 0.07),
) -> list[CatalogueObject]:
    """``per_class`` boxes then ``per_class`` cylinders with seeded random sizes (4.5); the first
    half of each class is known, the second half unknown. Then ``large_boxes`` known boxes of the
    MPC scenes' YCB sizes (:mod:`sqmanip.planning.scenarios`: the 17.5 cm sugar box, the 34 cm
    "grasping large" box, boxes 2.5-3.5 cm flat), which the 4-9 cm boxes leave outside SQPD-Net's
    data; sides from ``large_box_sides``. They are drawn last, so the other sizes and ids do not
    depend on them. Ids are list indices."""
    if per_class < 2:
        raise ValueError(f"per_class must be >= 2, got {per_class}")
    rng = np.random.default_rng([seed, 4_5])
    out: list[CatalogueObject] = []
    for k in range(per_class):
        sx, sy = rng.uniform(*box_sides, size=2)
        sz = rng.uniform(*box_heights)
        out.append(CatalogueObject(len(out), "box", (float(sx), float(sy), float(sz)),
                                   k < per_class // 2))  # fmt: skip
    for k in range(per_class):
        r = float(rng.uniform(*cyl_radii))
        h = float(rng.uniform(*cyl_heights))
        out.append(CatalogueObject(len(out), "cylinder", (2 * r, 2 * r, h), k < per_class // 2))
    for _ in range(large_boxes):
        sx, sy = (float(rng.uniform(*side)) for side in large_box_sides)
        sz = float(rng.uniform(*large_box_heights))
        out.append(CatalogueObject(len(out), "box", (sx, sy, sz), True))
    return out


# --- configuration and planning -------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class GenerationConfig:
    """Settings of a generation run (stored in each split's manifest ``meta``)."""

    seed: int = 0
    scale: float = 1.0
    shard_size: int = 100
    max_objects: int = 4
    max_pushes: int = 20
    """Pushes per sequence (4.6.2)."""
    push_length: float = 0.10
    fall_tilt_deg: float = 15.0
    """An object whose z axis tilts more than this from vertical has fallen."""
    placement_margin: float = 0.06
    """Objects are placed this far inside the workspace edges (m)."""
    object_gap: float = 0.01
    cloud_points: int = 1024
    """Observed object points kept per tuple (0: no cloud)."""
    camera_width: int = 320
    camera_height: int = 288
    """Half the default wrist camera's resolution (same field of view)."""
    push_retries: int = 10
    catalogue_seed: int = 0
    large_boxes: int = 0
    """Known YCB-sized boxes added to the catalogue (:func:`make_catalogue`); 0 keeps the
    36-object catalogue."""
    push_transit: str = "teleport"
    """``SimConfig.push_transit`` of the generating simulator: ``teleport`` skips the arm's
    free-space moves home and back (same resting poses, about 1.5x faster per tuple)."""

    def __post_init__(self) -> None:
        if not self.scale > 0:
            raise ValueError(f"scale must be positive, got {self.scale}")
        if self.shard_size < 1:
            raise ValueError(f"shard_size must be >= 1, got {self.shard_size}")
        if not 1 <= self.max_objects <= 4:
            raise ValueError(f"max_objects must be in 1..4, got {self.max_objects}")
        if self.large_boxes < 0:
            raise ValueError(f"large_boxes must be >= 0, got {self.large_boxes}")
        if self.max_pushes < 1:
            raise ValueError(f"max_pushes must be >= 1, got {self.max_pushes}")
        if self.cloud_points < 0:
            raise ValueError(f"cloud_points must be >= 0, got {self.cloud_points}")

    def intrinsics(self) -> Any:
        from sqmanip.sim import Intrinsics

        f = 504.0 * self.camera_width / 640
        return Intrinsics(self.camera_width, self.camera_height, f, f,
                          (self.camera_width - 1) / 2, (self.camera_height - 1) / 2)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class ShardTask:
    """One shard to build: ``count`` tuples of ``split`` into ``root/shard-{index}.npz``."""

    root: str
    split: str
    index: int
    count: int
    n_objects: int | None
    """Fixed object count (``unknown`` split), or None for uniform 1..max_objects."""


def plan_shards(
    out: str | Path, split: str, total: int, config: GenerationConfig
) -> list[ShardTask]:
    """Cut ``total`` tuples of ``split`` into shard tasks (``unknown``: equal groups per object
    count, each group in its own shards)."""
    if split not in _SPLIT_IDS:
        raise ValueError(f"split must be one of {sorted(_SPLIT_IDS)}, got {split!r}")
    root = str(Path(out) / split)
    groups: list[tuple[int | None, int]]
    if split == "unknown":
        m = config.max_objects
        groups = [(k, total // m + (1 if k <= total % m else 0)) for k in range(1, m + 1)]
    else:
        groups = [(None, total)]
    tasks: list[ShardTask] = []
    for n_obj, count in groups:
        for start in range(0, count, config.shard_size):
            size = min(config.shard_size, count - start)
            tasks.append(ShardTask(root, split, len(tasks), size, n_obj))
    return tasks


# --- one sequence ---------------------------------------------------------------------------------


def _place(
    catalogue: Sequence[CatalogueObject], n: int, bounds: np.ndarray, rng: np.random.Generator,
    config: GenerationConfig,
) -> list[tuple[CatalogueObject, float, float, float]]:  # fmt: skip
    """``n`` objects at random non-overlapping upright poses (rejection sampling)."""
    lo = bounds[0, :2] + config.placement_margin
    hi = bounds[1, :2] - config.placement_margin
    for _ in range(100):
        chosen = [catalogue[int(i)] for i in rng.integers(len(catalogue), size=n)]
        placed: list[tuple[CatalogueObject, float, float, float]] = []
        for obj in chosen:
            for _try in range(50):
                x, y = rng.uniform(lo, hi)
                r = obj.footprint_radius
                if all(
                    math.hypot(x - px, y - py) > r + o.footprint_radius + config.object_gap
                    for o, px, py, _ in placed
                ):
                    placed.append((obj, float(x), float(y), float(rng.uniform(-math.pi, math.pi))))
                    break
        if len(placed) == n:
            return placed
    raise RuntimeError(f"could not place {n} objects without overlap in 100 attempts")


def _stopped(state: Any, bounds: np.ndarray, config: GenerationConfig) -> bool:
    """Whether an object fell (tilt) or left the workspace (4.6.2)."""
    cos_tilt = math.cos(math.radians(config.fall_tilt_deg))
    for o in state.objects:
        T = o.pose
        if T[2, 2] < cos_tilt:
            return True
        if np.any(T[:2, 3] < bounds[0, :2]) or np.any(T[:2, 3] > bounds[1, :2]):
            return True
        if T[2, 3] < bounds[0, 2] - 0.01:
            return True
    return False


def _arrays(state: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    sqs = [o.superquadric for o in state.objects]
    poses = np.stack([o.pose for o in state.objects])
    params = np.stack([s.params() for s in sqs])
    kinds = np.array([s.kind_index for s in sqs])
    return poses, params, kinds


def _cloud(sim: Any, config: GenerationConfig, rng: np.random.Generator):
    obs = sim.observe(intrinsics=config.intrinsics())
    keep = np.nonzero(obs.point_labels >= 0)[0]
    if keep.size > config.cloud_points:
        keep = np.sort(rng.choice(keep, size=config.cloud_points, replace=False))
    return obs.points[keep].astype(np.float32), obs.point_labels[keep].astype(np.int64), obs


def run_sequence(
    sim: Any,
    catalogue: Sequence[CatalogueObject],
    rng: np.random.Generator,
    config: GenerationConfig,
    *,
    n_objects: int | None = None,
    max_tuples: int | None = None,
    sequence: int = -1,
) -> list[Any]:
    """One pushing sequence in ``sim`` (a ``sqmanip.sim.Simulator``): tuples ``(s, a, s')``."""
    from sqmanip.errors import PreconditionError, ValidationError
    from sqmanip.sim import SceneSpec, workspace_bounds

    from .data import PushTuple

    bounds = workspace_bounds()
    n = int(rng.integers(1, config.max_objects + 1)) if n_objects is None else n_objects
    placed = _place(catalogue, n, bounds, rng, config)
    specs = tuple(
        obj.spec(x, y, yaw, tuple(float(c) for c in rng.uniform(0.2, 0.95, 3)) + (1.0,))
        for obj, x, y, yaw in placed
    )
    ids = np.array([obj.id for obj, *_ in placed])
    state = sim.reset(SceneSpec("tabletop", specs, int(rng.integers(2**31))))
    limit = config.max_pushes if max_tuples is None else min(config.max_pushes, max_tuples)
    out: list[PushTuple] = []
    for step in range(limit):
        poses, params, kinds = _arrays(state)
        cloud = labels = None
        if config.cloud_points:
            cloud, labels, _ = _cloud(sim, config, rng)
        result = None
        for _ in range(config.push_retries):
            act = sample_push_actions((poses, params), bounds, rng, n=1,
                                      push_length=config.push_length)  # fmt: skip
            if act.shape[0] == 0:
                break
            try:
                result = sim.push(act[0, :3], act[0, 3:])
                break
            except (PreconditionError, ValidationError):
                continue
        if result is None:
            break
        after = result.after
        if _stopped(after, bounds, config):
            break
        out.append(
            PushTuple(
                poses=poses,
                params=params,
                kinds=kinds,
                action_p=act[0, :3],
                action_v=act[0, 3:],
                next_poses=np.stack([o.pose for o in after.objects]),
                object_ids=ids,
                cloud=cloud,
                cloud_labels=labels,
                sequence=sequence,
                step=step,
            )
        )
        state = after
    return out


# --- shards ---------------------------------------------------------------------------------------

_SIM: Any = None


def _simulator(config: GenerationConfig) -> Any:
    """One simulator per process, created on first use (PyBullet DIRECT client)."""
    global _SIM
    if _SIM is None:
        from sqmanip.sim import SimConfig, Simulator

        _SIM = Simulator(SimConfig(push_transit=config.push_transit))
    return _SIM


def generate_shard(task: ShardTask, config: GenerationConfig) -> dict[str, Any]:
    """Build one shard (skipped if it exists); returns ``{"index", "count", "seconds"}``."""
    from .data import shard_path

    path = shard_path(task.root, task.index)
    if path.is_file():
        return {"index": task.index, "count": task.count, "seconds": 0.0, "skipped": True}
    t0 = time.perf_counter()
    catalogue = [o for o in make_catalogue(config.catalogue_seed, large_boxes=config.large_boxes)
                 if o.known == (task.split != "unknown")]  # fmt: skip
    sim = _simulator(config)
    tuples: list[Any] = []
    seq = 0
    while len(tuples) < task.count:
        rng = np.random.default_rng([config.seed, _SPLIT_IDS[task.split], task.index, seq])
        tuples += run_sequence(
            sim, catalogue, rng, config, n_objects=task.n_objects,
            max_tuples=task.count - len(tuples), sequence=task.index * 100_000 + seq,
        )  # fmt: skip
        seq += 1
        if seq > 50 * task.count + 100:
            raise RuntimeError(f"shard {task.index} of {task.split}: too many empty sequences")
    write_shard(task.root, task.index, tuples, config.max_objects)
    return {"index": task.index, "count": len(tuples), "seconds": time.perf_counter() - t0,
            "skipped": False}  # fmt: skip


def _camera_meta(config: GenerationConfig) -> dict[str, Any]:
    """The wrist camera at the home pose (the robot returns home after every push), for the 2D
    mask IoU of :mod:`.evaluate` (``meta.camera``)."""
    sim = _simulator(config)
    k = config.intrinsics()
    pose = sim.camera_pose("wrist")
    return {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width,
            "height": k.height, "pose": np.asarray(pose).tolist()}  # fmt: skip


def _run_local(tasks: list[ShardTask], config: GenerationConfig, workers: int) -> Iterator[dict]:
    if workers <= 1:
        for t in tasks:
            yield generate_shard(t, config)
        return
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
        yield from pool.map(generate_shard, tasks, [config] * len(tasks))


def _run_ray(tasks: list[ShardTask], config: GenerationConfig, address: str) -> Iterator[dict]:
    try:
        import ray  # noqa: PLC0415
    except ImportError as exc:
        raise RuntimeError(
            "--ray-address needs the 'ray' package (pip install 'ray[default]'); "
            "without it use --workers for local processes"
        ) from exc
    if not ray.is_initialized():
        ray.init(address=address)
    remote = ray.remote(num_cpus=1)(generate_shard)
    pending = [remote.remote(t, config) for t in tasks]
    while pending:
        done, pending = ray.wait(pending, num_returns=1)
        yield ray.get(done[0])


def generate_dataset(
    out: str | Path,
    config: GenerationConfig | None = None,
    *,
    splits: Sequence[str] | None = None,
    counts: dict[str, int] | None = None,
    workers: int = 1,
    ray_address: str | None = None,
    progress: bool = True,
) -> dict[str, dict[str, Any]]:
    """Generate (or resume) the splits under ``out``; returns each split's manifest.

    ``counts`` overrides the tuple counts (default :data:`SPLITS` times ``config.scale``).
    """
    from tqdm import tqdm

    config = config or GenerationConfig()
    splits = list(splits or SPLITS)
    tasks: list[ShardTask] = []
    for split in splits:
        total = (
            counts[split]
            if counts and split in counts
            else max(1, round(SPLITS[split] * config.scale))
        )
        tasks += plan_shards(out, split, total, config)
    todo = [t for t in tasks if t.index not in existing_shards(t.root)]
    log.info("%d shards planned, %d to build", len(tasks), len(todo))
    runner = (
        _run_ray(todo, config, ray_address) if ray_address else _run_local(todo, config, workers)
    )
    n_tuples = 0
    with tqdm(total=len(todo), desc="pushing data", unit="shard", disable=not progress) as bar:
        for res in runner:
            n_tuples += res["count"]
            bar.update(1)
            bar.set_postfix(tuples=n_tuples)
    meta = {
        "generator": "sqmanip.dynamics.generate",
        "config": dataclasses.asdict(config),
        "camera": _camera_meta(config) if config.cloud_points else None,
    }
    manifests = {}
    for split in splits:
        root = Path(out) / split
        root.mkdir(parents=True, exist_ok=True)
        manifests[split] = finalize_split(root, config.max_objects, {**meta, "split": split})
    return manifests


# --- command line ---------------------------------------------------------------------------------


def _run_cli(args: argparse.Namespace) -> int:
    config = GenerationConfig(
        seed=args.seed, scale=args.scale, shard_size=args.shard_size,
        cloud_points=0 if args.no_cloud else args.cloud_points, push_transit=args.push_transit,
        large_boxes=args.large_boxes,
    )  # fmt: skip
    manifests = generate_dataset(
        args.out, config, splits=args.splits, workers=args.workers, ray_address=args.ray_address
    )
    for split, m in manifests.items():
        print(f"{split:>8s}: {m['count']} tuples in {len(m['shards'])} shards")
    return 0


def add_cli(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``pushing`` under a ``data`` command's sub-parsers (``sqmanip data pushing``)."""
    p = subparsers.add_parser(
        "pushing",
        help="generate the pushing dataset (Ch. 4.5) in the simulator",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", required=True, help="output directory (one sub-directory per split)")
    p.add_argument("--scale", type=float, default=1.0,
                   help="multiply the 12000/1200/1200/1200 tuple counts (0.01: minutes)")  # fmt: skip
    p.add_argument("--workers", type=int, default=1, help="local worker processes")
    p.add_argument("--ray-address", help="run shards as Ray tasks on this cluster (needs ray)")
    p.add_argument("--splits", nargs="+", choices=list(SPLITS), help="only these splits")
    p.add_argument("--shard-size", type=int, default=100, help="tuples per shard")
    p.add_argument("--cloud-points", type=int, default=1024, help="observed points per tuple")
    p.add_argument("--no-cloud", action="store_true", help="skip the camera (faster)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--large-boxes", type=int, default=0, metavar="N",
                   help="add N known boxes of 8-16 x 12-36 x 2.5-7 cm (the MPC scenes' YCB "
                        "sizes, the 34 cm 'grasping large' box among them) to the catalogue")  # fmt: skip
    p.add_argument("--push-transit", choices=("teleport", "move"), default="teleport",
                   help="teleport the arm between pushes (default, faster) or drive it; the "
                        "pushes themselves are simulated alike")  # fmt: skip
    p.set_defaults(func=_run_cli)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sqmanip.dynamics.generate")
    sub = parser.add_subparsers(dest="dataset", required=True)
    add_cli(sub)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
