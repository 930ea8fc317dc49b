"""The ``sqmanip`` command line: one command, sub-commands with ``--help``.

``up`` starts the stack; ``sim`` drives a running simulator; ``data`` generates datasets;
``train`` trains the learned models; ``bench`` runs a benchmark script from ``benchmarks/``.
"""

from __future__ import annotations

import argparse
import runpy
import sys
from pathlib import Path

BENCHMARKS_DIR = Path(__file__).resolve().parents[2] / "benchmarks"


def _add_group(subparsers, name: str, help: str, dest: str) -> argparse._SubParsersAction:
    parser = subparsers.add_parser(name, help=help, description=help)
    return parser.add_subparsers(dest=dest, metavar=dest.upper(), required=True)


def _run_bench(args: argparse.Namespace) -> int:
    """Run ``python -m benchmarks.<name>`` with the remaining arguments."""
    if not (BENCHMARKS_DIR / f"{args.name}.py").exists():
        available = sorted(p.stem for p in BENCHMARKS_DIR.glob("*.py") if p.stem != "__init__")
        print(f"sqmanip bench: unknown benchmark {args.name!r}; available: {available}")
        return 2
    sys.path.insert(0, str(BENCHMARKS_DIR.parent))
    sys.argv = [f"benchmarks.{args.name}", *args.args]
    runpy.run_module(f"benchmarks.{args.name}", run_name="__main__")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sqmanip",
        description="SQManip: superquadric recognition, grasping, pushing and shelf search.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    from sqmanip import launch
    from sqmanip.dynamics import generate as pushing_data
    from sqmanip.dynamics import train as dynamics_train
    from sqmanip.perception.learned import datasets as recognition_data
    from sqmanip.perception.learned import train as recognition_train
    from sqmanip.sim.cli import add_cli as add_sim_cli

    launch.add_parser(subparsers)
    add_sim_cli(subparsers)

    data = _add_group(subparsers, "data", "generate a training dataset", "dataset")
    recognition_data.add_cli(data)
    pushing_data.add_cli(data)

    train = _add_group(subparsers, "train", "train a learned model", "model")
    recognition_train.add_cli(train)
    dynamics_train.add_cli(train)

    bench = subparsers.add_parser(
        "bench",
        help="run a benchmark (python -m benchmarks.NAME)",
        description="Run benchmarks/NAME.py; arguments after NAME go to the script "
        "(e.g. `sqmanip bench geometry --quick`).",
    )
    bench.add_argument("name", help="benchmark name, e.g. geometry, recognition, sim")
    bench.add_argument("args", nargs=argparse.REMAINDER, help="arguments for the script")
    bench.set_defaults(func=_run_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
