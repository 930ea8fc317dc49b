"""Table 5.1: find / grasp success and mean steps of the four methods (O-/R- x search-and-grasp /
search-for-grasp) on simulated shelf scenarios with 2, 4, 6 and 8 surrounding objects, beside the
thesis' numbers; plus the timing of f and g over the whole pose grid (C.2: 13 ms, C.3: 12.8 ms on
an RTX 3090).

Scenarios (:mod:`sqmanip.search.scenarios`) are generated once per object count from seeds
``--seed, --seed + 1, ...`` (discarded ones skipped) and shared by all methods; a change to the
arm check changes which scenarios are kept, so ``--save-scenarios F`` at one commit and
``--scenarios F`` at another compare two versions on the same scenes. An episode replays step
for step on one machine, but a committed run need not replay in another session: the saved
seed-300/500 scenes grasped 29 of 54 at 6 and 8 objects in one session against the 34 committed
from an earlier one with the same planner, and only 53 of 124 6-8 object episodes ended alike
(``search_r_sfg_*_rerun.json``); small numeric differences grow over the closed loop
(simulator, recognition, sampling). Compare two versions in the same session, on the same
machine, and read a paired difference of a few episodes in 54 as noise. Episodes run in
``--workers`` processes (one simulator and planner per process, 1 torch thread each) or, with
``--ray-address``, as Ray tasks on a cluster (``pip install ray``; the full 180 episodes per cell
of the thesis). The R- methods recognize with the recognition network refined by the fitter
(:data:`sqmanip.search.episode.RECOGNITION`; ``benchmarks.search_recognition`` compares the
methods on the shelf). Pushes are predicted with the kinematic push model, or with SQPD-Net from a
checkpoint directory (``--dynamics models/sqpdnet``, the thesis' choice). The kinematic model is
the default because it measured no worse here (within the replay noise above) in half to two
thirds of the planning time per decision: R-Search-for-Grasp at 6 and 8 objects on the saved
seed-300/500 scenarios, 34 of 54 grasped against 30 with SQPD-Net (found 44 against 43)
(``benchmarks/results/search_r_sfg_6_8_seed*_sqpdnet.json``). Once the target is visible,
``g(x*)`` counts only the grasps the simulator's own IK and collision checks accept
(:class:`sqmanip.search.execution.SimGraspCheck`), and scenarios whose target no such grasp
reaches with the shelf alone are discarded (5.5.1). One PNG per shown episode (the first of each
cell): camera image, f and f*g maps and the chosen action per step, written without a plotting
library.

    python -m benchmarks.search [--episodes N] [--objects 2 4 6 8] [--workers W] [--quick]
    python -m benchmarks.search --scenarios F --seed S --episodes N --only 9105 9322  # replay two
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import struct
import sys
import time
import zlib
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

import numpy as np

OUT = os.path.join(os.path.dirname(__file__), "results", "search.json")
PNG_DIR = os.path.join(os.path.dirname(__file__), "results", "search_png")

METHODS = {
    "O-Search-and-Grasp": ("oracle", "search_and_grasp"),
    "O-Search-for-Grasp": ("oracle", "search_for_grasp"),
    "R-Search-and-Grasp": ("recognized", "search_and_grasp"),
    "R-Search-for-Grasp": ("recognized", "search_for_grasp"),
}
NEAR_WALL = 0.10
"""A target whose side is closer than this (m) to a side board counts as near a wall in the
split of the summary: there, a wide occluder against the board can be neither pushed off it
(the pusher's palm reaches 10 cm along the push) nor picked (the fingers do not fit beside it),
and most failures were such scenes (ours)."""

THESIS = {  # Table 5.1: n -> (find succ, grasp succ, find steps, grasp steps)
    "O-Search-and-Grasp": {
        2: (0.978, 0.939, 1.392, 1.562),
        4: (0.939, 0.761, 2.178, 2.635),
        6: (0.878, 0.622, 2.589, 3.473),
        8: (0.844, 0.528, 2.664, 3.947),
    },
    "O-Search-for-Grasp": {
        2: (0.983, 0.928, 1.407, 1.647),
        4: (0.933, 0.794, 2.077, 2.769),
        6: (0.900, 0.678, 2.377, 3.574),
        8: (0.889, 0.578, 2.831, 4.125),
    },
    "R-Search-and-Grasp": {
        2: (0.983, 0.928, 1.362, 1.611),
        4: (0.928, 0.789, 2.222, 2.739),
        6: (0.889, 0.656, 2.581, 3.432),
        8: (0.878, 0.606, 2.981, 3.78),
    },
    "R-Search-for-Grasp": {
        2: (0.972, 0.922, 1.331, 1.651),
        4: (0.933, 0.756, 2.196, 2.765),
        6: (0.922, 0.672, 2.301, 3.281),
        8: (0.894, 0.656, 2.901, 3.975),
    },
}


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a success rate ``k / n``."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    den = 1 + z * z / n
    c = (p + z * z / (2 * n)) / den
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, c - h), min(1.0, c + h))


# --- PNG without a plotting library ------------------------------------------------------------


def write_png(path: str, rgb: np.ndarray) -> None:
    """Write an ``(H, W, 3)`` uint8 image as PNG (zlib, no filter)."""
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].astype(np.uint8).tobytes() for y in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    with open(path, "wb") as fh:
        fh.write(png)


def _map_image(m: np.ndarray, size: int, color: tuple[int, int, int]) -> np.ndarray:
    """A grid map (n_x, n_y) as an image seen from above: x (depth) up, y (left) to the left."""
    img = m[::-1, ::-1]  # far (large x) at the top, +y (left seen from the robot) left
    v = np.clip(img, 0, 1)
    cell = max(1, size // max(v.shape))
    big = np.kron(v, np.ones((cell, cell)))
    out = np.full((*big.shape, 3), 40, np.uint8)
    for c in range(3):
        out[..., c] = (40 + big * (color[c] - 40)).astype(np.uint8)
    return out


def _mark(img: np.ndarray, ij: tuple[float, float], shape, color) -> None:
    cell = img.shape[0] // shape[0]
    i = int((shape[0] - 1 - ij[0]) * cell + cell / 2)
    j = int((shape[1] - 1 - ij[1]) * cell + cell / 2)
    r = max(2, cell // 2)
    img[max(0, i - r) : i + r, max(0, j - r) : j + r] = color


def _pad(a: np.ndarray, h: int) -> np.ndarray:
    return np.pad(a, ((0, h - a.shape[0]), (0, 4), (0, 0)))


def episode_png(path: str, events: list, grid_xy0, resolution: float) -> None:
    """Rows = steps: camera image | f map | f*g map, the action's start (white) and end
    (yellow) marked on the maps (grid cells; pick: grasp -> place)."""
    rows = []
    for e in events:
        rgb = e.rgb[::4, ::4] if e.rgb is not None else np.zeros((180, 320, 3), np.uint8)
        h = rgb.shape[0]
        f = _map_image(e.f_map, h, (80, 160, 255))
        fg = _map_image(e.fg_map, h, (80, 255, 120))
        shape = e.f_map.shape
        p = e.params
        pts = []
        if e.action == "push":
            s = np.asarray(p["start"])
            pts = [s[:2], s[:2] + np.asarray(p["displacement"])[:2]]
        elif e.action in ("pick_and_place",):
            pts = [np.asarray(p["grasp_pose"])[:2, 3], np.asarray(p["place_pose"])[:2, 3]]
        elif e.action == "grasp":
            pts = [np.asarray(p["grasp_pose"])[:2, 3]]
        for img in (f, fg):
            for q, col in zip(pts, ((255, 255, 255), (255, 220, 0)), strict=False):
                ij = ((q[0] - grid_xy0[0]) / resolution, (q[1] - grid_xy0[1]) / resolution)
                _mark(img, ij, shape, col)
        rows.append(np.concatenate([_pad(a, h) for a in (rgb, f, fg)], 1))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 4), (0, width - r.shape[1]), (0, 0))) for r in rows]
    write_png(path, np.concatenate(rows, 0))


# --- workers ---------------------------------------------------------------------------------

_STATE: dict[str, Any] = {}


def _worker_init() -> None:
    import torch

    torch.set_num_threads(1)


def _push_dynamics(name: str, floor_z: float):
    """``kinematic`` (rigid slide of the pushed object) or an SQPD-Net checkpoint directory,
    lowered to the shelf floor (:class:`sqmanip.search.SQPDNetDynamics`)."""
    from sqmanip.search import KinematicPushDynamics, SQPDNetDynamics

    if name == "kinematic":
        return KinematicPushDynamics()
    from sqmanip.dynamics.server import load_checkpoint

    return SQPDNetDynamics(load_checkpoint(name), floor_z)


def run_episode(task: dict) -> dict:
    """One episode (runs in a worker process or a Ray task)."""
    import torch
    from sqmanip.search import SearchConfig, SearchPlanner
    from sqmanip.search.episode import NOTHING_MOVED, EpisodeRunner
    from sqmanip.search.mpc import LAST_RESORT, STUCK
    from sqmanip.search.scenarios import ShelfScenario
    from sqmanip.sim import Simulator

    torch.set_num_threads(1)
    if "sim" not in _STATE:
        _STATE["sim"] = Simulator()
        _STATE["planners"] = {}
    sim = _STATE["sim"]
    shapes, method = METHODS[task["method"]]
    dyn_name = task.get("dynamics", "kinematic")
    overrides = dict(task.get("config", {}))
    key = (method, dyn_name, tuple(sorted(overrides.items())))
    planner = _STATE["planners"].get(key)
    if planner is None:
        from sqmanip.search.scenarios import shelf_spec

        dynamics = _push_dynamics(dyn_name, shelf_spec(sim).bottom_z)
        cfg = SearchConfig(method=method, **overrides)
        planner = SearchPlanner(dynamics, None, cfg)
        _STATE["planners"][key] = planner
    runner = EpisodeRunner(sim, planner, shapes=shapes, keep_images=bool(task.get("png")))
    scenario = ShelfScenario.from_dict(task["scenario"])
    t = time.perf_counter()
    res = runner.run(scenario, seed=task["seed"])
    wall = time.perf_counter() - t
    plan = [e.timings_ms.get("plan_total", 0.0) for e in res.events]
    target = scenario.scene.objects[scenario.target_index]
    wall_gap = (
        runner.shelf.inner_width / 2 - abs(target.position[1]) - scenario.target.horizontal_radius
    )
    if task.get("png"):
        os.makedirs(os.path.dirname(task["png"]), exist_ok=True)
        _, ev, _ = planner.models(runner.shelf, scenario.target, runner.camera)
        episode_png(task["png"], res.events, ev.em.grid.xy[0].numpy(), ev.em.grid.resolution)
    return {
        "method": task["method"],
        "n_objects": task["n_objects"],
        "seed": scenario.seed,
        "found": res.found,
        "grasped": res.grasped,
        "find_steps": res.find_steps,
        "grasp_steps": res.grasp_steps,
        "steps": res.steps,
        "target_wall_gap": float(wall_gap),
        "reason": res.reason,
        "wall_s": wall,
        "plan_ms_mean": float(np.mean(plan)) if plan else 0.0,
        "plan_ms_max": float(np.max(plan)) if plan else 0.0,
        "refused": sum(e.message.startswith("refused") for e in res.events),
        "idle": sum(e.message.endswith(f"({NOTHING_MOVED})") for e in res.events),
        "last_resort": sum(LAST_RESORT in e.params.get("reason", "") for e in res.events),
        "stuck": sum(STUCK in e.params.get("reason", "") for e in res.events),
        "upright": sum(
            bool(e.params.get("upright")) and not e.message.startswith("refused")
            for e in res.events
        ),
        "grasp_check_ms": float(
            np.mean(
                [
                    e.timings_ms["plan_grasp_check"]
                    for e in res.events
                    if "plan_grasp_check" in e.timings_ms
                ]
                or [0.0]
            )
        ),  # fmt: skip
    }


def _progress(k: int, total: int, r: dict, t0: float) -> None:
    print(
        f"  [{k}/{total} {time.perf_counter() - t0:5.0f} s] {r['method']} n={r['n_objects']} "
        f"seed={r['seed']}: found={r['found']} grasped={r['grasped']} steps={r['steps']} "
        f"({r['reason'][:60]})",
        flush=True,
    )


def make_scenarios(n_objects: int, count: int, seed: int) -> list[dict]:
    from sqmanip.search.scenarios import ScenarioBuilder

    b = ScenarioBuilder()
    out = [s.to_dict() for s in b.scenarios(n_objects, count, seed=seed + 1000 * n_objects)]
    b.sim.close()
    return out


def time_f_g(repeat: int = 5) -> dict:
    """Median ms of f and g over the whole pose grid for a 4-object scene (1 thread)."""
    import torch
    from sqmanip.search import (
        KinematicPushDynamics,
        SceneState,
        SearchPlanner,
        ShelfSpec,
        TargetSpec,
    )

    from benchmarks.search_functions import scene, timed

    torch.set_num_threads(1)
    shelf, target = ShelfSpec(), TargetSpec.cylinder(0.03, 0.12)
    planner = SearchPlanner(KinematicPushDynamics())
    _, ev, _ = planner.models(shelf, target, shelf.camera())
    s = SceneState.from_objects(scene(shelf))
    f_med, f_min, _ = timed(lambda: ev.em.evaluate(s), repeat)
    g_med, g_min, _ = timed(lambda: ev.gm.evaluate(s), repeat)
    return {"f_ms": f_med, "f_min_ms": f_min, "g_ms": g_med, "g_min_ms": g_min}


def config_overrides(items: list[str]) -> dict[str, Any]:
    """``["alpha=2", ...]`` -> SearchConfig keyword arguments, each value of its field's type
    (checked by building the config once, so a bad name or value fails before any episode)."""
    import dataclasses

    from sqmanip.errors import ValidationError
    from sqmanip.search import SearchConfig

    names = {f.name for f in dataclasses.fields(SearchConfig)} - {"method"}
    defaults = SearchConfig()
    out: dict[str, Any] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or name not in names:
            raise ValueError(f"--set {item!r}: expected NAME=VALUE with NAME a SearchConfig field")
        default = getattr(defaults, name)
        if isinstance(default, bool):
            out[name] = value.lower() in ("1", "true", "yes")
        elif isinstance(default, (int, float, str)):
            out[name] = type(default)(value)
        elif isinstance(default, tuple):
            out[name] = tuple(float(v) for v in value.split(",") if v)
        else:
            raise ValueError(f"--set {item!r}: {name} cannot be set from the command line")
    try:
        SearchConfig(**out)
    except (ValidationError, TypeError) as exc:
        raise ValueError(f"--set: {exc}") from None
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=6, help="episodes per cell")
    ap.add_argument("--objects", type=int, nargs="+", default=[2, 4, 6, 8])
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--ray-address", default=None, help="run the episodes as Ray tasks")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-png", action="store_true")
    ap.add_argument("--quick", action="store_true", help="2 episodes, 2 and 4 objects")
    ap.add_argument("--out", default=OUT, help=f"results file (default {OUT})")
    ap.add_argument(
        "--set",
        metavar="NAME=VALUE",
        action="append",
        default=[],
        help="override a SearchConfig field for every episode (repeatable), e.g. --set alpha=2 "
        "--set risk_weight=0.5",
    )
    ap.add_argument(
        "--dynamics",
        default="kinematic",
        help="push model: 'kinematic' (the pushed object slides, the others stay) or an SQPD-Net "
        "checkpoint directory such as models/sqpdnet (default kinematic)",
    )
    ap.add_argument(
        "--scenarios",
        default=None,
        help="replay the scenarios saved by --save-scenarios (JSON) instead of generating them: "
        "two code versions compared on the same scenes",
    )
    ap.add_argument("--save-scenarios", default=None, help="write the scenarios used (JSON)")
    ap.add_argument(
        "--only",
        type=int,
        nargs="+",
        default=None,
        metavar="SEED",
        help="run only the scenarios with these seeds, each with the episode seed it has in the "
        "full run: replays chosen episodes of a run exactly, e.g. the ones a change can affect",
    )
    args = ap.parse_args(argv)
    try:
        overrides = config_overrides(args.set)
    except ValueError as exc:
        ap.error(str(exc))
    if args.quick:
        args.episodes, args.objects = 2, [2, 4]
    import torch

    torch.set_num_threads(1)
    print("command:", " ".join([sys.executable, "-m", "benchmarks.search", *sys.argv[1:]]))
    print(
        f"machine: {platform.processor() or platform.machine()}, cores={os.cpu_count()}, "
        f"torch threads=1 per worker, workers={args.workers}, load={os.getloadavg()[0]:.1f}"
    )
    t0 = time.perf_counter()
    timing = time_f_g()
    print(
        f"f over grid {timing['f_ms']:.1f} ms (thesis 13 ms, RTX 3090); g over grid "
        f"{timing['g_ms']:.1f} ms (thesis 12.8 ms); 4-object scene, median of 5"
    )
    if args.scenarios:
        with open(args.scenarios) as f:
            saved = {int(n): v for n, v in json.load(f).items()}
        missing = [n for n in args.objects if n not in saved]
        if missing:
            ap.error(f"{args.scenarios} holds no scenarios with {missing} objects")
        scen = {n: saved[n][: args.episodes] for n in args.objects}
    else:
        scen = {n: make_scenarios(n, args.episodes, args.seed) for n in args.objects}
    if args.save_scenarios:
        with open(args.save_scenarios, "w") as f:
            json.dump(scen, f)
    print(
        f"scenarios: { {n: len(v) for n, v in scen.items()} } in {time.perf_counter() - t0:.0f} s"
    )
    tasks = []
    for n in args.objects:
        for m in args.methods:
            for k, sc in enumerate(scen[n]):
                if args.only is not None and sc["seed"] not in args.only:
                    continue
                png = None
                if k == 0 and not args.no_png:
                    png = os.path.join(PNG_DIR, f"{m}_{n}obj_seed{sc['seed']}.png")
                tasks.append(dict(method=m, n_objects=n, scenario=sc, seed=args.seed + k, png=png,
                                  dynamics=args.dynamics,
                                  config=overrides))  # fmt: skip
    t1 = time.perf_counter()
    if args.ray_address:
        import ray

        ray.init(address=args.ray_address)
        remote = ray.remote(num_cpus=1)(run_episode)
        results = ray.get([remote.remote(t) for t in tasks])
    elif args.workers > 1:
        with ProcessPoolExecutor(args.workers, initializer=_worker_init) as pool:
            futures = [pool.submit(run_episode, t) for t in tasks]
            for k, fut in enumerate(as_completed(futures)):
                _progress(k + 1, len(tasks), fut.result(), t1)
            results = [f.result() for f in futures]
    else:
        results = []
        for k, t in enumerate(tasks):
            results.append(run_episode(t))
            _progress(k + 1, len(tasks), results[-1], t1)
    wall = time.perf_counter() - t1

    rows = []
    head = (
        f"{'method':20s} {'n':>2s} {'eps':>3s} {'find':>6s} {'95% CI':>13s} {'thesis':>6s} "
        f"{'grasp':>6s} {'95% CI':>13s} {'thesis':>6s} {'f-steps':>7s} {'th':>5s} "
        f"{'g-steps':>7s} {'th':>5s} {'plan ms':>8s}"
    )
    print(head)
    for m in args.methods:
        for n in args.objects:
            rs = [r for r in results if r["method"] == m and r["n_objects"] == n]
            N = len(rs)
            kf = sum(r["found"] for r in rs)
            kg = sum(r["grasped"] for r in rs)
            fs = [r["find_steps"] for r in rs if r["found"]]
            gs = [r["grasp_steps"] for r in rs if r["grasped"]]
            th = THESIS[m][n] if n in THESIS[m] else (float("nan"),) * 4
            row = dict(
                method=m,
                n_objects=n,
                episodes=N,
                find=kf / N if N else float("nan"),
                find_ci=wilson(kf, N),
                grasp=kg / N if N else float("nan"),
                grasp_ci=wilson(kg, N),
                find_steps=float(np.mean(fs)) if fs else float("nan"),
                grasp_steps=float(np.mean(gs)) if gs else float("nan"),
                plan_ms=float(np.mean([r["plan_ms_mean"] for r in rs])) if rs else float("nan"),
                near_wall=[r["grasped"] for r in rs if r["target_wall_gap"] < NEAR_WALL],
                elsewhere=[r["grasped"] for r in rs if r["target_wall_gap"] >= NEAR_WALL],
                thesis=dict(find=th[0], grasp=th[1], find_steps=th[2], grasp_steps=th[3]),
            )
            rows.append(row)
            print(
                f"{m:20s} {n:2d} {N:3d} {row['find']:6.2f} "
                f"[{row['find_ci'][0]:.2f}, {row['find_ci'][1]:.2f}] {th[0]:6.3f} "
                f"{row['grasp']:6.2f} [{row['grasp_ci'][0]:.2f}, {row['grasp_ci'][1]:.2f}] "
                f"{th[1]:6.3f} {row['find_steps']:7.2f} {th[2]:5.2f} {row['grasp_steps']:7.2f} "
                f"{th[3]:5.2f} {row['plan_ms']:8.0f}"
            )
    for row in rows:
        near, far = row["near_wall"], row["elsewhere"]
        print(
            f"{row['method']} n={row['n_objects']}: target within {NEAR_WALL * 100:.0f} cm of a "
            f"side wall {sum(near)}/{len(near)} grasped, elsewhere {sum(far)}/{len(far)}"
        )
    reasons: dict[str, int] = {}
    for r in results:
        key = r["reason"].split(":")[0]
        reasons[key] = reasons.get(key, 0) + 1
    print(f"episode endings: {reasons}")
    print(
        f"actions the simulator refused: {sum(r['refused'] for r in results)}, executed but "
        f"moved nothing: {sum(r.get('idle', 0) for r in results)}, last-resort decisions: "
        f"{sum(r.get('last_resort', 0) for r in results)}, decisions that found no safe gain: "
        f"{sum(r.get('stuck', 0) for r in results)}, upright pushes executed: "
        f"{sum(r.get('upright', 0) for r in results)}, in "
        f"{len(results)} episodes; grasp executability check (SimGraspCheck) "
        f"{np.mean([r['grasp_check_ms'] for r in results if r['grasp_check_ms'] > 0] or [0]):.0f}"
        " ms per visible step"
    )
    print(f"episodes: {len(results)} in {wall:.0f} s ({args.workers} workers)")
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump(
            dict(
                args=vars(args),
                timing=timing,
                wall_s=wall,
                rows=rows,
                episodes=results,
                endings=reasons,
            ),
            fh,
            indent=2,
        )
    print("wrote", args.out, "and", PNG_DIR if not args.no_png else "(no PNG)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
