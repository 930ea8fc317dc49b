"""Timing of the existence function f and graspability g over the whole pose grid (C.2, C.3) for
a 4-object shelf scene, and of one MPC decision (30 sequences x horizon 3, 5.4.3).

Thesis: f 13 ms, g 12.8 ms on an RTX 3090 (C.2, C.3). Targets on this CPU: f, g <= 50 ms each,
one decision <= 2 s. The decision uses the kinematic push model (no trained SQPD-Net shipped),
so its timing excludes network inference (SQPD-Net predict is a few ms per batch).

    python -m benchmarks.search_functions [--quick] [--threads N]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import numpy as np
import torch
from sqmanip.geometry import Superquadric
from sqmanip.search import (
    KinematicPushDynamics,
    SceneState,
    SearchConfig,
    SearchPlanner,
    ShelfSpec,
    TargetSpec,
)

OUT = os.path.join(os.path.dirname(__file__), "results", "search_functions.json")


def scene(shelf: ShelfSpec) -> list[Superquadric]:
    def box(x, y, sx, sy, h, e2=0.2):
        T = np.eye(4)
        T[:3, 3] = (x, y, shelf.bottom_z + h / 2)
        return Superquadric((sx / 2, sy / 2, h / 2), (0.2, e2), T)

    return [
        box(0.60, 0.0, 0.06, 0.20, 0.20),
        box(0.62, 0.22, 0.08, 0.08, 0.15, 1.0),
        box(0.65, -0.2, 0.06, 0.06, 0.20),
        box(0.75, 0.1, 0.05, 0.05, 0.10, 1.0),
    ]


def timed(fn, repeat: int) -> tuple[float, float, object]:
    out, ts = None, []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        ts.append((time.perf_counter() - t) * 1e3)
    return float(np.median(ts)), float(np.min(ts)), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    print(
        "command:", " ".join([sys.executable, "-m", "benchmarks.search_functions", *sys.argv[1:]])
    )
    print(
        f"machine: {platform.processor() or platform.machine()}, cores={os.cpu_count()}, "
        f"torch threads={torch.get_num_threads()}, load={os.getloadavg()[0]:.1f}"
    )
    repeat = 3 if args.quick else 7
    cfg = SearchConfig()
    shelf, target = ShelfSpec(), TargetSpec.cylinder(0.03, 0.12)
    planner = SearchPlanner(KinematicPushDynamics(), None, cfg)
    cam = shelf.camera()
    t = time.perf_counter()
    grid, ev, _ = planner.models(shelf, target, cam)
    setup = (time.perf_counter() - t) * 1e3
    s = SceneState.from_objects(scene(shelf))
    em, gm = ev.em, ev.gm
    f_med, f_min, f = timed(lambda: em.evaluate(s), repeat)
    g_med, g_min, _ = timed(lambda: gm.evaluate(s), repeat)
    mask = f.bool()
    gf_med, gf_min, _ = timed(lambda: gm.evaluate(s, mask), repeat)
    n_dec = 2 if args.quick else 5
    planner.decide(scene(shelf), target, shelf, cam, False, rng=0)  # warm caches
    d_med, d_min, d = timed(
        lambda: planner.decide(scene(shelf), target, shelf, cam, False, rng=1), n_dec
    )
    # the exact afterimage point test (the reference of the voxel correlation), once
    t = time.perf_counter()
    idx = torch.arange(len(grid))
    n_exact = gm.exact_counts(s, idx)
    ex_ms = (time.perf_counter() - t) * 1e3
    valid = gm.local_valid[gm._theta_index]
    n_fast = gm.n_shelf.clone()
    for i in range(len(s)):
        n_fast += gm.object_hits(s, i).long()
    agree = float((n_exact.bool() == n_fast.bool())[valid].float().mean())
    false_free = int((n_exact.bool() & ~n_fast.bool())[valid].sum())
    rows = [
        ("f over grid (C.2)", f_med, f_min, 13.0, 50.0),
        ("g over grid (C.3)", g_med, g_min, 12.8, 50.0),
        ("g exact point test", ex_ms, ex_ms, None, None),
        ("g where f = 1 (5.3)", gf_med, gf_min, None, 50.0),
        ("MPC decision 30x3", d_med, d_min, None, 2000.0),
    ]
    print(
        f"grid: {len(grid)} poses ({grid.resolution} m), render {em.camera.width}x{em.camera.height}, "
        f"N_gr={gm.n_candidates}, n_gr={cfg.n_gripper_points}, sum f={int(f.sum())}, "
        f"setup (caches) {setup:.0f} ms"
    )
    print(
        f"{'quantity':24s} {'median ms':>10s} {'min ms':>9s} {'thesis ms':>10s} {'target ms':>10s}"
    )
    for name, med, mn, th, tg in rows:
        print(
            f"{name:24s} {med:10.1f} {mn:9.1f} {f'{th:.1f}' if th else '-':>10s} "
            f"{f'{tg:.0f}' if tg else '-':>10s}"
        )
    print(
        f"voxel g vs exact point test: (pose, grasp) collision agreement {agree:.4f}, "
        f"false free {false_free}; decision timings {d.timings_ms}"
    )
    res = {
        "grid_poses": len(grid),
        "resolution_m": grid.resolution,
        "render_px": [em.camera.width, em.camera.height],
        "n_candidates": gm.n_candidates,
        "threads": torch.get_num_threads(),
        "load_avg": os.getloadavg()[0],
        "setup_ms": setup,
        "rows": [
            dict(name=r[0], median_ms=r[1], min_ms=r[2], thesis_ms=r[3], target_ms=r[4])
            for r in rows
        ],
        "decision": {"kind": d.kind, "timings_ms": d.timings_ms},
        "g_voxel_vs_exact": {"agreement": agree, "false_free": false_free},
    }
    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    with open(OUT, "w") as fh:
        json.dump(res, fh, indent=2)
    print("wrote", OUT)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
