"""``sqmanip recognize`` and ``sqmanip grasp``: point-cloud files in, superquadrics and ranked
grasps out, through the gateway (the SDK, :mod:`sqmanip_client`).

Clouds: PLY (ascii / binary), NPY ``(N, 3)`` or ``(N, 6)`` with colors, or the NPZ of
``sqmanip sim observe`` (:mod:`sqmanip.io.clouds`). Shapes out: the ``/recognize`` JSON (read
back by ``--scene-json``), OBJ (one group per part, one object per recognized object) or PLY
meshes (:mod:`sqmanip.io.meshes`, surfaces from the geometry core, Ch. 2.2-2.3).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from . import common
from .common import CLIError, fmt_vec, parser_kwargs, table

METHODS = ("optimization", "network", "hybrid", "mvbb")

RECOGNIZE_EXAMPLES = """
  sqmanip recognize cloud.ply                        # table of objects and parts
  sqmanip recognize cloud.npy --json > shapes.json   # the /recognize JSON
  sqmanip recognize frame.npz --out shapes.obj --out shapes.json --view
  sqmanip recognize cloud.ply --method mvbb --viewpoint 0.5,0,0.8 --out parts.ply --split
  SQMANIP_GATEWAY_URL=http://robot:8080 sqmanip recognize cloud.ply"""

GRASP_EXAMPLES = """
  sqmanip grasp cloud.ply                            # recognize, then grasps on every object
  sqmanip grasp --scene-json shapes.json --target 2 --top 10
  sqmanip grasp cloud.ply --method rule_based --score uncertainty --json > grasps.json"""


def _recognize_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("recognition")
    g.add_argument(
        "--method",
        choices=METHODS,
        default=None,
        help="fitting method (service default: optimization)",
    )
    g.add_argument(
        "--segmentation",
        choices=("clustering", "network"),
        default=None,
        help="how the cloud is split into objects (clustering)",
    )
    g.add_argument(
        "--viewpoint",
        metavar="X,Y,Z",
        default=None,
        help="sensor origin (m, world frame) for hidden-side completion (default: the one "
        "the file records, e.g. from sqmanip sim observe)",
    )
    g.add_argument(
        "--workspace",
        metavar="X0,Y0,Z0,X1,Y1,Z1",
        default=None,
        help="crop box (m): points outside are ignored",
    )
    g.add_argument(
        "--keep-support", action="store_true", help="do not find and remove the support plane"
    )
    g.add_argument("--no-amodal", action="store_true", help="no hidden-side completion")
    g.add_argument("--rigid", action="store_true", help="no taper/bend (plain superquadrics)")
    g.add_argument("--seed", type=int, default=None, help="fitting seed (0)")
    g.add_argument(
        "--no-colors",
        action="store_true",
        help="do not send the file's colors (faster binary upload)",
    )


def add_recognize(subparsers) -> None:
    p = subparsers.add_parser(
        "recognize",
        help="recognize superquadrics in a PLY/NPY point cloud (via the gateway)",
        **parser_kwargs(
            "Send a point cloud (world frame, metres) to the gateway's /recognize and print the "
            "recognized objects and their superquadric parts (kind, size a1 a2 a3, shape e1 e2, "
            "position, yaw). --out writes the shapes as JSON, OBJ or PLY meshes.",
            RECOGNIZE_EXAMPLES,
        ),
    )
    p.add_argument("file", type=Path, help="point cloud: .ply, .npy (N x 3 or N x 6) or .npz")
    _recognize_options(p)
    o = p.add_argument_group("output")
    o.add_argument("--json", action="store_true", help="print the scene as JSON (stdout)")
    o.add_argument(
        "--out",
        type=Path,
        action="append",
        default=[],
        metavar="PATH",
        help="write shapes.json | shapes.obj | shapes.ply (repeatable)",
    )
    o.add_argument(
        "--resolution", type=int, default=24, help="mesh cells per cube edge / ring count (24)"
    )
    o.add_argument(
        "--split", action="store_true", help="one mesh file per part (<stem>_<id>_<part>.obj|.ply)"
    )
    o.add_argument("--view", action="store_true", help="print (and open) the viewer URL")
    common.add_gateway_args(p)
    p.set_defaults(func=cmd_recognize)


