"""``sqmanip images build`` (issue 11): argument parsing and the compose/build.sh command line
(the build itself is exercised by .ci/docker.sh and tests/compose)."""

from __future__ import annotations

import argparse
import subprocess

from sqmanip import images


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="sqmanip")
    images.add_parser(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(list(argv))


def test_build_runs_the_checkout_build_script_with_the_chosen_flags() -> None:
    args = parse("images", "build", "--force-wheels", "--no-cache")
    assert args.func is images.cmd_build
    cmd = images.build_command(args)
    assert cmd[0] == "bash" and cmd[1].endswith("compose/build.sh")
    assert cmd[2:] == ["--force-wheels", "--no-cache"]
    assert images.build_command(parse("images", "build"))[2:] == []


def test_build_script_is_valid_bash_and_documents_its_flags() -> None:
    script = images.build_script()
    assert subprocess.run(["bash", "-n", str(script)], capture_output=True).returncode == 0
    usage = subprocess.run(["bash", str(script), "--help"], capture_output=True, text=True)
    assert usage.returncode == 0 and "--force-base" in usage.stdout
    bad = subprocess.run(["bash", str(script), "--bogus"], capture_output=True, text=True)
    assert bad.returncode == 2 and "unknown argument --bogus" in bad.stderr
