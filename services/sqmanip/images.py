"""``sqmanip images build``: build the container images with no image registry (issue 11).

The work is done by ``compose/build.sh`` in the repository (a shell script, so that CI and
people without the Python environment can run it too): a Debian bookworm base image from
debootstrap + ``docker import``, a wheelhouse from the host (``pip download``, torch pinned to
the CPU build) and the application image from ``compose/Dockerfile``; each stage is skipped when
its output is up to date. This module only finds the script and runs it (light imports: the CLI
must start fast).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def build_script() -> Path:
    """``compose/build.sh`` of the source checkout this package runs from.

    Raises ``FileNotFoundError`` naming the looked-up path when the package is not run from a
    checkout (e.g. inside the image itself, where there is nothing to build).
    """
    script = Path(__file__).resolve().parents[2] / "compose" / "build.sh"
    if not script.is_file():
        raise FileNotFoundError(
            f"compose/build.sh not found at {script}: `sqmanip images build` needs the source "
            "checkout (pip install -e .)"
        )
    return script


def build_command(args) -> list[str]:
    """The ``bash compose/build.sh ...`` command line for the parsed CLI ``args``."""
    cmd = ["bash", str(build_script())]
    if args.force_base:
        cmd.append("--force-base")
    if args.force_wheels:
        cmd.append("--force-wheels")
    if args.no_cache:
        cmd.append("--no-cache")
    return cmd


def cmd_build(args) -> int:
    try:
        cmd = build_command(args)
    except FileNotFoundError as exc:
        print(f"sqmanip images build: {exc}", file=sys.stderr)
        return 2
    env = dict(os.environ)
    env.setdefault("PYTHON", sys.executable)  # the wheelhouse matches this interpreter
    if args.image:
        env["SQMANIP_IMAGE"] = args.image
    return subprocess.call(cmd, env=env)


def add_parser(subparsers) -> None:
    """Register ``sqmanip images build`` on the CLI's sub-parsers."""
    p = subparsers.add_parser(
        "images",
        help="build the container images (base, wheelhouse, app) offline",
        description="Container images for docker compose (compose/docker-compose.yml).",
    )
    sub = p.add_subparsers(dest="images_command", required=True)
    b = sub.add_parser(
        "build",
        help="run compose/build.sh: base image, wheelhouse, app image (cached stages reused)",
        description=__doc__.split("\n\n")[1],
    )
    b.add_argument("--force-base", action="store_true", help="re-create the base image")
    b.add_argument("--force-wheels", action="store_true", help="re-download the wheelhouse")
    b.add_argument("--no-cache", action="store_true", help="docker build --no-cache")
    b.add_argument("--image", default=None, help="app image tag (default sqmanip:latest)")
    b.set_defaults(func=cmd_build)
