"""``sqmanip sim reset|observe``: drive a running Simulator service from the shell (gRPC).

Examples (the service from ``sqmanip up``, or ``python -m sqmanip.sim.server``)::

    sqmanip sim reset --seed 7 --n-objects 4 --save scene.json
    sqmanip sim reset --scene scene.json          # replay a saved scene
    sqmanip sim observe --width 320 --height 288 --out frame.npz
    sqmanip sim observe --out frame.ply            # colored cloud for `sqmanip recognize`

``--address`` defaults to the stack's sim address (``SQMANIP_SIM_PORT``, ``SQMANIP_HOST``).
The ``.npz`` holds depth, rgb, segmentation, points, point_labels, point_pixels, camera_pose and
camera_matrix (the same arrays as ``POST /sim/observe?format=npz``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from sqmanip.errors import SQManipError


def add_cli(subparsers) -> None:
    """Register ``sqmanip sim`` and its sub-commands on the CLI's sub-parsers."""
    sim = subparsers.add_parser(
        "sim",
        help="reset / observe the simulator service",
        description="Talk to a running Simulator service over gRPC.",
    )
    sub = sim.add_subparsers(dest="sim_command", metavar="SIM_COMMAND", required=True)

    reset = sub.add_parser("reset", help="reset to a random (seeded) or saved scene")
    source = reset.add_mutually_exclusive_group(required=True)
    source.add_argument("--seed", type=int, help="sample a random scene from this seed")
    source.add_argument("--scene", type=Path, help="replay a scene JSON (from --save)")
    reset.add_argument("--n-objects", type=int, default=None, help="random scene: objects (4)")
    reset.add_argument("--kind", choices=("tabletop", "shelf"), default="tabletop")
    reset.add_argument(
        "--object-kinds", default=None, help="comma-separated: box,cylinder,superquadric"
    )
    reset.add_argument("--save", type=Path, help="write the scene as built to this JSON file")
    _common(reset)
    reset.set_defaults(func=cmd_reset)

    observe = sub.add_parser("observe", help="render one frame; print a summary, save arrays")
    observe.add_argument("--camera", default="default", help="default|wrist|shelf|overview")
    observe.add_argument("--width", type=int, default=None, help="image width (px; 640)")
    observe.add_argument("--height", type=int, default=None, help="image height (px; 576)")
    observe.add_argument("--no-noise", action="store_true", help="no point-cloud noise")
    observe.add_argument(
        "--keep-robot",
        action="store_true",
        help=".ply/.npy: keep the robot's own points (dropped by default)",
    )
    observe.add_argument(
        "--out",
        type=Path,
        help="write the arrays to this .npz file, or the colored cloud to a .ply / .npy file "
        "(ready for `sqmanip recognize`)",
    )
    _common(observe)
    observe.set_defaults(func=cmd_observe)


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--address", default=None, help="sim service host:port")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds per call (60)")


def _remote(args):
    from sqmanip.rpc.client import RemoteSimulator
    from sqmanip.settings import get_settings

    settings = get_settings()
    return RemoteSimulator(args.address or settings.address("sim"), settings, timeout=args.timeout)


def _print_objects(objects) -> None:
    print(f"{'id':>3}  {'kind':<12} {'x':>8} {'y':>8} {'z':>8}  name")
    for o in objects:
        x, y, z = o.position
        print(f"{o.id:>3}  {o.kind:<12} {x:8.4f} {y:8.4f} {z:8.4f}  {o.name}")


def cmd_reset(args) -> int:
    try:
        scene = None
        if args.scene is not None:
            scene = json.loads(args.scene.read_text())
        kinds = tuple(k.strip() for k in (args.object_kinds or "").split(",") if k.strip())
        with _remote(args) as sim:
            state = sim.reset(
                scene,
                seed=args.seed,
                n_objects=args.n_objects if scene is None else None,
                kind=args.kind if scene is None else "",
                object_kinds=kinds if scene is None else (),
            )
            spec = sim.scene_spec
    except (SQManipError, OSError, json.JSONDecodeError) as exc:
        print(f"error: sim reset: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    print(f"{state.scene_kind} scene, {len(state.objects)} objects (seed {spec.seed}):")
    _print_objects(state.objects)
    if args.save is not None:
        args.save.write_text(json.dumps(spec.to_dict(), indent=1) + "\n")
        print(f"scene written to {args.save}")
    return 0


def cmd_observe(args) -> int:
    from sqmanip.sim.camera import Intrinsics

    try:
        k = None
        if args.width is not None or args.height is not None:
            base = Intrinsics()
            k = Intrinsics.scaled(args.width or base.width, args.height or base.height)
        suffix = "" if args.out is None else args.out.suffix.lower()
        if args.out is not None and suffix not in (".npz", ".ply", ".npy"):
            raise SQManipError(f"--out {args.out}: expected a .npz, .ply or .npy file name")
        with _remote(args) as sim:
            obs = sim.observe(args.camera, intrinsics=k, noise=not args.no_noise)
        if suffix in (".ply", ".npy"):
            from sqmanip.io.clouds import write_cloud
            from sqmanip.sim.config import LABEL_ROBOT

            rgb = np.asarray(obs.rgb).reshape(-1, 3)
            colors = rgb[np.asarray(obs.point_pixels, dtype=np.int64)] / 255.0
            keep = np.ones(len(obs.points), dtype=bool)
            if not args.keep_robot:
                keep = np.asarray(obs.point_labels) != LABEL_ROBOT
            viewpoint = np.asarray(obs.camera_pose)[:3, 3]
            write_cloud(args.out, obs.points[keep], colors[keep], viewpoint)
        elif args.out is not None:
            np.savez(
                args.out,
                depth=obs.depth,
                rgb=obs.rgb,
                segmentation=obs.segmentation,
                points=obs.points.astype(np.float32),
                point_labels=obs.point_labels,
                point_pixels=obs.point_pixels.astype(np.int32),
                camera_pose=obs.camera_pose,
                camera_matrix=obs.intrinsics.matrix(),
            )
    except (SQManipError, OSError) as exc:
        print(f"error: sim observe: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    h, w = obs.depth.shape
    labels, counts = np.unique(obs.point_labels, return_counts=True)
    per_label = ", ".join(f"{int(lab)}: {int(c)}" for lab, c in zip(labels, counts, strict=True))
    print(f"camera {obs.camera}, {w} x {h} px, t = {obs.time:.3f} s")
    print(f"{obs.points.shape[0]} points (per label {{{per_label}}})")
    _print_objects(obs.objects)
    if args.out is not None:
        what = "arrays" if args.out.suffix.lower() == ".npz" else "point cloud"
        print(f"{what} written to {args.out}")
    return 0
