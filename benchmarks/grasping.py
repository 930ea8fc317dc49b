"""Closed-loop grasping in the simulator: observe, recognize, plan, execute (Table 3.4).

Run: ``python -m benchmarks.grasping [--trials N] [--objects NAME ...] [--quick] [--workers W]``.
Writes ``benchmarks/results/grasping.json``.

Each trial resets a tabletop scene with ONE object at a random position and yaw (resting on the
table), takes one depth image with the ``overview`` camera (or ``--camera wrist``), recognizes
the cropped cloud with the perception ``Recognizer`` (no labels: support-plane RANSAC and
clustering; viewpoint = camera position), plans with ``GraspPlanner(PandaIKReachability())``
on the largest recognized object (the other segments are obstacles; the support plane comes
from the recognized scene), and executes the best grasp with ``Simulator.grasp``; when the
simulator refuses a grasp (``PreconditionError``: arm collision or IK), the next candidate is
tried, up to 3. The planned pose goes to the simulator through
``PandaIKReachability.executable_pose`` (the one planner -> simulator frame conversion). Success = the simulator reports the object lifted 10 cm and held for 1 s.
Both recognition methods run on the same observation of the same scene (same seeds): the
superquadric fitter (``optimization``, ours) and the MVBB baseline (``mvbb``). A third row,
``gt``, plans on the *true* shapes (the superquadrics the primitives and the mug/bottle were built
from, posed in the world; n/a for the pybullet_data meshes, which have none), so the planner's own
error is separated from recognition error.

The planner uses the hand measured on the simulator's URDF (``PANDA_HAND_URDF``), the swept
pre-grasp approach of the simulator (10 cm along the approach axis, wrist included), and opens the
hand to ``PlanOptions.opening(width)``, the same opening its collision check assumed. Every trial
logs why the simulator refused or dropped a grasp (``failure``: ``ik``, ``approach collision``,
``grasp collision``, ``lift collision``, ``slipped``, ``not lifted``, ``no feasible grasp``).

Reference (Table 3.4, real-world, 3.5.2): DSQNet 93 %, MVBB 59 % grasp success. These are
simulated numbers with a training-free fitter, so they are *beside*, not equal to, the table.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import platform
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results" / "grasping.json"
REFERENCE = {"optimization": 0.93, "mvbb": 0.59}
"""Table 3.4 (real robot): DSQNet 93 %, MVBB 59 %."""
METHODS = ("optimization", "mvbb", "gt")
MAX_ATTEMPTS = 3
APPROACH = 0.10
"""The simulator's pre-grasp distance along the approach axis (``SimConfig.approach_distance``)."""
CROP = ((0.15, -0.30, -0.03), (0.75, 0.30, 0.30))
"""Recognition crop box (world, m): the table top around the workspace, below the robot."""
REGION = ((0.32, -0.15), (0.58, 0.15))
"""Object positions are drawn uniformly in this x-y rectangle (inside the 0.512 m workspace)."""


# --- objects ---------------------------------------------------------------------------------------


def _compound_obj(name: str, parts: list) -> str:
    """Write the convex hulls of superquadric ``parts`` as one multi-object OBJ (PyBullet loads
    it as a compound of hulls); supertoroids are split into 8 sectors, each convex."""
    import trimesh
    from sqmanip.geometry.mesh import superquadric_trimesh

    hulls = []
    for sq in parts:
        mesh = superquadric_trimesh(sq, resolution=24)
        v = np.asarray(mesh.vertices)
        if sq.kind == "supertoroid":
            local = (v - sq.pose[:3, 3]) @ sq.pose[:3, :3]
            ang = np.arctan2(local[:, 1], local[:, 0])
            edges = np.linspace(-np.pi, np.pi, 9)
            for lo, hi in zip(edges[:-1], edges[1:], strict=True):
                m = (ang >= lo - 0.05) & (ang <= hi + 0.05)
                if m.sum() >= 4:
                    hulls.append(trimesh.convex.convex_hull(v[m]))
        else:
            hulls.append(trimesh.convex.convex_hull(v))
    blob = b"".join(np.ascontiguousarray(h.vertices).tobytes() for h in hulls)
    folder = Path(tempfile.gettempdir()) / f"sqmanip_bench_meshes_{os.getuid()}"
    folder.mkdir(exist_ok=True)
    path = folder / f"{name}_{hashlib.sha1(blob).hexdigest()[:12]}.obj"
    if not path.exists():
        lines, off = [], 1
        for i, h in enumerate(hulls):
            lines.append(f"o piece{i}")
            lines += [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in h.vertices]
            lines += [f"f {a + off} {b + off} {c + off}" for a, b, c in h.faces]
            off += len(h.vertices)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text("\n".join(lines) + "\n")
        os.replace(tmp, path)
    return str(path)