def add_grasp(subparsers) -> None:
    p = subparsers.add_parser(
        "grasp",
        help="plan ranked grasps on a cloud or a recognized scene",
        **parser_kwargs(
            "Plan parallel-jaw grasps (Franka hand) with the gateway's /grasps: on a point "
            "cloud (recognized first) or on the shapes of `sqmanip recognize --out shapes.json`. "
            "Prints the best grasps per object: score, width, position, approach direction.",
            GRASP_EXAMPLES,
        ),
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("file", type=Path, nargs="?", help="point cloud: .ply, .npy or .npz")
    src.add_argument(
        "--scene-json",
        type=Path,
        metavar="JSON",
        help="recognized scene (recognize --json / --out shapes.json)",
    )
    _recognize_options(p)
    g = p.add_argument_group("grasping")
    g.add_argument("--target", type=int, default=None, help="object id (default: every object)")
    g.add_argument("--top", type=int, default=5, help="grasps printed per object (5)")
    g.add_argument("--max-results", type=int, default=None, help="grasps planned per object (20)")
    g.add_argument(
        "--grasp-method",
        choices=("antipodal", "rule_based"),
        default=None,
        help="candidate generator (antipodal)",
    )
    g.add_argument(
        "--score", choices=("top_down", "uncertainty"), default=None, help="ranking (top_down)"
    )
    g.add_argument("--samples", type=int, default=None, help="surface samples (256)")
    g.add_argument(
        "--no-reachability",
        action="store_true",
        help="skip the Panda IK check (gripper collisions only)",
    )
    o = p.add_argument_group("output")
    o.add_argument("--json", action="store_true", help="print the grasps as JSON (stdout)")
    o.add_argument("--out", type=Path, default=None, help="write the grasps to this JSON file")
    common.add_gateway_args(p)
    p.set_defaults(func=cmd_grasp)


# --- helpers --------------------------------------------------------------------------------------


def _read(args) -> Any:
    from sqmanip.io.clouds import read_cloud

    return read_cloud(args.file)


def _recognize_kwargs(args, cloud=None) -> tuple[dict[str, Any], dict[str, Any]]:
    """(viewpoint/workspace keywords, recognition options) of the SDK call. The viewpoint is
    ``--viewpoint``, else the one the file records (``sqmanip sim observe`` writes it)."""
    kw: dict[str, Any] = {}
    if args.viewpoint:
        kw["viewpoint"] = common.floats(args.viewpoint, 3, "--viewpoint")
    elif cloud is not None and cloud.viewpoint is not None:
        kw["viewpoint"] = [float(v) for v in cloud.viewpoint]
    if args.workspace:
        w = common.floats(args.workspace, 6, "--workspace")
        kw["workspace"] = (w[:3], w[3:])
    opts = {
        "method": args.method,
        "segmentation": args.segmentation,
        "remove_support": False if args.keep_support else None,
        "amodal": False if args.no_amodal else None,
        "deformable": False if args.rigid else None,
        "seed": args.seed,
    }
    return kw, {k: v for k, v in opts.items() if v is not None}


def _info(args, msg: str) -> None:
    """Status lines: stdout normally, stderr when stdout carries JSON."""
    print(msg, file=sys.stderr if getattr(args, "json", False) else sys.stdout)


def print_scene(scene, n_points: int | None = None) -> None:
    """Compact table: one row per part (object id, part, kind, size, shape, position, yaw)."""
    plane = scene.support_plane
    head = f"{len(scene.objects)} object(s)"
    if n_points is not None:
        head += f" from {n_points} points"
    if plane is not None:
        head += f"; support plane n = {fmt_vec(plane.normal, 2)}, d = {plane.offset:.3f} m"
    t = scene.timings_ms
    if t:
        total = t.get("total", sum(t.values()))
        stages = ", ".join(f"{k} {v:.0f}" for k, v in t.items() if k != "total")
        head += f"; {total:.0f} ms ({stages})" if stages else f"; {total:.0f} ms"
    print(head)
    rows = []
    for o in scene.objects:
        for j, p in enumerate(o.parts):
            x, y, z = p.pose.position
            rows.append(
                [
                    o.id if j == 0 else "",
                    j,
                    p.kind,
                    " ".join(f"{a:.3f}" for a in p.size),
                    f"{p.shape[0]:.2f} {p.shape[1]:.2f}",
                    f"{x:.3f}",
                    f"{y:.3f}",
                    f"{z:.3f}",
                    f"{common.yaw_deg(p.pose):.0f}",
                    len(o.point_indices) if j == 0 else "",
                    f"{o.confidence:.2f}" if j == 0 else "",
                ]
            )
    if rows:
        print(
            table(
                [
                    "id",
                    "part",
                    "kind",
                    "size a1 a2 a3 (m)",
                    "shape e1 e2",
                    "x",
                    "y",
                    "z",
                    "yaw deg",
                    "points",
                    "conf",
                ],
                rows,
            )
        )


def write_outputs(args, scene, paths: list[Path]) -> list[Path]:
    """Write the recognized shapes to each of ``paths`` (.json, .obj, .ply)."""
    from sqmanip.io.meshes import MESH_SUFFIXES

    written: list[Path] = []
    meshes = None
    for path in paths:
        suffix = path.suffix.lower()
        if suffix == ".json":
            path.write_text(json.dumps(common.scene_json(scene), indent=1) + "\n")
            written.append(path)
        elif suffix in MESH_SUFFIXES:
            if meshes is None:
                meshes = _meshes(scene, args.resolution)
            from sqmanip.io.meshes import write_meshes

            written += write_meshes(path, meshes, split=args.split)
        else:
            raise CLIError(f"--out {path}: expected a .json, .obj or .ply file name", 2)
    return written


def _meshes(scene, resolution: int):
    from sqmanip_client import to_superquadric
    from tqdm import tqdm

    from sqmanip.io.meshes import object_meshes

    objs = []
    for o in tqdm(scene.objects, desc="meshing", unit="object", disable=None, leave=False):
        objs.append((o.id, [to_superquadric(p) for p in o.parts]))
    return object_meshes(objs, resolution)


def _check_outputs(paths: list[Path]) -> None:
    """Fail before the (slow) request when an output cannot be written."""
    for path in paths:
        if path.suffix.lower() not in (".json", ".obj", ".ply"):
            raise CLIError(f"--out {path}: expected a .json, .obj or .ply file name", 2)
        if not path.parent.exists():
            raise CLIError(f"--out {path}: directory {path.parent} does not exist")


# --- commands -------------------------------------------------------------------------------------


def cmd_recognize(args) -> int:
    if args.resolution < 2:
        raise CLIError(f"--resolution: expected at least 2, got {args.resolution}", 2)
    _check_outputs(args.out)
    cloud = _read(args)
    kw, opts = _recognize_kwargs(args, cloud)
    colors = None if args.no_colors else cloud.colors
    with common.client(args) as c:
        scene = c.recognize(cloud.points, colors=colors, **kw, **opts)
        url = c.base_url
    if args.json:
        json.dump(common.scene_json(scene), sys.stdout, indent=1)
        print()
    else:
        print_scene(scene, len(cloud.points))
    for path in write_outputs(args, scene, args.out):
        _info(args, f"wrote {path}")
    if args.view:
        common.open_viewer(url)
    return 0


def grasp_json(plan) -> dict[str, Any]:
    from sqmanip_client.sim import pose_json

    return {
        "targets": [
            {
                "target_id": t.target_id,
                "grasps": [
                    {
                        "pose": pose_json(g.pose),
                        "width": g.width,
                        "score": g.score,
                        "contacts": None if g.contacts is None else g.contacts.tolist(),
                        "uncertainty": g.uncertainty,
                    }
                    for g in t.grasps
                ],
                "stats": t.stats,
            }
            for t in plan.targets
        ]
    }


def cmd_grasp(args) -> int:
    options = {
        "max_results": args.max_results,
        "method": args.grasp_method,
        "score": args.score,
        "n_samples": args.samples,
        "check_reachability": False if args.no_reachability else None,
    }
    options = {k: v for k, v in options.items() if v is not None}
    if args.top < 0:
        raise CLIError(f"--top: expected >= 0, got {args.top}", 2)
    if args.out is not None and not args.out.parent.exists():
        raise CLIError(f"--out {args.out}: directory {args.out.parent} does not exist")
    with common.client(args) as c:
        if args.scene_json is not None:
            from sqmanip_client.grasps import UNSET

            scene = common.load_scene_json(args.scene_json)
            plane = scene.support_plane if scene.support_plane is not None else UNSET
            plan = c.plan_grasps(scene, args.target, support_plane=plane, **options)
        else:
            cloud = _read(args)
            kw, ropts = _recognize_kwargs(args, cloud)
            colors = None if args.no_colors else cloud.colors
            plan = c.plan_grasps(
                None,
                args.target,
                points=cloud.points,
                colors=colors,
                recognize_options=ropts or None,
                **kw,
                **options,
            )
    data = grasp_json(plan)
    if args.out is not None:
        args.out.write_text(json.dumps(data, indent=1) + "\n")
    if args.json:
        json.dump(data, sys.stdout, indent=1)
        print()
    else:
        print_grasps(plan, args.top)
    if args.out is not None:
        _info(args, f"wrote {args.out}")
    return 0


def print_grasps(plan, top: int) -> None:
    if plan.objects is not None:
        print(f"recognized {len(plan.objects)} object(s)")
    for t in plan.targets:
        stats = t.stats or {}
        ms = stats.get("timings_ms", {})
        total = ms.get("total", sum(ms.values())) if isinstance(ms, dict) and ms else None
        counts = ", ".join(
            f"{k[2:]} {v}" for k, v in stats.items() if k.startswith("n_") and isinstance(v, int)
        )
        line = f"object {t.target_id}: {len(t.grasps)} grasp(s)"
        if counts:
            line += f" ({counts})"
        if total is not None:
            line += f", {total:.0f} ms"
        print(line)
        rows = []
        for rank, g in enumerate(t.grasps[:top]):
            T = g.pose.matrix()
            x, y, z = g.pose.position
            rows.append(
                [
                    rank + 1,
                    f"{g.score:.3f}",
                    f"{g.width * 1000:.1f}",
                    f"{x:.3f}",
                    f"{y:.3f}",
                    f"{z:.3f}",
                    fmt_vec(T[:3, 2], 2),
                ]
            )
        if rows:
            print(table(["rank", "score", "width mm", "x", "y", "z", "approach"], rows))
