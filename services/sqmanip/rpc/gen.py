"""Regenerate the protobuf/gRPC modules in ``services/sqmanip/v1`` from ``protos/``.

``python -m sqmanip.rpc.gen`` rewrites the checked-in modules; ``--check`` regenerates into a
temporary directory and exits 1 if the checked-in files differ (the unit test
``tests/unit/rpc/test_generated_up_to_date.py`` does the same). Generation runs
``grpc_tools.protoc`` with ``-I protos`` and ``services`` as the output root, so a file
``protos/sqmanip/v1/x.proto`` becomes ``services/sqmanip/v1/x_pb2.py`` and its imports read
``from sqmanip.v1 import common_pb2``, which resolves inside the installed package.
"""

from __future__ import annotations

import argparse
import filecmp
import sys
import tempfile
from importlib import resources
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
PROTO_ROOT = REPO / "protos"
OUT_ROOT = REPO / "services"
PACKAGE_DIR = ("sqmanip", "v1")
INIT_TEXT = '"""Generated protobuf and gRPC modules (package sqmanip.v1). Do not edit: run\n``python -m sqmanip.rpc.gen``."""\n'


def proto_files(proto_root: Path = PROTO_ROOT) -> list[Path]:
    """All ``.proto`` files of the ``sqmanip.v1`` package, sorted."""
    return sorted(proto_root.joinpath(*PACKAGE_DIR).glob("*.proto"))


def generate(out_root: Path, proto_root: Path = PROTO_ROOT) -> Path:
    """Run protoc for every proto file into ``out_root``; return ``out_root/sqmanip/v1``."""
    from grpc_tools import protoc

    files = proto_files(proto_root)
    if not files:
        raise FileNotFoundError(f"no .proto files under {proto_root.joinpath(*PACKAGE_DIR)}")
    well_known = str(resources.files("grpc_tools") / "_proto")
    out_root.mkdir(parents=True, exist_ok=True)
    args = [
        "grpc_tools.protoc",
        f"-I{proto_root}",
        f"-I{well_known}",
        f"--python_out={out_root}",
        f"--grpc_python_out={out_root}",
        f"--pyi_out={out_root}",
        *[str(f.relative_to(proto_root)) for f in files],
    ]
    # protoc resolves the relative file names against -I, so run from the proto root.
    code = protoc.main(args)
    if code != 0:
        raise RuntimeError(f"protoc failed with exit code {code}")
    package_dir = out_root.joinpath(*PACKAGE_DIR)
    (package_dir / "__init__.py").write_text(INIT_TEXT)
    return package_dir


def generated_names(package_dir: Path) -> set[str]:
    return {p.name for p in package_dir.iterdir() if p.suffix in (".py", ".pyi")}


def diff(checked_in: Path, fresh: Path) -> list[str]:
    """Names of files that differ, are missing or are stale between two generated dirs."""
    a, b = generated_names(checked_in) if checked_in.exists() else set(), generated_names(fresh)
    problems = [f"missing: {n}" for n in sorted(b - a)]
    problems += [f"stale (no proto): {n}" for n in sorted(a - b)]
    problems += [
        f"differs: {n}"
        for n in sorted(a & b)
        if not filecmp.cmp(checked_in / n, fresh / n, shallow=False)
    ]
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sqmanip.rpc.gen", description=__doc__)
    parser.add_argument("--check", action="store_true", help="fail if checked-in code is stale")
    args = parser.parse_args(argv)
    target = OUT_ROOT.joinpath(*PACKAGE_DIR)
    if not args.check:
        generate(OUT_ROOT)
        print(f"generated {sorted(generated_names(target))} in {target}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        problems = diff(target, generate(Path(tmp)))
    for p in problems:
        print(p, file=sys.stderr)
    if problems:
        print("run: python -m sqmanip.rpc.gen", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