def _at(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def mug_parts() -> list:
    """Mug-like: a cylindrical body (r 3.4 cm, 9 cm tall) and a half-ring handle (supertoroid)."""
    from sqmanip.geometry import Superquadric

    body = Superquadric((0.034, 0.034, 0.045), (0.2, 1.0), _at(0, 0, 0.045))
    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # torus axis along world y
    handle_pose = _at(0.036, 0.0, 0.047)
    handle_pose[:3, :3] = R
    handle = Superquadric(
        (0.022, 0.022, 0.006), (1.0, 1.0), handle_pose, kind="supertoroid", a4=1.0
    )
    return [body, handle]


def bottle_parts() -> list:
    """Bottle-like: body (r 3 cm, 12 cm), a tapered shoulder and a neck (r 1.3 cm, 4 cm)."""
    from sqmanip.geometry import Superquadric

    body = Superquadric((0.03, 0.03, 0.06), (0.2, 1.0), _at(0, 0, 0.06))
    shoulder = Superquadric((0.03, 0.03, 0.02), (0.5, 1.0), _at(0, 0, 0.12), taper=-0.55)
    neck = Superquadric((0.013, 0.013, 0.025), (0.2, 1.0), _at(0, 0, 0.155))
    return [body, shoulder, neck]


def object_catalog() -> dict[str, dict]:
    """Name -> ``ObjectSpec`` keyword arguments (pose added per trial)."""
    sphere = (0.03, 0.03, 0.03, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0)
    return {
        "box_small": {"kind": "box", "size": (0.04, 0.05, 0.07)},
        "box_large": {"kind": "box", "size": (0.06, 0.10, 0.09), "mass": 0.3},
        "cyl_thin": {"kind": "cylinder", "radius": 0.02, "height": 0.10},
        "cyl_wide": {"kind": "cylinder", "radius": 0.034, "height": 0.12, "mass": 0.3},
        "sphere": {"kind": "superquadric", "params": sphere},
        "mug": {"kind": "mesh", "compound": "mug"},
        "bottle": {"kind": "mesh", "compound": "bottle"},
        "duck": {"kind": "mesh", "path": "duck_vhacd.urdf", "scale": 0.8},
        "teddy": {"kind": "mesh", "path": "teddy_vhacd.urdf", "scale": 0.7},
        "block": {"kind": "mesh", "path": "random_urdfs/009/009.urdf"},
        "lego": {"kind": "mesh", "path": "lego/lego.urdf", "scale": 1.5},
    }


COMPOUNDS = {"mug": mug_parts, "bottle": bottle_parts}


def true_parts(spec) -> list | None:
    """The object's true shape as world-frame superquadric parts, or None (mesh objects)."""
    from scipy.spatial.transform import Rotation
    from sqmanip.geometry import Superquadric

    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(spec.orientation).as_matrix()
    T[:3, 3] = spec.position
    name = spec.name
    kw = object_catalog()[name]
    if kw.get("compound"):
        return [dataclasses.replace(p, pose=T @ p.pose) for p in COMPOUNDS[kw["compound"]]()]
    if spec.kind == "box":
        return [Superquadric(tuple(0.5 * np.asarray(spec.size)), (0.2, 0.2), T)]
    if spec.kind == "cylinder":
        return [Superquadric((spec.radius, spec.radius, 0.5 * spec.height), (0.2, 1.0), T)]
    if spec.kind == "superquadric" and spec.sq_kind == "superellipsoid":
        a1, a2, a3, e1, e2, k, b, alpha, _ = spec.params
        return [Superquadric((a1, a2, a3), (e1, e2), T, taper=k, bend=b, bend_direction=alpha)]
    return None


def failure_kind(message: str) -> str:
    """Category of a simulator refusal / outcome message (why the grasp was not executed/held)."""
    m = message.lower()
    if "ik" in m.split() or "no ik" in m or "did not converge" in m or "unreachable" in m:
        return "ik"
    if "pre-grasp" in m and "collides" in m:
        return "approach collision"
    if "grasp configuration collides" in m:
        return "grasp collision"
    if "lift" in m and "collides" in m:
        return "lift collision"
    if "nothing between the fingers" in m:
        return "slipped"
    if "not lifted" in m:
        return "not lifted"
    return m.split(":")[0][:40]


def object_spec(name: str, position, orientation):
    from sqmanip.sim import ObjectSpec

    kw = dict(object_catalog()[name])
    compound = kw.pop("compound", None)
    if compound is not None:
        kw["path"] = _compound_obj(compound, COMPOUNDS[compound]())
        kw.setdefault("mass", 0.2)
    rgb = np.random.default_rng(abs(hash(name)) % 2**32).uniform(0.2, 0.9, 3)
    return ObjectSpec(
        position=tuple(position),
        orientation=tuple(orientation),
        color=(*map(float, rgb), 1.0),
        name=name,
        **kw,
    )


def resting_z(spec) -> float:
    """Height of the object frame above the table when its lowest point touches it (m)."""
    import pybullet as p
    from sqmanip.sim.scene import spawn

    cid = p.connect(p.DIRECT)
    try:
        body = spawn(dataclasses.replace(spec, position=(0.0, 0.0, 0.0)), cid)
        lo = p.getAABB(body, physicsClientId=cid)[0][2]
        for j in range(p.getNumJoints(body, physicsClientId=cid)):
            lo = min(lo, p.getAABB(body, j, physicsClientId=cid)[0][2])
    finally:
        p.disconnect(cid)
    return -float(lo) + 0.001


def trial_scene(name: str, seed: int):
    """One object at a random position/yaw in ``REGION``, resting on the table."""
    from scipy.spatial.transform import Rotation
    from sqmanip.sim import SceneSpec

    rng = np.random.default_rng(seed)
    (x0, y0), (x1, y1) = REGION
    xy = (rng.uniform(x0, x1), rng.uniform(y0, y1))
    q = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)).as_quat()
    spec = object_spec(name, (xy[0], xy[1], 0.0), q)
    spec = dataclasses.replace(spec, position=(xy[0], xy[1], resting_z(spec)))
    return SceneSpec(kind="tabletop", objects=(spec,), seed=seed)


