"""The checked-in protobuf modules match what protoc generates from protos/ now."""

from pathlib import Path

from sqmanip.rpc import gen


def test_checked_in_generated_code_matches_protos(tmp_path: Path) -> None:
    fresh = gen.generate(tmp_path)
    problems = gen.diff(gen.OUT_ROOT / "sqmanip" / "v1", fresh)
    assert problems == [], f"stale generated code ({problems}); run: python -m sqmanip.rpc.gen"


def test_generated_modules_import_each_other_inside_the_package() -> None:
    text = (gen.OUT_ROOT / "sqmanip" / "v1" / "perception_pb2.py").read_text()
    assert "from sqmanip.v1 import common_pb2" in text
