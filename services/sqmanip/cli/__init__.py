"""The ``sqmanip`` command line: one command, sub-commands with ``--help`` and examples.

Sub-commands are registered lazily (:data:`COMMANDS`): ``main`` builds only the sub-parser the
command line names, so ``sqmanip --help`` and ``sqmanip recognize ...`` never import torch,
PyBullet or pinocchio unless the command needs them. :func:`build_parser` builds them all (tests).

Errors are one line on stderr, ``error: <what is wrong>``, and exit code 1 (2 for usage errors,
as argparse does): SDK errors (gateway unreachable, HTTP 4xx/5xx with the server's detail), the
stack's typed errors, ``ValueError`` and file errors. ``--debug`` / ``-v`` shows the traceback.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import re
import runpy
import sys
from collections.abc import Sequence
from pathlib import Path

from .common import CLIError, parser_kwargs

BENCHMARKS_DIR = Path(__file__).resolve().parents[3] / "benchmarks"


@dataclasses.dataclass(frozen=True)
class Command:
    """One top-level sub-command: ``adders`` are ``"module:function"`` names called with the
    sub-parsers action (a group's own sub-parsers for ``group`` commands)."""

    name: str
    help: str
    adders: tuple[str, ...]
    group: str | None = None
    """For ``data``/``train``: the dest of the group's own sub-command (dataset, model)."""


COMMANDS: tuple[Command, ...] = (
    Command("up", "start the gateway and the services as local processes",
            ("sqmanip.launch:add_parser",)),
    Command("recognize", "recognize superquadrics in a PLY/NPY point cloud (via the gateway)",
            ("sqmanip.cli.perceive:add_recognize",)),
    Command("grasp", "plan ranked grasps on a cloud or a recognized scene",
            ("sqmanip.cli.perceive:add_grasp",)),
    Command("predict", "predict object poses after pushes (SQPD-Net or physics)",
            ("sqmanip.cli.act:add_predict",)),
    Command("plan", "one pushing-MPC step, or a closed-loop pushing episode",
            ("sqmanip.cli.act:add_plan",)),
    Command("search", "run a shelf search-for-grasp episode and follow it",
            ("sqmanip.cli.act:add_search",)),
    Command("sim", "reset / observe the simulator service", ("sqmanip.sim.cli:add_cli",)),
    Command("data", "generate a training dataset",
            ("sqmanip.perception.learned.datasets:add_cli", "sqmanip.dynamics.generate:add_cli"),
            group="dataset"),
    Command("train", "train a learned model",
            ("sqmanip.perception.learned.train:add_cli", "sqmanip.dynamics.train:add_cli"),
            group="model"),
    Command("bench", "run a benchmark (python -m benchmarks.NAME)", ("sqmanip.cli:add_bench",)),
    Command("images", "build the container images (base, wheelhouse, app) offline",
            ("sqmanip.images:add_parser",)),
)  # fmt: skip

EXAMPLES: dict[tuple[str, ...], str] = {
    ("up",): """
  sqmanip up                                   # everything, ports from the settings
  sqmanip up --services perception,sim         # only these services (+ gateway, Zenoh)
  sqmanip up --port-offset 100 --log-dir logs  # a second stack beside the first""",
    ("sim",): """
  sqmanip sim reset --seed 7 --n-objects 4 --save scene.json
  sqmanip sim observe --out frame.ply          # the cloud with colors, ready for recognize""",
    ("sim", "reset"): """
  sqmanip sim reset --seed 7 --n-objects 4 --save scene.json
  sqmanip sim reset --scene scene.json         # replay a saved scene
  sqmanip sim reset --seed 3 --kind shelf --object-kinds box,cylinder""",
    ("sim", "observe"): """
  sqmanip sim observe --out frame.npz          # depth, rgb, segmentation, points, camera
  sqmanip sim observe --out frame.ply          # the point cloud (colored) only
  sqmanip sim observe --camera overview --width 320 --height 288 --no-noise""",
    ("data",): """
  sqmanip data recognition --help
  sqmanip data pushing --help""",
    ("data", "recognition"): """
  sqmanip data recognition --out data/recognition --help   # see the size options""",
    ("data", "pushing"): """
  sqmanip data pushing --out data/pushing --help           # see the size options""",
    ("train",): """
  sqmanip train dsqnet --help
  sqmanip train sqpdnet --help""",
    ("train", "dsqnet"): """
  sqmanip train dsqnet --help                  # data directory, epochs, device""",
    ("train", "sqpdnet"): """
  sqmanip train sqpdnet --help                 # data directory, preset (cpu|gpu), epochs""",
    ("images",): """
  sqmanip images build                         # base image, wheelhouse, app image
  sqmanip images build --image sqmanip:dev --no-cache""",
    ("images", "build"): """
  sqmanip images build
  sqmanip images build --force-wheels          # re-download the wheelhouse first""",
    ("bench",): """
  sqmanip bench geometry --quick
  sqmanip bench recognition --quick""",
}
"""Epilogs added to sub-parsers that other modules define without examples."""


# --- bench ----------------------------------------------------------------------------------------


def add_bench(subparsers) -> None:
    bench = subparsers.add_parser(
        "bench",
        help="run a benchmark (python -m benchmarks.NAME)",
        **parser_kwargs(
            "Run benchmarks/NAME.py; arguments after NAME go to the script. Each benchmark "
            "prints a table and writes benchmarks/results/NAME.json.",
            EXAMPLES[("bench",)],
        ),
    )
    bench.add_argument("name", help="benchmark name, e.g. geometry, recognition, sim")
    bench.add_argument("args", nargs=argparse.REMAINDER, help="arguments for the script")
    bench.set_defaults(func=_run_bench)


def _run_bench(args: argparse.Namespace) -> int:
    """Run ``python -m benchmarks.<name>`` with the remaining arguments."""
    if not (BENCHMARKS_DIR / f"{args.name}.py").exists():
        available = sorted(p.stem for p in BENCHMARKS_DIR.glob("*.py") if p.stem != "__init__")
        raise CLIError(f"unknown benchmark {args.name!r}; available: {', '.join(available)}", 2)
    sys.path.insert(0, str(BENCHMARKS_DIR.parent))
    sys.argv = [f"benchmarks.{args.name}", *args.args]
    runpy.run_module(f"benchmarks.{args.name}", run_name="__main__")
    return 0


# --- parser ---------------------------------------------------------------------------------------


def _resolve(spec: str):
    module, _, func = spec.partition(":")
    return getattr(importlib.import_module(module), func)


def _available(cmd: Command) -> bool:
    """False when a command's module is not in this checkout (``images`` comes with compose).

    Checked on the file system: ``importlib.util.find_spec`` would import the parent packages
    (``sqmanip.dynamics`` loads torch), which is what the lazy registry avoids.
    """
    root = Path(__file__).resolve().parents[1]  # .../sqmanip
    for spec in cmd.adders:
        parts = spec.partition(":")[0].split(".")[1:]
        base = root.joinpath(*parts)
        if not (base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()):
            return False
    return True


def _subparsers_of(parser: argparse.ArgumentParser) -> argparse._SubParsersAction | None:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action
    return None


def _add_examples(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()) -> None:
    """Give every sub-parser without an epilog its :data:`EXAMPLES` entry (verbatim)."""
    sub = _subparsers_of(parser)
    if sub is None:
        return
    for name, child in sub.choices.items():
        key = (*path, name)
        if not child.epilog and key in EXAMPLES:
            child.epilog = "examples:\n" + EXAMPLES[key].strip("\n")
            if child.formatter_class is argparse.HelpFormatter:
                child.formatter_class = argparse.RawDescriptionHelpFormatter
        _add_examples(child, key)


def _add_command(subparsers, cmd: Command) -> None:
    if cmd.group is None:
        for spec in cmd.adders:
            _resolve(spec)(subparsers)
        return
    group = subparsers.add_parser(cmd.name, help=cmd.help, description=cmd.help)
    inner = group.add_subparsers(dest=cmd.group, metavar=cmd.group.upper(), required=True)
    for spec in cmd.adders:
        _resolve(spec)(inner)


def build_parser(only: str | None = None, *, full: bool | None = None) -> argparse.ArgumentParser:
    """The ``sqmanip`` parser. ``only``: build just that sub-command's parser (the others are
    listed by name and help); default: all of them (``full``)."""
    parser = argparse.ArgumentParser(
        prog="sqmanip",
        description="SQManip: superquadric recognition, grasping, pushing and shelf search. "
        "Every command answers --help with examples.",
        epilog="examples:\n"
        "  sqmanip up                                  # start the stack\n"
        "  sqmanip sim reset --seed 7 && sqmanip sim observe --out frame.ply\n"
        "  sqmanip recognize frame.ply --out shapes.obj --view\n"
        "  sqmanip grasp --scene-json shapes.json --target 0\n"
        "  sqmanip search --n-objects 3 --seed 1\n\n"
        "gateway: --gateway URL, or $SQMANIP_GATEWAY_URL (default http://127.0.0.1:8080)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "-v", "--debug", action="store_true", help="show tracebacks and debug logs on errors"
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    full = only is None if full is None else full
    for cmd in COMMANDS:
        if not _available(cmd):
            continue
        if full or cmd.name == only:
            _add_command(subparsers, cmd)
        else:
            subparsers.add_parser(cmd.name, help=cmd.help, add_help=False)
    _add_examples(parser)
    return parser


def _command_name(argv: Sequence[str]) -> str | None:
    """The sub-command named on the command line (first token not starting with '-')."""
    for tok in argv:
        if not tok.startswith("-"):
            return tok
    return None


VECTOR_OPTIONS = frozenset({"--viewpoint", "--workspace", "--push", "--goal"})
"""Options whose value is a comma-separated vector, which may start with a minus sign."""


def _join_vector_values(argv: list[str]) -> list[str]:
    """``--push -0.1,0,...`` -> ``--push=-0.1,0,...``: argparse would take a value starting with
    '-' (that is not a plain negative number) for an option."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        tok = argv[i]
        nxt = argv[i + 1] if i + 1 < len(argv) else None
        if tok in VECTOR_OPTIONS and nxt is not None and re.match(r"^-[\d.]", nxt):
            out.append(f"{tok}={nxt}")
            i += 2
            continue
        out.append(tok)
        i += 1
    return out


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    if isinstance(exc, KeyError) and len(exc.args) == 1 and isinstance(exc.args[0], str):
        text = exc.args[0]
    return " ".join(text.split()) or type(exc).__name__


def _user_error(exc: BaseException) -> bool:
    """Errors that are the user's or the environment's (bad file, bad value, gateway down):
    one line. Anything else is a bug: one line too, with a hint to rerun with --debug."""
    if isinstance(exc, CLIError | ValueError | OSError | KeyError):
        return True
    from sqmanip.errors import SQManipError

    if isinstance(exc, SQManipError):
        return True
    sdk = sys.modules.get("sqmanip_client.errors")
    return sdk is not None and isinstance(exc, sdk.SQManipError)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``sqmanip``; returns the exit code (0 ok, 1 error, 2 usage, 130 Ctrl-C).

    ``--debug`` may appear anywhere (``-v`` before the sub-command): tracebacks and DEBUG logs.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    argv = _join_vector_values([a for a in argv if a != "--debug"])
    command = _command_name(argv)
    head = argv if command is None else argv[: argv.index(command)]
    debug = debug or "-v" in head
    if debug:
        import logging

        logging.basicConfig(level=logging.DEBUG, format="%(levelname)s %(name)s: %(message)s")
    try:
        parser = build_parser(command, full=False)
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return 0
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if debug:
            raise
        if _user_error(exc):
            print(f"error: {_one_line(exc)}", file=sys.stderr)
        else:
            print(
                f"error: internal error: {type(exc).__name__}: {_one_line(exc)} "
                "(rerun with --debug for the traceback)",
                file=sys.stderr,
            )
        return exc.code if isinstance(exc, CLIError) else 1


if __name__ == "__main__":
    sys.exit(main())