# --- one trial -------------------------------------------------------------------------------------

_SIM = None
_PLANNER = None


def _worker_init(threads: int) -> None:
    import torch

    torch.set_num_threads(threads)


def _state():
    global _SIM, _PLANNER
    if _SIM is None:
        from sqmanip.grasping import PANDA_HAND_URDF, GraspPlanner
        from sqmanip.grasping.reachability import PandaIKReachability
        from sqmanip.sim import Simulator

        _SIM = Simulator()
        _PLANNER = GraspPlanner(
            reachability=PandaIKReachability(gripper=PANDA_HAND_URDF), gripper=PANDA_HAND_URDF
        )
    return _SIM, _PLANNER


def run_method(sim, planner, spec, obs, method: str, seed: int, args) -> dict:
    from sqmanip.errors import SQManipError
    from sqmanip.grasping import Environment
    from sqmanip.perception.pipeline import Recognizer
    from sqmanip.perception.types import RecognizeOptions, RecognizeRequest, Workspace

    out: dict = {"method": method, "success": False, "outcome": ""}
    if method == "gt":
        return _run_gt(sim, planner, spec, seed, args, out)
    req = RecognizeRequest(
        points=obs.points.astype(np.float32),
        viewpoint=obs.camera_pose[:3, 3].copy(),
        workspace=Workspace(CROP[0], CROP[1]),
        labels=obs.point_labels.astype(np.int32) if args.labels else None,
        options=RecognizeOptions(method=method, seed=seed),
    )
    t0 = time.perf_counter()
    try:
        scene = Recognizer().recognize(req)
    except SQManipError as exc:
        out.update(
            outcome=f"recognition failed: {exc}", recognize_ms=1e3 * (time.perf_counter() - t0)
        )
        return out
    out["recognize_ms"] = 1e3 * (time.perf_counter() - t0)
    out["n_segments"] = len(scene.objects)
    if not scene.objects:
        out["outcome"] = "nothing recognized"
        return out
    order = sorted(scene.objects, key=lambda o: -len(o.point_indices))
    target, others = order[0], order[1:]
    out["parts"] = [
        {"size": list(p.size), "shape": list(p.shape), "position": p.pose[:3, 3].tolist()}
        for p in target.parts
    ]
    env = (
        Environment(
            support_normal=scene.support_plane.normal, support_offset=scene.support_plane.offset
        )
        if scene.support_plane is not None
        else Environment.table(0.0)
    )
    observed = obs.points[target.point_indices] if args.score == "uncertainty" else None
    return _plan_and_execute(
        sim, planner, target.parts, [o.parts for o in others], env, seed, args, out, observed
    )


