"""The ``sqmanip`` command line: every sub-command answers ``--help`` with an example, the
top-level help loads no heavy module, and bad input is one ``error:`` line."""

from __future__ import annotations

import subprocess
import sys

import pytest
from sqmanip.cli import COMMANDS, build_parser, main

COMMANDS_WITH_HELP = [
    ["up"],
    ["recognize"],
    ["grasp"],
    ["predict"],
    ["plan"],
    ["search"],
    ["sim"],
    ["sim", "reset"],
    ["sim", "observe"],
    ["data"],
    ["data", "recognition"],
    ["data", "pushing"],
    ["train"],
    ["train", "dsqnet"],
    ["train", "sqpdnet"],
    ["bench"],
    ["images"],
    ["images", "build"],
]


@pytest.fixture(scope="module")
def parser():
    return build_parser()


@pytest.mark.parametrize("command", COMMANDS_WITH_HELP, ids=lambda c: " ".join(c))
def test_every_subcommand_has_help_with_an_example(parser, command, capsys):
    with pytest.raises(SystemExit) as exc:
        parser.parse_args([*command, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert f"usage: sqmanip {' '.join(command)}" in out
    assert "examples:" in out and f"sqmanip {command[0]}" in out.split("examples:")[1]


def test_every_registered_command_is_in_the_help_test() -> None:
    tested = {c[0] for c in COMMANDS_WITH_HELP}
    assert {c.name for c in COMMANDS} <= tested


@pytest.mark.parametrize("command", ["recognize", "grasp", "plan", "search", "sim"])
def test_lazy_parser_builds_the_named_command_like_the_full_one(command) -> None:
    lazy = build_parser(command, full=False)
    full = build_parser()
    assert lazy._subparsers._group_actions[0].choices[command].format_help() == (
        full._subparsers._group_actions[0].choices[command].format_help()
    )


def test_no_command_prints_help_and_succeeds(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    assert "COMMAND" in out and "recognize" in out and "examples:" in out


def test_top_level_help_and_recognize_help_import_no_heavy_module() -> None:
    code = (
        "import sys\n"
        "from sqmanip.cli import main\n"
        "for argv in (['--help'], ['recognize', '--help'], ['sim', 'observe', '--help']):\n"
        "    try:\n"
        "        main(argv)\n"
        "    except SystemExit:\n"
        "        pass\n"
        "heavy = sorted(m for m in ('torch', 'pybullet', 'pinocchio', 'trimesh', 'fastapi')\n"
        "               if m in sys.modules)\n"
        "print('HEAVY', heavy, file=sys.stderr)\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "HEAVY []" in res.stderr, res.stderr
    assert "pybullet build time" not in res.stdout


def test_unknown_benchmark_is_one_error_line_and_usage_exit_code(capsys):
    assert main(["bench", "no_such_benchmark"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: unknown benchmark 'no_such_benchmark'")
    assert "geometry" in err[0]


def test_unknown_command_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["no-such-command"])
    assert exc.value.code == 2
    assert "invalid choice" in capsys.readouterr().err


def test_vector_values_may_start_with_a_minus_sign(capsys) -> None:
    assert main(["predict", "--sim", "--push", "-0.1,0,0.03,0,0.05", "--push", "-1"]) == 2
    err = capsys.readouterr().err
    assert "error: --push: expected 6 comma-separated numbers, got 5" in err
