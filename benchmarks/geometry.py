"""Geometry throughput on this CPU: implicit evaluation, sampling, line intersection, IoU, depth rendering.

Run: ``python -m benchmarks.geometry [--quick]``. Writes ``benchmarks/results/geometry.json``.
The thesis reports 0.013 s for the existence check of Appendix C.2 (18,564 rays, 7 samples per ray,
4 objects, plus 512-point collision check) on an RTX 3090; our number is CPU-only, rendering alone.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch
from sqmanip.geometry import Superquadric
from sqmanip.geometry.iou import volume_iou_estimate
from sqmanip.geometry.mesh import superquadric_trimesh
from sqmanip.geometry.raycast import line_intersections
from sqmanip.geometry.render import PinholeCamera, render_depth
from sqmanip.geometry.sampling import sample_surface
from sqmanip.geometry.superquadric import implicit
from sqmanip.settings import get_settings

RESULTS = Path(__file__).parent / "results" / "geometry.json"
PLAIN = [0.05, 0.04, 0.08, 0.5, 0.8, 0.0, 0.0, 0.0, 0.0]
DEFORMED = [0.05, 0.04, 0.08, 0.5, 0.8, 0.3, 2.0, 0.4, 0.0]


def timeit(fn, reps: int) -> float:
    """Median wall time of ``reps`` calls after one warm-up."""
    fn()
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def scene(batch: int | None = None, seed: int = 0):
    """Four objects on a 0.6 x 0.4 m patch 0.7 m in front of the camera (C.2's shelf scale)."""
    g = torch.Generator().manual_seed(seed)
    shape = (4,) if batch is None else (batch, 4)
    params = torch.tensor(DEFORMED).repeat(*shape, 1)
    params[..., :3] = 0.03 + 0.05 * torch.rand(*shape, 3, generator=g)
    poses = torch.eye(4).repeat(*shape, 1, 1)
    poses[..., 0, 3] = torch.rand(shape, generator=g) * 0.6 - 0.3
    poses[..., 1, 3] = torch.rand(shape, generator=g) * 0.4 - 0.2
    return params, poses


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions, smaller batches")
    args = ap.parse_args(argv)
    threads = get_settings().torch_threads
    torch.set_num_threads(threads)
    reps = 1 if args.quick else 5
    print(
        f"command: {' '.join([sys.executable, '-m', 'benchmarks.geometry', *(argv or sys.argv[1:])])}"
    )
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"torch {torch.__version__}, torch threads {torch.get_num_threads()}"
    )
    rows: list[dict] = []

    def add(name, value, unit, thesis=None, note=""):
        rows.append({"name": name, "value": value, "unit": unit, "thesis": thesis, "note": note})
        print(f"  {name:<52} {value:>12.4g} {unit:<10} {thesis or '':<22} {note}", flush=True)

    print(f"  {'measure':<52} {'ours':>12} {'unit':<10} {'thesis':<22} note")
    g = torch.Generator().manual_seed(0)
    n_pts = 200_000 if args.quick else 1_000_000
    x = torch.randn(n_pts, 3, generator=g) * 0.1
    for label, p in (("plain", PLAIN), ("deformed", DEFORMED)):
        for dtype in (torch.float32, torch.float64):
            pt = torch.tensor(p, dtype=dtype)
            xd = x.to(dtype)
            t = timeit(lambda pt=pt, xd=xd: implicit(xd, pt), reps)
            add(f"implicit {label} {str(dtype)[6:]} ({n_pts} pts)", n_pts / t, "points/s")

    batch = 4 if args.quick else 16
    params = torch.tensor(DEFORMED).repeat(batch, 1)
    t = timeit(lambda: sample_surface(params, 512, generator=0), reps)
    add(f"sample_surface fps, {batch} shapes x 512 pts", batch / t, "shapes/s", note=f"{t:.3f} s")
    t = timeit(lambda: sample_surface(params, 512, generator=0, method="area"), reps)
    add(f"sample_surface area, {batch} shapes x 512 pts", batch / t, "shapes/s", note=f"{t:.3f} s")

    n_lines = 5_000 if args.quick else 20_000
    o = torch.randn(n_lines, 3, generator=g) * 0.05
    d = torch.randn(n_lines, 3, generator=g)
    for label, p in (("plain", PLAIN), ("deformed", DEFORMED)):
        pt = torch.tensor(p)
        t = timeit(lambda pt=pt: line_intersections(o, d, pt), reps)
        add(f"line intersections {label} f32 ({n_lines} lines)", n_lines / t, "lines/s")

    a = [Superquadric((0.05, 0.04, 0.08), (0.5, 0.8), taper=0.3, bend=2.0)]
    pose = np.eye(4)
    pose[0, 3] = 0.03
    b = [a[0].with_pose(pose)]
    mesh = superquadric_trimesh(b[0], 32)
    t = timeit(lambda: volume_iou_estimate(a, b, n=50_000), reps)
    add("IoU superquadric vs superquadric (50k pts)", t, "s/pair")
    t = timeit(lambda: volume_iou_estimate(a, mesh, n=50_000), reps)
    add(f"IoU superquadric vs mesh ({len(mesh.faces)} faces, 50k pts)", t, "s/pair")

    look = PinholeCamera.look_at([0.0, 0.0, 0.7], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))
    hd = PinholeCamera(
        fx=900.0, fy=900.0, cx=639.5, cy=359.5, width=1280, height=720, pose=look.pose
    )
    c2 = PinholeCamera(fx=130.0, fy=130.0, cx=77.5, cy=59.0, width=156, height=119, pose=look.pose)
    assert c2.width * c2.height == 18_564
    params, poses = scene()
    t = timeit(lambda: render_depth(params, poses, hd, n_samples=7), 1 if args.quick else 3)
    add(
        "render_depth 4 objects 1280x720, 7 samples/ray",
        1280 * 720 / t,
        "rays/s",
        note=f"{t:.3f} s/image",
    )
    t = timeit(lambda: render_depth(params, poses, c2, n_samples=7), reps)
    add(
        "render_depth 4 objects 18,564 rays, 7 samples/ray",
        t,
        "s/image",
        thesis="0.013 s (RTX 3090)",
        note=f"{18_564 / t:.3g} rays/s",
    )
    nb = 16 if args.quick else 64
    bparams, bposes = scene(nb)
    t = timeit(lambda: render_depth(bparams, bposes, c2, n_samples=7), 1 if args.quick else 3)
    add(
        f"render_depth batched {nb} scenes x 18,564 rays, 7 s/ray",
        t / nb,
        "s/image",
        thesis="0.013 s (RTX 3090)",
        note=f"{nb * 18_564 / t:.3g} rays/s",
    )

    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(
        json.dumps(
            {
                "command": " ".join(
                    ["python", "-m", "benchmarks.geometry", *(argv or sys.argv[1:])]
                ),
                "cores": os.cpu_count(),
                "torch_threads": torch.get_num_threads(),
                "torch": torch.__version__,
                "quick": args.quick,
                "rows": rows,
            },
            indent=2,
        )
    )
    print(f"wrote {RESULTS}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
