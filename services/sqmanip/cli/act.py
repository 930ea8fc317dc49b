"""``sqmanip predict``, ``sqmanip plan`` and ``sqmanip search``: pushing dynamics (Ch. 4), one
pushing-MPC step or a closed-loop episode (4.4), and the shelf search-for-grasp episode (Ch. 5),
all through the gateway (the SDK).

Objects come from a recognized scene (``--scene-json``, the output of ``sqmanip recognize``) or
from the simulator's current state (``--sim``: the spawned objects' superquadrics).
Episodes run in the gateway's background; the command follows them with a progress bar and
prints one line per step.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from . import common
from .common import CLIError, fmt_vec, parser_kwargs, table

PREDICT_EXAMPLES = """
  sqmanip predict --sim --push 0.45,0.0,0.03,0.0,0.08,0.0
  sqmanip predict --scene-json shapes.json --push 0.4,-0.1,0.03,0.05,0,0 --push 0.4,0,0.03,0,0.05,0
  sqmanip predict --sim --push 0.45,0,0.03,0,0.08,0 --model physics --json"""

PLAN_EXAMPLES = """
  sqmanip plan --sim --task singulation
  sqmanip plan --scene-json shapes.json --task moving --goal 0:0.5,0.1,0.03 --goal 1:0.5,-0.1,0.03
  sqmanip plan --sim --task grasping --target 2 --num-sequences 50 --execute
  sqmanip plan --episode moving --index 0 --seed 3       # closed loop in the simulator"""

SEARCH_EXAMPLES = """
  sqmanip search                                   # 2 occluders, seed 0, oracle shapes
  sqmanip search --n-objects 4 --seed 7 --shapes recognized --max-steps 8
  sqmanip search --method search_and_grasp --json > episode.json"""

EPISODE_KINDS = (
    "moving",
    "singulation",
    "grasping_clutter",
    "grasping_large",
    "interactive_moving",
)


def _source(p: argparse.ArgumentParser, required: bool = True) -> None:
    src = p.add_mutually_exclusive_group(required=required)
    src.add_argument(
        "--scene-json",
        type=Path,
        metavar="JSON",
        help="recognized scene (sqmanip recognize --json / --out shapes.json)",
    )
    src.add_argument(
        "--sim", action="store_true", help="the simulator's current objects (their superquadrics)"
    )


def add_predict(subparsers) -> None:
    p = subparsers.add_parser(
        "predict",
        help="predict object poses after pushes (SQPD-Net or physics)",
        **parser_kwargs(
            "Predict where every object goes under each push (start point p and displacement "
            "v, world frame, m; Ch. 4.3) with the gateway's /predict. Each object must have one "
            "superquadric part.",
            PREDICT_EXAMPLES,
        ),
    )
    _source(p)
    p.add_argument(
        "--push",
        action="append",
        required=True,
        metavar="PX,PY,PZ,VX,VY,VZ",
        help="a push (repeatable; all are predicted in one call)",
    )
    p.add_argument("--model", default="sqpdnet", help="sqpdnet | physics | a checkpoint name")
    p.add_argument("--json", action="store_true", help="print the predicted poses as JSON")
    common.add_gateway_args(p)
    p.set_defaults(func=cmd_predict)


