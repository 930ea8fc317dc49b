"""Closed-loop pushing manipulation in simulation: Table 4.6 (and 4.3, 4.7.3) of the thesis.

Rows (4.7.4): ``R-SQPD-Net`` (recognized shapes + the SQPD-Net checkpoint in ``--model``),
``PyBullet w/ Recog.`` (recognized shapes re-simulated in PyBullet, ``PhysicsDynamics``) and
``PyBullet w/ GT`` (the simulator's true shapes re-simulated). Columns: moving 20, singulation 20,
grasping clutter 10, grasping large 10 episodes (+ interactive moving, 4.7.3), success and the
mean number of pushes over successes. Grasping success is strict (a feasible grasp exists AND
executing it lifts the target); the thesis' criterion (a feasible grasp is found) is reported
beside it as ``found``. Per-step planning latency is split into sampling (incl. start-pose
collision checks), rollout, cost and grasp feasibility; recognition and execution are listed too.

The physics baseline re-simulates the candidate pushes in one batched PyBullet world (a kinematic
Panda hand per scene copy, ``PhysicsDynamics``: 100 pushes of 4 objects in 8-20 s on this CPU,
the full-robot reference took 55-115 s), so ``--physics-sequences`` (K for the PyBullet rows) is
the knob that makes a reduced run affordable; the thesis' K = 100 is the default. Episodes run in
worker processes (``--workers``; torch threads = 1 in each), or as Ray tasks with
``--ray-address``.

Full run (Table 4.6 sizes)::

    python -m benchmarks.mpc --model models/sqpdnet --workers 2

Writes ``benchmarks/results/mpc.json`` and one PNG strip per task
(``benchmarks/results/mpc_<task>.png``, the first episode of the first method run).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"

TASKS = ("moving", "singulation", "grasping_clutter", "grasping_large", "interactive_moving")
FULL_COUNTS = {
    "moving": 20,
    "singulation": 20,
    "grasping_clutter": 10,
    "grasping_large": 10,
    "interactive_moving": 10,
}
METHODS = ("R-SQPD-Net", "PyBullet w/ Recog.", "PyBullet w/ GT")
THESIS = {  # Table 4.6 (success, mean steps); interactive moving has no numbers in the thesis
    "R-SQPD-Net": {
        "moving": ("19/20", None),
        "singulation": ("18/20", 5.17),
        "grasping_clutter": ("9/10", 2.50),
        "grasping_large": ("9/10", 2.56),
    },
    "PyBullet w/ Recog.": {
        "moving": ("19/20", None),
        "singulation": ("15/20", 5.43),
        "grasping_clutter": ("7/10", 3.29),
        "grasping_large": ("9/10", 2.22),
    },
    "PyBullet w/ GT": {
        "moving": ("20/20", None),
        "singulation": ("19/20", 4.73),
        "grasping_clutter": ("9/10", 2.56),
        "grasping_large": ("9/10", 2.22),
    },
}
TIMING_KEYS = ("sampling", "rollout", "cost", "grasp", "plan", "observe", "recognize", "execute")

# --- worker side ---------------------------------------------------------------------------------

_CACHE: dict = {}


def _init_worker() -> None:
    import torch

    torch.set_num_threads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def _runner(method: str, model_dir: str | None, k_seq: int, max_steps: int, reach: str):
    """One runner per (method, K) per process: simulator, dynamics, recognizer are reused."""
    key = (method, model_dir, k_seq, max_steps, reach)
    if key in _CACHE:
        return _CACHE[key]
    from sqmanip.planning.episode import EpisodeRunner, sim_planner
    from sqmanip.planning.recognition import GroundTruthObjects, PerceptionObjects
    from sqmanip.planning.scenarios import sim_table
    from sqmanip.sim import Simulator

    sim = _CACHE.setdefault("sim", Simulator())
    if method == "R-SQPD-Net":
        from sqmanip.dynamics.train import load_model

        dyn = load_model(model_dir)
        dyn.eval()
    else:
        from sqmanip.dynamics.physics import PhysicsDynamics

        dyn = _CACHE.setdefault("physics", PhysicsDynamics())
    objects = (
        GroundTruthObjects() if method == "PyBullet w/ GT" else PerceptionObjects(table=sim_table())
    )
    reachability = None
    if reach == "workspace":
        from sqmanip.grasping.config import WorkspaceReachability
        from sqmanip.planning.mpc import ROBOT_BASE

        reachability = WorkspaceReachability(base=ROBOT_BASE)
    # the physics rows re-simulate every push: K draws, never every push (their K is the cost)
    every = {} if method == "R-SQPD-Net" else {"score_every_single_push": ()}
    planner = sim_planner(dyn, k_seq, reachability=reachability, **every)
    runner = EpisodeRunner(sim, objects, planner, max_steps=max_steps)
    _CACHE[key] = runner
    return runner


def run_one(job: dict) -> dict:
    """Run one episode (in a worker); returns a JSON-able record."""
    _init_worker()
    from sqmanip.planning.episode import render_strip, run_episode
    from sqmanip.planning.scenarios import make_scenario

    t0 = time.perf_counter()
    try:
        sc = make_scenario(job["task"], job["index"], job["seed"])
        runner = _runner(job["method"], job["model"], job["k"], job["max_steps"], job["reach"])
        res = run_episode(runner, sc)
    except Exception as exc:  # one broken episode must not sink the whole table
        return {
            "method": job["method"],
            "task": job["task"],
            "index": job["index"],
            "success": False,
            "steps": 0,
            "reason": f"error: {type(exc).__name__}: {exc}",
            "grasp_found": None,
            "metric": None,
            "wall_s": time.perf_counter() - t0,
            "step_timings_ms": [],
        }
    rec = {"method": job["method"], "task": job["task"], **res.to_dict()}
    rec["wall_s"] = time.perf_counter() - t0
    if job.get("strip"):
        path = render_strip(sc, res, job["strip"])
        rec["strip"] = str(path)
    return rec


# --- driver --------------------------------------------------------------------------------------


def _model_status(model: str | None) -> tuple[bool, str]:
    if not model:
        return False, "no --model given"
    p = Path(model)
    if not (p / "config.json").is_file() or not (p / "model.pt").is_file():
        return False, f"no trained SQPD-Net checkpoint in {p} (needs config.json and model.pt)"
    return True, f"checkpoint {p}"


def _summary(records: list[dict], method: str, task: str) -> dict:
    rs = [r for r in records if r["method"] == method and r["task"] == task]
    succ = [r for r in rs if r["success"]]
    out = {
        "episodes": len(rs),
        "success": len(succ),
        "mean_steps": (sum(r["steps"] for r in succ) / len(succ)) if succ else None,
        "failures": sorted({r["reason"] for r in rs if not r["success"]}),
    }
    if task.startswith("grasping"):
        out["grasp_found"] = sum(bool(r["grasp_found"]) for r in rs)
    steps = [t for r in rs for t in r["step_timings_ms"] if "plan" in t]
    out["latency_ms"] = {
        k: (sum(t.get(k, 0.0) for t in steps) / len(steps)) if steps else None for k in TIMING_KEYS
    }
    out["planning_steps"] = len(steps)
    out["episode_wall_s"] = (sum(r["wall_s"] for r in rs) / len(rs)) if rs else None
    return out


def _fmt_steps(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.mpc", description=__doc__.split("\n")[0]
    )
    ap.add_argument(
        "--episodes", type=int, default=None, help="episodes per task (default: Table 4.6)"
    )
    ap.add_argument(
        "--counts",
        default=None,
        help="per-task episodes, e.g. moving=2,singulation=2 (overrides --episodes for those)",
    )
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    ap.add_argument(
        "--reachability",
        choices=("ik", "workspace"),
        default="ik",
        help="grasp kinematic feasibility in the MPC: Panda IK (as the simulator) or the "
        "workspace-radius stand-in (fast, optimistic)",
    )
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--model", default="models/sqpdnet", help="SQPD-Net checkpoint dir")
    ap.add_argument("--sequences", type=int, default=100, help="K for R-SQPD-Net (B.4: 100)")
    ap.add_argument(
        "--physics-sequences", type=int, default=100, help="K for the PyBullet rows (B.4: 100)"
    )
    ap.add_argument("--max-steps", type=int, default=10)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ray-address", default=None, help="run episodes as Ray tasks there")
    ap.add_argument(
        "--quick", action="store_true", help="1 episode per task, K = 8 for physics, 4 steps"
    )
    ap.add_argument("--out", default=str(RESULTS / "mpc.json"))
    ap.add_argument("--strip-dir", default=str(RESULTS), help="where the PNG strips go")
    args = ap.parse_args(argv)
    if args.quick:
        args.episodes = 1 if args.episodes is None else args.episodes
        args.physics_sequences = min(args.physics_sequences, 8)
        args.max_steps = min(args.max_steps, 4)

    import torch

    print("command:", " ".join([sys.executable, "-m", "benchmarks.mpc", *sys.argv[1:]]))
    print(
        f"machine: {platform.machine()} {platform.processor() or ''} cores={os.cpu_count()} "
        f"torch={torch.__version__} torch_threads(workers)=1 python={platform.python_version()}"
    )
    ok_model, model_msg = _model_status(args.model)
    methods = []
    skipped = {}
    for m in args.methods:
        if m == "R-SQPD-Net" and not ok_model:
            skipped[m] = model_msg
            print(f"SKIP {m}: {model_msg}; train one with `sqmanip train` and pass --model DIR")
            continue
        methods.append(m)
    counts = {
        t: (args.episodes if args.episodes is not None else FULL_COUNTS[t]) for t in args.tasks
    }
    for item in (args.counts or "").split(","):
        if item:
            task, _, n = item.partition("=")
            if task not in counts or not n.isdigit():
                ap.error(f"--counts: expected TASK=N with TASK in {args.tasks}, got {item!r}")
            counts[task] = int(n)
    print(
        f"episodes per task: {counts}; K: R-SQPD-Net {args.sequences}, PyBullet "
        f"{args.physics_sequences}; max steps {args.max_steps}; workers {args.workers}; "
        f"grasp reachability {args.reachability}"
    )
    RESULTS.mkdir(parents=True, exist_ok=True)
    jobs = []
    for m in methods:
        for t in args.tasks:
            for i in range(counts[t]):
                jobs.append(
                    {
                        "method": m,
                        "task": t,
                        "index": i,
                        "seed": args.seed,
                        "model": args.model if m == "R-SQPD-Net" else None,
                        "k": args.sequences if m == "R-SQPD-Net" else args.physics_sequences,
                        "max_steps": args.max_steps,
                        "reach": args.reachability,
                        "strip": str(Path(args.strip_dir) / f"mpc_{t}.png")
                        if (i == 0 and m == methods[0])
                        else None,
                    }
                )
    # longest first (physics grasping with horizon 3) to balance the workers
    cost = {"grasping_clutter": 3, "grasping_large": 3, "singulation": 2}
    jobs.sort(
        key=lambda j: -(cost.get(j["task"], 1) * (j["k"] if "PyBullet" in j["method"] else 1))
    )
    t0 = time.perf_counter()
    records: list[dict] = []

    def report(rec: dict) -> None:
        records.append(rec)
        print(
            f"  [{len(records)}/{len(jobs)}] {rec['method']:<18} {rec['task']:<18} #{rec['index']} "
            f"{'OK ' if rec['success'] else 'FAIL'} steps={rec['steps']} "
            f"({rec['reason']}) {rec['wall_s']:.0f}s",
            flush=True,
        )

    if args.ray_address:
        try:
            import ray
        except ImportError:
            print("error: --ray-address needs the 'ray' package (pip install ray)", file=sys.stderr)
            return 2
        ray.init(address=args.ray_address)
        remote = ray.remote(num_cpus=1)(run_one)
        pending = [remote.remote(j) for j in jobs]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            report(ray.get(done[0]))
    elif args.workers <= 1:
        for j in jobs:
            report(run_one(j))
    else:
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        with ProcessPoolExecutor(args.workers, mp_context=ctx, initializer=_init_worker) as ex:
            futs = [ex.submit(run_one, j) for j in jobs]
            from concurrent.futures import as_completed

            for f in as_completed(futs):
                report(f.result())
    wall = time.perf_counter() - t0

    summary = {m: {t: _summary(records, m, t) for t in args.tasks} for m in methods}
    head = f"{'MODEL':<20}" + "".join(f"| {t:<26}" for t in args.tasks)
    print("\nTable 4.6 layout: ours success (steps) [thesis success (steps)]")
    print(head)
    print("-" * len(head))
    for m in args.methods:
        row = f"{m:<20}"
        for t in args.tasks:
            th = THESIS.get(m, {}).get(t)
            ths = f"[{th[0]} {_fmt_steps(th[1])}]" if th else "[-]"
            if m in skipped:
                cell = f"skipped {ths}"
            else:
                s = summary[m][t]
                cell = f"{s['success']}/{s['episodes']} {_fmt_steps(s['mean_steps'])} {ths}"
                if "grasp_found" in s:
                    cell = f"{s['success']}/{s['episodes']}(found {s['grasp_found']}) " + (
                        f"{_fmt_steps(s['mean_steps'])} {ths}"
                    )
            row += f"| {cell:<26}"
        print(row)
    print(
        "\nmean per-step latency (ms): sampling / rollout / cost / grasp | plan total | recognize"
    )
    for m in methods:
        for t in args.tasks:
            lat = summary[m][t]["latency_ms"]
            if lat["plan"] is None:
                continue
            print(
                f"  {m:<18} {t:<18} {lat['sampling']:8.1f} / {lat['rollout']:8.1f} / "
                f"{lat['cost']:6.1f} / {lat['grasp']:7.1f} | {lat['plan']:8.1f} | "
                f"{lat['recognize']:7.1f}  ({summary[m][t]['planning_steps']} steps)"
            )
    for m, why in skipped.items():
        print(f"skipped {m}: {why}")
    print(f"wall time {wall:.0f} s")
    out = {
        "command": " ".join(
            ["python -m benchmarks.mpc", *(argv if argv is not None else sys.argv[1:])]
        ),
        "machine": {"cores": os.cpu_count(), "torch_threads": 1, "platform": platform.platform()},
        "config": {
            "episodes": counts,
            "sequences": args.sequences,
            "physics_sequences": args.physics_sequences,
            "max_steps": args.max_steps,
            "reachability": args.reachability,
            "seed": args.seed,
            "workers": args.workers,
            "model": args.model,
        },
        "skipped": skipped,
        "thesis_table_4_6": THESIS,
        "summary": summary,
        "episodes": records,
        "wall_s": wall,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1, default=_json_default))
    print(f"wrote {args.out}")
    return 0


def _json_default(o):
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if hasattr(o, "tolist"):
        return o.tolist()
    return str(o)


if __name__ == "__main__":
    raise SystemExit(main())