def plan_options(seed: int, args) -> object:
    from sqmanip.grasping import PlanOptions

    return PlanOptions(
        max_results=MAX_ATTEMPTS,
        seed=seed,
        chunk_size=args.chunk_size,
        approach_distance=APPROACH,
        include_wrist=True,
        score=args.score,
    )


def _run_gt(sim, planner, spec, seed, args, out) -> dict:
    from sqmanip.grasping import Environment

    parts = true_parts(spec.objects[0])
    if parts is None:
        out["outcome"] = "n/a"
        return out
    observed = None
    if args.score == "uncertainty":  # the true shape is all observed
        from sqmanip.geometry import sample_parts

        observed = sample_parts(parts, 512, generator=seed)[0]
    return _plan_and_execute(
        sim, planner, parts, [], Environment.table(0.0), seed, args, out, observed
    )


def _plan_and_execute(sim, planner, target_parts, others, env, seed, args, out, observed) -> dict:
    from sqmanip.errors import PreconditionError, SQManipError

    opts = plan_options(seed, args)
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        plan = planner.plan_detailed(
            target_parts, others, env, options=opts, observed_points=observed
        )
    except SQManipError as exc:
        out.update(outcome=f"planning failed: {exc}", plan_ms=1e3 * (time.perf_counter() - t0))
        out["failure"] = "planning failed"
        return out
    out["plan_ms"] = 1e3 * (time.perf_counter() - t0)
    out["plan_cpu_ms"] = 1e3 * (time.process_time() - c0)
    out["plan_stats"] = {
        "candidates": plan.stats.n_candidates,
        "checked": plan.stats.n_checked,
        "unreachable": plan.stats.n_unreachable,
        "colliding": plan.stats.n_colliding,
        "timings_ms": {k: round(v, 1) for k, v in plan.stats.timings_ms.items()},
    }
    if not plan.grasps:
        out["outcome"] = "no feasible grasp"
        out["failure"] = "no feasible grasp"
        return out
    refusals = []
    for k, g in enumerate(plan.grasps[:MAX_ATTEMPTS]):
        width = opts.opening(g.width, planner.gripper.max_opening)
        tool = planner.reachability.executable_pose(g.pose)
        if tool is None:  # the planner only returns reachable grasps
            refusals.append("unreachable by PandaIKReachability")
            continue
        try:
            res = sim.grasp(tool, width)
        except (PreconditionError, SQManipError) as exc:
            refusals.append(str(exc))
            continue
        out.update(
            success=bool(res.success),
            outcome=res.message,
            attempt=k + 1,
            grasp={"pose": g.pose.tolist(), "width": g.width, "score": g.score},
        )
        break
    else:
        out["outcome"] = "all candidates refused"
    out["refusals"] = refusals
    out["refusal_kinds"] = [failure_kind(r) for r in refusals]
    if not out["success"]:
        out["failure"] = (
            out["refusal_kinds"][0]
            if out["outcome"] == "all candidates refused" and refusals
            else failure_kind(out["outcome"])
        )
    out["unreachable_refusals"] = sum("unreachable" in r for r in refusals)
    return out


