"""Simulator timings: reset (random scene), observe (640x576, 1280x720), push and grasp.

Run: ``python -m benchmarks.sim [--quick]``. Writes ``benchmarks/results/sim.json``.
Wall-clock seconds per call on this CPU (PyBullet DIRECT, TinyRenderer), median over reps,
with the simulated seconds of the actions beside them (real-time factor = sim / wall).
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
from sqmanip.sim import Intrinsics, ObjectSpec, SceneSpec, Simulator

RESULTS = Path(__file__).parent / "results" / "sim.json"


def top_grasp(x, y, z) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = (x, y, z)
    return T


def timed(fn) -> tuple[float, object]:
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = ap.parse_args(argv)
    reps = 3 if args.quick else 10
    print("command:", " ".join([sys.executable, "-m", "benchmarks.sim", *(argv or sys.argv[1:])]))
    print(
        f"machine: {platform.processor() or platform.machine()}, cores={os.cpu_count()}, "
        f"torch threads={torch.get_num_threads()}, python {platform.python_version()}"
    )
    rows: dict[str, dict] = {}
    sim = Simulator()

    def record(name, walls, sims=None):
        rows[name] = {"wall_s_median": float(np.median(walls)), "reps": len(walls)}
        if sims is not None:
            rows[name]["sim_s_median"] = float(np.median(sims))

    walls = [timed(lambda i=i: sim.reset(seed=i, n_objects=4))[0] for i in range(reps)]
    record("reset (random, 4 objects, settle)", walls)
    spec = sim.scene_spec
    walls = [timed(lambda: sim.reset(spec))[0] for _ in range(reps)]
    record("reset (replay spec)", walls)

    for w, h in ((640, 576), (1280, 720)):
        k = Intrinsics.scaled(w, h)
        sim.observe(intrinsics=k)
        walls = [timed(lambda k=k: sim.observe(intrinsics=k))[0] for _ in range(reps)]
        record(f"observe {w}x{h} (+cloud, noise)", walls)

    box = ObjectSpec("box", position=(0.42, 0.0, 0.025), size=(0.05, 0.05, 0.05))
    push_scene = SceneSpec(objects=(box,))
    walls, sims, ok = [], [], 0
    for _ in range(reps):
        sim.reset(push_scene)
        dt, res = timed(lambda: sim.push([0.36, 0.0, 0.02], [0.10, 0.0, 0.0]))
        walls.append(dt)
        sims.append(res.sim_time)
        ok += res.success
    record("push (10 cm, 10 via points, home)", walls, sims)

    walls, sims, ok_g = [], [], 0
    for _ in range(reps):
        sim.reset(push_scene)
        dt, res = timed(lambda: sim.grasp(top_grasp(0.42, 0.0, 0.03), 0.08))
        walls.append(dt)
        sims.append(res.sim_time)
        ok_g += res.success
    record("grasp (approach, close, lift, hold 1 s)", walls, sims)
    rows["grasp (approach, close, lift, hold 1 s)"]["success"] = f"{ok_g}/{reps}"
    sim.close()

    print(f"\n{'operation':<40} {'wall s':>8} {'sim s':>7} {'RTF':>6}")
    for name, r in rows.items():
        s = r.get("sim_s_median")
        rtf = f"{s / r['wall_s_median']:.1f}" if s else "-"
        print(f"{name:<40} {r['wall_s_median']:>8.3f} {s if s else float('nan'):>7.2f} {rtf:>6}")
    print(f"grasp success: {ok_g}/{reps}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(
        json.dumps({"quick": args.quick, "cores": os.cpu_count(), "results": rows}, indent=2) + "\n"
    )
    print(f"wrote {RESULTS}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