def add_plan(subparsers) -> None:
    p = subparsers.add_parser(
        "plan",
        help="one pushing-MPC step, or a closed-loop pushing episode",
        **parser_kwargs(
            "One step of the sampling-based pushing MPC (4.4) with the gateway's /plan: the push "
            "to execute now for a task (moving, singulation, grasping, interactive_moving), its "
            "cost and the predicted poses. --execute runs it in the simulator (--sim). "
            "--episode runs a generated scenario closed-loop in the simulator instead.",
            PLAN_EXAMPLES,
        ),
    )
    _source(p, required=False)
    t = p.add_argument_group("task")
    t.add_argument(
        "--task",
        choices=("moving", "singulation", "grasping", "interactive_moving"),
        default=None,
        help="the pushing task",
    )
    t.add_argument(
        "--goal",
        action="append",
        default=[],
        metavar="[ID:]X,Y,Z",
        help="moving: ID:x,y,z per object (repeatable); interactive_moving: x,y,z",
    )
    t.add_argument("--target", type=int, default=None, help="grasping / interactive_moving")
    t.add_argument("--tau", type=float, default=None, help="singulation distance (m; 0.20)")
    m = p.add_argument_group("MPC")
    m.add_argument("--num-sequences", type=int, default=None, help="sampled sequences K (100)")
    m.add_argument("--horizon", type=int, default=None, help="pushes per sequence (1; 3 grasping)")
    m.add_argument("--seed", type=int, default=None, help="sampling seed")
    m.add_argument("--dynamics-model", default=None, help="sqpdnet (default) | physics")
    p.add_argument("--execute", action="store_true", help="--sim: execute the push in the sim")
    e = p.add_argument_group("episode")
    e.add_argument(
        "--episode",
        choices=EPISODE_KINDS,
        default=None,
        help="run a generated scenario closed-loop (no --scene-json/--sim)",
    )
    e.add_argument("--index", type=int, default=0, help="scenario index (0)")
    e.add_argument("--max-steps", type=int, default=None, help="episode step limit")
    e.add_argument(
        "--ground-truth",
        action="store_true",
        help="plan on ground-truth shapes instead of recognized ones",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    common.add_gateway_args(p, timeout=300.0)
    p.set_defaults(func=cmd_plan)


def add_search(subparsers) -> None:
    p = subparsers.add_parser(
        "search",
        help="run a shelf search-for-grasp episode and follow it",
        **parser_kwargs(
            "Start a shelf search episode in the simulator (Ch. 5: find a hidden target behind "
            "occluders by pushing and pick-and-place, then grasp it) and follow it step by step "
            "with a progress bar until it ends; prints the result.",
            SEARCH_EXAMPLES,
        ),
    )
    p.add_argument(
        "--scenario",
        type=Path,
        default=None,
        help="a ShelfScenario JSON (an earlier result's 'scenario')",
    )
    p.add_argument("--n-objects", type=int, default=2, help="occluders when generating (2)")
    p.add_argument("--seed", type=int, default=0, help="scenario seed (0)")
    p.add_argument(
        "--method",
        choices=("search_for_grasp", "search_and_grasp"),
        default="search_for_grasp",
        help="search for a pose where the target is graspable, or search first, then grasp",
    )
    p.add_argument(
        "--shapes",
        choices=("oracle", "recognized"),
        default="oracle",
        help="occluder shapes: ground truth or recognized from the camera (oracle)",
    )
    p.add_argument(
        "--actions",
        choices=("both", "push", "pick_and_place"),
        default="both",
        help="actions the planner may use (both)",
    )
    p.add_argument("--dynamics-model", default="kinematic", help="kinematic | a dynamics model")
    p.add_argument("--max-steps", type=int, default=None, help="step limit (10)")
    p.add_argument("--num-sequences", type=int, default=None, help="MPC sequences per step")
    p.add_argument("--plan-seed", type=int, default=0, help="MPC sampling seed (0)")
    p.add_argument("--poll", type=float, default=0.5, help="seconds between status polls (0.5)")
    p.add_argument("--json", action="store_true", help="print the final episode as JSON")
    p.add_argument("--out", type=Path, default=None, help="write the final episode JSON here")
    common.add_gateway_args(p)
    p.set_defaults(func=cmd_search)


# --- objects --------------------------------------------------------------------------------------


def _objects(args, c) -> list[tuple[int, Any]]:
    """``(id, SuperquadricPart list)`` of the chosen source."""
    if args.scene_json is not None:
        scene = common.load_scene_json(args.scene_json)
        if not scene.objects:
            raise CLIError(f"{args.scene_json}: the scene has no objects")
        return [(o.id, list(o.parts)) for o in scene.objects]
    state = c.sim_state()
    objs = [(o.id, [o.superquadric]) for o in state.objects if o.superquadric is not None]
    if not objs:
        raise CLIError(
            "the simulator has no objects with a superquadric (reset it first: "
            "sqmanip sim reset --seed 0)"
        )
    return objs


def _push(text: str) -> list[float]:
    return common.floats(text, 6, "--push")


# --- commands -------------------------------------------------------------------------------------


def cmd_predict(args) -> int:
    pushes = [_push(t) for t in args.push]
    with common.client(args) as c:
        objs = _objects(args, c)
        for oid, parts in objs:
            if len(parts) != 1:
                raise CLIError(
                    f"object {oid} has {len(parts)} parts; the dynamics model takes "
                    "one part per object"
                )
        result = c.predict([parts[0] for _, parts in objs], pushes, model=args.model)
    ids = [oid for oid, _ in objs]
    if args.json:
        out = {
            "model": result.model,
            "latency_ms": result.latency_ms,
            "ids": ids,
            "pushes": pushes,
            "poses": result.poses.tolist(),
            "failed": None if result.failed is None else result.failed.tolist(),
        }
        json.dump(out, sys.stdout, indent=1)
        print()
        return 0
    print(
        f"model {result.model}, {len(pushes)} push(es) x {len(ids)} object(s), "
        f"{result.latency_ms:.0f} ms"
    )
    import numpy as np

    before = {oid: parts[0].pose.matrix() for oid, parts in objs}
    for k, push in enumerate(pushes):
        failed = result.failed is not None and bool(result.failed[k])
        print(
            f"push {k}: p = {fmt_vec(push[:3])}, v = {fmt_vec(push[3:])}"
            + ("  (not executable)" if failed else "")
        )
        rows = []
        for i, oid in enumerate(ids):
            T0, T1 = before[oid], result.poses[k, i]
            d = T1[:3, 3] - T0[:3, 3]
            dyaw = np.degrees(np.arctan2(T1[1, 0], T1[0, 0]) - np.arctan2(T0[1, 0], T0[0, 0]))
            dyaw = (dyaw + 180.0) % 360.0 - 180.0
            rows.append(
                [
                    oid,
                    f"{T1[0, 3]:.3f}",
                    f"{T1[1, 3]:.3f}",
                    f"{T1[2, 3]:.3f}",
                    f"{np.linalg.norm(d) * 1000:.1f}",
                    f"{dyaw:.1f}",
                ]
            )
        print(table(["id", "x", "y", "z", "moved mm", "yaw change deg"], rows))
    return 0


def _task(args) -> dict[str, Any]:
    kind = args.task
    if kind is None:
        raise CLIError("--task: required (moving, singulation, grasping, interactive_moving)", 2)
    if kind == "moving":
        if not args.goal:
            raise CLIError("--goal ID:x,y,z: at least one is required for --task moving", 2)
        goals = dict(common.id_and_floats(g, 3, "--goal") for g in args.goal)
        return {"kind": "moving", "goals": goals}
    if kind == "singulation":
        return {"kind": "singulation"} if args.tau is None else {"kind": kind, "tau": args.tau}
    if args.target is None:
        raise CLIError(f"--target: required for --task {kind}", 2)
    if kind == "grasping":
        return {"kind": kind, "target_id": args.target}
    if len(args.goal) != 1 or ":" in args.goal[0]:
        raise CLIError("--goal x,y,z: one goal position is required for interactive_moving", 2)
    return {
        "kind": kind,
        "target_id": args.target,
        "goal": common.floats(args.goal[0], 3, "--goal"),
    }


def cmd_plan(args) -> int:
    if args.episode is not None:
        if args.scene_json is not None or args.sim or args.task is not None:
            raise CLIError("--episode runs a generated scenario: drop --scene-json/--sim/--task", 2)
        return _plan_episode(args)
    if args.scene_json is None and not args.sim:
        raise CLIError("give the objects: --scene-json JSON or --sim (or --episode KIND)", 2)
    if args.execute and not args.sim:
        raise CLIError("--execute needs --sim (the push runs in the simulator)", 2)
    task = _task(args)
    options = {
        "num_sequences": args.num_sequences,
        "horizon": args.horizon,
        "seed": args.seed,
        "dynamics_model": args.dynamics_model,
    }
    options = {k: v for k, v in options.items() if v is not None}
    with common.client(args) as c:
        objs = _objects(args, c)
        plan = c.plan([(parts, oid) for oid, parts in objs], task, **options)
        executed = None
        if args.execute and plan.action is not None:
            executed = c.sim_push(plan.action[:3], plan.action[3:])
    if args.json:
        from sqmanip_client.sim import pose_json

        out = {
            "action": None if plan.action is None else plan.action.tolist(),
            "pushed_id": plan.pushed_id,
            "cost": plan.cost,
            "current_cost": plan.current_cost,
            "solved": plan.solved,
            "predicted_next": {str(k): pose_json(v) for k, v in plan.predicted_next.items()},
            "num_candidates": plan.num_candidates,
            "timings_ms": plan.timings_ms,
            "dynamics_model": plan.dynamics_model,
            "executed": None
            if executed is None
            else {"success": executed.success, "message": executed.message},
        }
        json.dump(out, sys.stdout, indent=1)
        print()
        return 0
    total = plan.timings_ms.get("total", sum(plan.timings_ms.values()))
    print(
        f"task {task['kind']}: {plan.num_candidates} admissible of {plan.num_sampled} sampled "
        f"sequences ({plan.dynamics_model}), {total:.0f} ms"
    )
    if plan.action is None:
        print("no admissible push (every sampled start point is blocked or out of the workspace)")
        return 0
    cost = "-" if plan.cost is None else f"{plan.cost:.4g}"
    now = "-" if plan.current_cost is None else f"{plan.current_cost:.4g}"
    print(
        f"push object {plan.pushed_id}: p = {fmt_vec(plan.action[:3])}, "
        f"v = {fmt_vec(plan.action[3:])}; cost {now} -> {cost}"
        + ("  (task solved)" if plan.solved else "")
    )
    rows = [
        [
            oid,
            f"{p.position[0]:.3f}",
            f"{p.position[1]:.3f}",
            f"{p.position[2]:.3f}",
            f"{common.yaw_deg(p):.0f}",
        ]
        for oid, p in sorted(plan.predicted_next.items())
    ]
    if rows:
        print("predicted poses after the push:")
        print(table(["id", "x", "y", "z", "yaw deg"], rows))
    if executed is not None:
        print(
            f"executed in the simulator: {'ok' if executed.success else 'failed'}"
            + (f" ({executed.message})" if executed.message else "")
        )
    return 0


def _describe_mpc(ev: dict[str, Any]) -> str:
    parts = [f"step {ev.get('step', '?'):>2}", str(ev.get("status", ""))]
    if ev.get("pushed_id") is not None:
        parts.append(f"push object {ev['pushed_id']}")
    if ev.get("cost") is not None:
        parts.append(f"cost {ev['cost']:.4f}")
    if ev.get("message") and ev.get("message") != ev.get("status"):
        parts.append(str(ev["message"]))
    return "  ".join(parts)


def _finish(args, status, summary: str) -> int:
    data = {
        "id": status.id,
        "kind": status.kind,
        "status": status.status,
        "result": status.result,
        "error": status.error,
        "elapsed_s": status.elapsed_s,
        "events": list(status.events),
    }
    if getattr(args, "out", None) is not None:
        args.out.write_text(json.dumps(data, indent=1) + "\n")
    if args.json:
        json.dump(data, sys.stdout, indent=1)
        print()
    if status.status != "done":
        err = status.error or {}
        raise CLIError(
            f"episode {status.id} {status.status}: "
            f"{err.get('detail') or err.get('code') or 'no result'}"
        )
    if not args.json:
        print(summary)
    if getattr(args, "out", None) is not None:
        print(f"wrote {args.out}", file=sys.stderr if args.json else sys.stdout)
    return 0


def _plan_episode(args) -> int:
    body: dict[str, Any] = {"objects": "ground_truth" if args.ground_truth else "recognition"}
    if args.max_steps is not None:
        body["max_steps"] = args.max_steps
    options = {
        "num_sequences": args.num_sequences,
        "horizon": args.horizon,
        "seed": args.seed,
        "dynamics_model": args.dynamics_model,
    }
    options = {k: v for k, v in options.items() if v is not None}
    if options:
        body["options"] = options
    with common.client(args) as c:
        eid = c.start_mpc_episode(args.episode, args.index, args.seed or 0, **body)
        print(f"started {args.episode} episode {eid}", file=sys.stderr)
        status = common.follow_episode(
            c.get_mpc_episode, eid, total=args.max_steps, describe=_describe_mpc, quiet=args.json
        )
    r = status.result or {}
    summary = (
        f"{'success' if r.get('success') else 'failure'} after {r.get('steps')} step(s): "
        f"{r.get('reason', '')} ({status.elapsed_s:.1f} s)"
    )
    return _finish(args, status, summary)


def _describe_search(ev: dict[str, Any]) -> str:
    flags = []
    if ev.get("visible"):
        flags.append("target visible")
    if ev.get("graspable"):
        flags.append("graspable")
    if ev.get("executed"):
        flags.append("executed")
    line = (
        f"step {ev.get('step', '?'):>2}  {ev.get('action', ''):<14} "
        f"f {ev.get('f_sum', 0.0):8.3f}  f*g {ev.get('fg_sum', 0.0):8.3f}"
    )
    if flags:
        line += "  " + ", ".join(flags)
    if ev.get("message"):
        line += f"  ({ev['message']})"
    return line


def cmd_search(args) -> int:
    body: dict[str, Any] = {
        "n_objects": args.n_objects,
        "seed": args.seed,
        "method": args.method,
        "shapes": args.shapes,
        "actions": args.actions,
        "dynamics_model": args.dynamics_model,
        "plan_seed": args.plan_seed,
    }
    if args.max_steps is not None:
        body["max_steps"] = args.max_steps
    if args.num_sequences is not None:
        body["num_sequences"] = args.num_sequences
    scenario = None
    if args.scenario is not None:
        try:
            scenario = json.loads(args.scenario.read_text())
        except json.JSONDecodeError as exc:
            raise CLIError(f"{args.scenario}: not valid JSON ({exc})") from None
        if isinstance(scenario, dict) and "result" in scenario:  # a saved episode
            scenario = (scenario.get("result") or {}).get("scenario") or scenario
    if args.out is not None and not args.out.parent.exists():
        raise CLIError(f"--out {args.out}: directory {args.out.parent} does not exist")
    with common.client(args) as c:
        eid = c.start_search_episode(scenario, **body)
        print(f"started search episode {eid}", file=sys.stderr)
        status = common.follow_episode(
            c.get_search_episode,
            eid,
            total=args.max_steps or 10,
            describe=_describe_search,
            poll_s=args.poll,
            quiet=args.json,
        )
    r = status.result or {}
    found = f"found at step {r.get('find_steps')}" if r.get("found") else "target not found"
    grasped = "grasped" if r.get("grasped") else "not grasped"
    summary = (
        f"{found}, {grasped}; {r.get('steps')} step(s): {r.get('reason', '')} "
        f"({status.elapsed_s:.1f} s)"
    )
    return _finish(args, status, summary)