def run_trial(name: str, trial: int, base_seed: int, args) -> dict:
    seed = int(base_seed + 1000 * trial + (int(hashlib.sha1(name.encode()).hexdigest(), 16) % 997))
    sim, planner = _state()
    t0 = time.perf_counter()
    spec = trial_scene(name, seed)
    sim.reset(spec)
    obs = sim.observe(args.camera)
    rec = {"object": name, "trial": trial, "seed": seed, "results": {}}
    for method in args.methods:
        sim.reset(spec)
        rec["results"][method] = run_method(sim, planner, spec, obs, method, seed, args)
    rec["n_object_points"] = int((obs.point_labels == 0).sum())
    rec["wall_s"] = time.perf_counter() - t0
    return rec


# --- report ----------------------------------------------------------------------------------------


def _pct(xs, q):
    xs = [x for x in xs if x is not None]
    return float(np.percentile(xs, q)) if xs else None


def summarize(records: list[dict], objects: list[str], methods: tuple[str, ...]) -> dict:
    per_object: dict[str, dict] = {}
    for name in objects:
        rows = [r for r in records if r["object"] == name]
        per_object[name] = {}
        for m in methods:
            rs = [
                r["results"][m]
                for r in rows
                if m in r["results"] and r["results"][m]["outcome"] != "n/a"
            ]
            outcomes: dict[str, int] = {}
            for x in rs:
                key = "success" if x["success"] else x.get("failure", x["outcome"].split(":")[0])
                outcomes[key] = outcomes.get(key, 0) + 1
            refusal_kinds: dict[str, int] = {}
            for x in rs:
                for k in x.get("refusal_kinds", []):
                    refusal_kinds[k] = refusal_kinds.get(k, 0) + 1
            per_object[name][m] = {
                "trials": len(rs),
                "success": sum(x["success"] for x in rs) / len(rs) if rs else None,
                "refusals": refusal_kinds,
                "plan_ms_p50": _pct([x.get("plan_ms") for x in rs], 50),
                "plan_ms_p95": _pct([x.get("plan_ms") for x in rs], 95),
                "plan_cpu_ms_p50": _pct([x.get("plan_cpu_ms") for x in rs], 50),
                "recognize_ms_p50": _pct([x.get("recognize_ms") for x in rs], 50),
                "unreachable_refusals": sum(x.get("unreachable_refusals", 0) for x in rs),
                "outcomes": outcomes,
            }
    average = {}
    for m in methods:
        vals = [per_object[o][m]["success"] for o in objects]
        vals = [v for v in vals if v is not None]
        average[m] = float(np.mean(vals)) if vals else None
    # the same objects only, to compare gt with recognition on equal terms
    gt_objects = [
        o for o in objects if "gt" in methods and per_object[o]["gt"]["success"] is not None
    ]
    average_on_gt_objects = {
        m: float(np.mean([per_object[o][m]["success"] for o in gt_objects]))
        for m in methods
        if gt_objects
    }
    return {
        "per_object": per_object,
        "average": average,
        "gt_objects": gt_objects,
        "average_on_gt_objects": average_on_gt_objects,
    }


def print_table(summary: dict, objects: list[str], methods: tuple[str, ...]) -> None:
    head = f"{'object':<11}"
    for m in methods:
        head += f" | {m[:5]:>5} succ  plan p50/p95 (cpu) ms"
    print(head)
    print("-" * len(head))
    for o in objects:
        line = f"{o:<11}"
        for m in methods:
            r = summary["per_object"][o][m]
            if r["success"] is None:
                line += f" | {'n/a':>7}  {'':>20}"
                continue
            p50 = r["plan_ms_p50"] or float("nan")
            p95 = r["plan_ms_p95"] or float("nan")
            cpu = r["plan_cpu_ms_p50"] or float("nan")
            line += f" | {r['success'] * 100:5.0f} %  {p50:5.0f}/{p95:<5.0f} ({cpu:4.0f})"
        print(line)
    print("-" * len(head))
    line = f"{'average':<11}"
    for m in methods:
        a = summary["average"][m]
        line += (f" | {a * 100:5.1f} %" if a is not None else " |   n/a  ") + " " * 22
    print(line)
    if summary["average_on_gt_objects"]:
        line = f"{'avg gt-objs':<11}"
        for m in methods:
            line += f" | {summary['average_on_gt_objects'][m] * 100:5.1f} %" + " " * 22
        print(line + f"  (the {len(summary['gt_objects'])} objects with a true superquadric shape)")
    ref = "  ".join(
        f"{'DSQNet' if m == 'optimization' else 'MVBB'} {REFERENCE[m] * 100:.0f} %"
        for m in methods
        if m in REFERENCE
    )
    print(f"Table 3.4 (real robot): {ref}")
    for o in objects:
        for m in methods:
            r = summary["per_object"][o][m]
            fails = {k: v for k, v in r["outcomes"].items() if k != "success"}
            if fails or r["refusals"]:
                print(f"  {o} [{m}] failures: {fails}; simulator refusals: {r['refusals']}")


