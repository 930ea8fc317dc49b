"""The ``sqmanip`` command line: every sub-command answers ``--help`` and bad input is one line."""

from __future__ import annotations

import pytest
from sqmanip.cli import build_parser, main

COMMANDS = [
    ["up"],
    ["sim"],
    ["data", "recognition"],
    ["data", "pushing"],
    ["train", "dsqnet"],
    ["train", "sqpdnet"],
    ["bench"],
]


@pytest.fixture(scope="module")
def parser():
    return build_parser()


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: " ".join(c))
def test_every_subcommand_has_help(parser, command, capsys):
    with pytest.raises(SystemExit) as exc:
        parser.parse_args([*command, "--help"])
    assert exc.value.code == 0
    assert "usage: sqmanip" in capsys.readouterr().out


def test_no_command_prints_help_and_succeeds(capsys):
    assert main([]) == 0
    assert "COMMAND" in capsys.readouterr().out


def test_unknown_benchmark_is_one_clear_line(capsys):
    assert main(["bench", "no_such_benchmark"]) == 2
    out = capsys.readouterr().out
    assert "unknown benchmark 'no_such_benchmark'" in out and "geometry" in out