def main(argv: list[str] | None = None) -> int:
    import torch

    catalog = list(object_catalog())
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=10, help="trials per object (default 10)")
    ap.add_argument("--objects", nargs="+", default=catalog, choices=catalog, metavar="NAME")
    ap.add_argument("--quick", action="store_true", help="3 trials per object")
    ap.add_argument("--workers", type=int, default=1, help="processes, one simulator each")
    ap.add_argument("--camera", default="overview", choices=("overview", "wrist"))
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--labels", action="store_true", help="give recognition the true labels")
    ap.add_argument("--chunk-size", type=int, default=32, help="planner feasibility chunk")
    ap.add_argument(
        "--score",
        default="top_down",
        choices=("top_down", "uncertainty"),
        help="grasp score (3.4.2), or uncertainty-aware with the target's observed points (3.6.3)",
    )
    ap.add_argument(
        "--threads", type=int, default=0, help="torch threads per worker (0: cores / workers)"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    args.methods = tuple(args.methods)
    trials = 3 if args.quick else args.trials
    threads = args.threads or max(1, (os.cpu_count() or 1) // max(args.workers, 1))
    print(
        "command:", " ".join([sys.executable, "-m", "benchmarks.grasping", *(argv or sys.argv[1:])])
    )
    print(
        f"machine: {platform.processor() or platform.machine()}, cores={os.cpu_count()}, "
        f"torch threads/worker={threads}, workers={args.workers}, python {platform.python_version()}"
    )
    print(f"objects={args.objects} trials={trials} methods={args.methods} camera={args.camera}")
    jobs = [(o, t) for t in range(trials) for o in args.objects]
    records: list[dict] = []
    t0 = time.perf_counter()
    from tqdm import tqdm

    bar = tqdm(total=len(jobs), desc="trials", file=sys.stderr)
    if args.workers <= 1:
        _worker_init(threads)
        partial = args.out.with_suffix(".partial.jsonl")
        partial.parent.mkdir(parents=True, exist_ok=True)
        partial.write_text("")
        for o, t in jobs:
            records.append(run_trial(o, t, args.seed, args))
            with partial.open("a") as f:  # progress, readable while the run goes on
                f.write(json.dumps(records[-1]) + "\n")
            bar.update()
        partial.unlink()
    else:
        with ProcessPoolExecutor(args.workers, initializer=_worker_init, initargs=(threads,)) as ex:
            futs = [ex.submit(run_trial, o, t, args.seed, args) for o, t in jobs]
            for f in as_completed(futs):
                records.append(f.result())
                bar.update()
    bar.close()
    wall = time.perf_counter() - t0
    records.sort(key=lambda r: (args.objects.index(r["object"]), r["trial"]))
    summary = summarize(records, args.objects, args.methods)
    print_table(summary, args.objects, args.methods)
    print(f"wall time {wall:.0f} s for {len(jobs)} trials; load average {os.getloadavg()}")
    print("plan ms: wall-clock p50/p95, (cpu) = process CPU time p50 (independent of other load)")
    result = {
        "command": " ".join(["python", "-m", "benchmarks.grasping", *(argv or sys.argv[1:])]),
        "machine": {
            "cores": os.cpu_count(),
            "torch_threads_per_worker": threads,
            "workers": args.workers,
            "torch": torch.__version__,
            "python": platform.python_version(),
        },
        "config": {
            "objects": args.objects,
            "trials": trials,
            "camera": args.camera,
            "labels": args.labels,
            "methods": list(args.methods),
            "score": args.score,
            "approach_distance": APPROACH,
            "gripper": "PANDA_HAND_URDF",
            "max_attempts": MAX_ATTEMPTS,
            "seed": args.seed,
        },
        "reference_table_3_4": REFERENCE,
        "summary": summary,
        "wall_s": wall,
        "trials": records,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
