"""Fuzzing the gateway (schemathesis, from its OpenAPI) and Perception's gRPC Recognize (issue 11,
item 5), against real processes on loopback. Bounded: a fixed number of examples per operation.

One stack: the real perception service and the real gateway. The gateway is configured with
*every* backend but only perception runs: ``/recognize`` is fuzzed end to end, the other routes
through all their gateway-side parsing and conversion up to the gRPC call, which then meets a
deliberately absent backend. Only there is a 503 accepted (and only with the gateway's
"<backend> service unavailable" message); any other 5xx fails the test, and every 4xx must carry
a non-empty ``detail`` (ARCHITECTURE.md error mapping: ``{"detail": str, "field": str|null}``).
"""

from __future__ import annotations

import json
import struct

import grpc
import numpy as np
import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode
from sqmanip.launch import Stack, settings_on_free_ports
from sqmanip.perception.synthetic import make_single_view
from sqmanip.settings import SERVICES
from sqmanip.v1 import common_pb2, perception_pb2, perception_pb2_grpc

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(300)]

EXAMPLES_PER_OPERATION = 6
GRPC_EXAMPLES = 60
REQUEST_TIMEOUT_S = 20.0

# Which backend each path reaches (the first path segment, as in gateway/routes/).
BACKEND_OF = {
    "recognize": "perception",
    "sim": "sim",
    "grasps": "grasp",
    "predict": "dynamics",
    "plan": "mpc",
    "mpc": "mpc",
    "search": "search",
}


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    settings_ = settings_on_free_ports(request_timeout_s=REQUEST_TIMEOUT_S, torch_threads=1)
    stack = Stack(
        settings_, ("perception",), zenoh=False, log_dir=tmp_path_factory.mktemp("fuzz-stack")
    )
    # Every backend configured, only perception started (see the module docstring).
    stack._env["SQMANIP_GATEWAY_SERVICES"] = json.dumps(list(SERVICES))
    with stack:
        stack.start(180)
        yield stack


def _operations() -> dict[str, object]:
    """The gateway's operations by label (``POST /recognize``), from its OpenAPI document."""
    from sqmanip.gateway.app import create_app

    schema = schemathesis.openapi.from_dict(create_app().openapi())
    ops = {}
    for result in schema.get_all_operations():
        op = result.ok()
        ops[op.label] = op
    return ops


OPERATIONS = _operations()


def _absent_backend_503(path: str, status: int, detail: str) -> bool:
    backend = BACKEND_OF.get(path.strip("/").split("/")[0])
    return (
        status == 503
        and backend not in (None, "perception")
        and detail.startswith((f"{backend} service unavailable", f"{backend} episode cannot start"))
    )


CASES = [
    (label, mode)
    for label, op in sorted(OPERATIONS.items())
    for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE)
    # schema-violating cases need a body or query parameters to violate
    if mode is GenerationMode.POSITIVE or len(op.body) or len(op.query)
]


@pytest.mark.parametrize(("label", "mode"), CASES)
def test_gateway_openapi_fuzz_no_server_errors(stack, label, mode) -> None:
    """Schemathesis cases (valid and schema-violating) for one operation: no 5xx (but the
    absent-backend 503), every 4xx with a message."""
    op = OPERATIONS[label]

    @given(case=op.as_strategy(generation_mode=mode))
    @settings(
        max_examples=EXAMPLES_PER_OPERATION,
        deadline=None,
        suppress_health_check=list(HealthCheck),
        derandomize=True,
        database=None,
    )
    def check(case) -> None:
        response = case.call(base_url=stack.gateway_url, timeout=REQUEST_TIMEOUT_S + 10)
        status = response.status_code
        try:
            body = response.json()
        except ValueError:
            body = None
        detail = body.get("detail") if isinstance(body, dict) else None
        where = f"{case.method} {case.formatted_path} -> {status}: {response.text[:300]}"
        if status >= 500:
            assert _absent_backend_503(case.path, status, detail or ""), where
        if 400 <= status < 500:
            assert isinstance(detail, str) and detail.strip(), f"4xx without a message: {where}"
            assert "field" in body, where

    check()


# --- gRPC: Perception.Recognize -------------------------------------------------------------------


@pytest.fixture(scope="module")
def perception(stack):
    channel = grpc.insecure_channel(stack.address("perception"))
    yield perception_pb2_grpc.PerceptionStub(channel)
    channel.close()


@pytest.fixture(scope="module")
def valid_request():
    scene = make_single_view("box", seed=2)
    return perception_pb2.RecognizeRequest(
        cloud=common_pb2.PointCloud(
            num_points=len(scene.points), xyz=scene.points.astype("<f4").tobytes()
        ),
        viewpoint=common_pb2.Vector3(
            x=scene.viewpoint[0], y=scene.viewpoint[1], z=scene.viewpoint[2]
        ),
        options=perception_pb2.RecognizeOptions(method="mvbb"),
    )


def _call(stub, request) -> tuple[grpc.StatusCode, str]:
    try:
        stub.Recognize(request, timeout=REQUEST_TIMEOUT_S)
        return grpc.StatusCode.OK, ""
    except grpc.RpcError as exc:
        return exc.code(), exc.details() or ""


def _still_serving(stub, valid_request) -> None:
    code, detail = _call(stub, valid_request)
    assert code == grpc.StatusCode.OK, f"the server no longer answers a valid request: {detail}"


def _cloud(n: int, xyz: bytes, rgb: bytes = b"", labels: bytes = b"") -> common_pb2.PointCloud:
    return common_pb2.PointCloud(num_points=n, xyz=xyz, rgb=rgb, labels=labels)


def _pts(values) -> bytes:
    return np.asarray(values, dtype="<f4").tobytes()


NAN, INF = float("nan"), float("inf")
BAD_REQUESTS = {
    "empty cloud": perception_pb2.RecognizeRequest(),
    "count larger than the bytes": perception_pb2.RecognizeRequest(
        cloud=_cloud(5, _pts([[0, 0, 0]]))
    ),
    "count smaller than the bytes": perception_pb2.RecognizeRequest(
        cloud=_cloud(1, _pts(np.zeros((4, 3))))
    ),
    "huge count, few bytes": perception_pb2.RecognizeRequest(cloud=_cloud(2**32 - 1, b"\0" * 12)),
    "huge count, no bytes": perception_pb2.RecognizeRequest(cloud=_cloud(2**31, b"")),
    "bytes not a multiple of 12": perception_pb2.RecognizeRequest(cloud=_cloud(1, b"\0" * 13)),
    "NaN point": perception_pb2.RecognizeRequest(
        cloud=_cloud(3, _pts([[0, 0, 0], [NAN, 0, 0], [0, 0, 1]]))
    ),
    "inf point": perception_pb2.RecognizeRequest(cloud=_cloud(2, _pts([[0, 0, 0], [0, INF, 0]]))),
    "rgb of the wrong size": perception_pb2.RecognizeRequest(
        cloud=_cloud(2, _pts(np.zeros((2, 3))), rgb=b"\1" * 5)
    ),
    "labels of the wrong size": perception_pb2.RecognizeRequest(
        cloud=_cloud(2, _pts(np.zeros((2, 3))), labels=b"\0" * 7)
    ),
    "NaN viewpoint": perception_pb2.RecognizeRequest(
        cloud=_cloud(2, _pts(np.ones((2, 3)))), viewpoint=common_pb2.Vector3(x=NAN)
    ),
    "NaN workspace": perception_pb2.RecognizeRequest(
        cloud=_cloud(2, _pts(np.ones((2, 3)))),
        workspace=common_pb2.Workspace(min=common_pb2.Vector3(x=NAN), max=common_pb2.Vector3()),
    ),
    "unknown method": perception_pb2.RecognizeRequest(
        cloud=_cloud(2, _pts(np.ones((2, 3)))),
        options=perception_pb2.RecognizeOptions(method="pickle"),
    ),
    "points_per_segment beyond the limit": perception_pb2.RecognizeRequest(
        cloud=_cloud(2, _pts(np.ones((2, 3)))),
        options=perception_pb2.RecognizeOptions(points_per_segment=2**32 - 1),
    ),
}


def test_grpc_bad_recognize_requests_are_invalid_argument(perception, valid_request) -> None:
    for name, request in BAD_REQUESTS.items():
        code, detail = _call(perception, request)
        assert code == grpc.StatusCode.INVALID_ARGUMENT, f"{name}: {code} {detail}"
        assert detail.strip(), f"{name}: INVALID_ARGUMENT without a message"
    _still_serving(perception, valid_request)


def test_grpc_garbage_message_bytes_are_invalid_argument(stack, perception, valid_request) -> None:
    """Bytes that are not a RecognizeRequest at all: INVALID_ARGUMENT from the error-mapping
    interceptor's deserializer (grpc alone would answer UNKNOWN "Unexpected DecodeError")."""
    channel = grpc.insecure_channel(stack.address("perception"))
    raw = channel.unary_unary("/sqmanip.v1.Perception/Recognize")  # bytes in, bytes out
    rng = np.random.default_rng(0)
    undecodable = 0
    try:
        for size in (1, 7, 64, 1000):
            for _ in range(3):
                with pytest.raises(grpc.RpcError) as err:
                    raw(rng.bytes(size), timeout=REQUEST_TIMEOUT_S)
                assert err.value.code() == grpc.StatusCode.INVALID_ARGUMENT, err.value
                assert err.value.details().strip()
                undecodable += "not a valid message" in err.value.details()
    finally:
        channel.close()
    assert undecodable > 0
    _still_serving(perception, valid_request)


_float_bits = st.integers(0, 2**32 - 1).map(lambda b: struct.pack("<I", b))
_special = st.sampled_from([NAN, INF, -INF, 0.0, -0.0, 1e38, -1e38, 1e-45, 1.0])


@st.composite
def fuzzed_requests(draw) -> perception_pb2.RecognizeRequest:
    n_true = draw(st.integers(0, 40))
    mode = draw(st.sampled_from(["random bits", "specials", "random bytes"]))
    if mode == "random bits":
        xyz = b"".join(draw(st.lists(_float_bits, min_size=3 * n_true, max_size=3 * n_true)))
    elif mode == "specials":
        vals = draw(st.lists(_special, min_size=3 * n_true, max_size=3 * n_true))
        xyz = struct.pack(f"<{len(vals)}f", *vals)
    else:
        xyz = draw(st.binary(max_size=12 * 40 + 11))
    n = draw(st.one_of(st.just(n_true), st.integers(0, 2**32 - 1), st.integers(0, 50)))
    rgb = draw(st.one_of(st.just(b""), st.binary(max_size=150)))
    labels = draw(st.one_of(st.just(b""), st.binary(max_size=200)))
    req = perception_pb2.RecognizeRequest(cloud=_cloud(n, xyz, rgb, labels))
    if draw(st.booleans()):
        v = draw(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=3, max_size=3))
        req.viewpoint.CopyFrom(common_pb2.Vector3(x=v[0], y=v[1], z=v[2]))
    if draw(st.booleans()):
        lo = draw(st.lists(st.floats(-10, 10), min_size=3, max_size=3))
        hi = draw(st.lists(st.floats(-10, 10), min_size=3, max_size=3))
        req.workspace.CopyFrom(
            common_pb2.Workspace(min=common_pb2.Vector3(x=lo[0], y=lo[1], z=lo[2]),
                                 max=common_pb2.Vector3(x=hi[0], y=hi[1], z=hi[2]))
        )  # fmt: skip
    req.options.method = draw(st.sampled_from(["", "mvbb", "optimization", "bogus"]))
    req.options.segmentation = draw(st.sampled_from(["", "clustering", "labels", "x"]))
    if draw(st.booleans()):
        req.options.points_per_segment = draw(st.integers(0, 2**32 - 1))
    return req


def test_grpc_recognize_fuzz(perception, valid_request) -> None:
    """Random byte planes, counts, NaNs and options: each answer is OK or INVALID_ARGUMENT with
    a message (never INTERNAL/UNKNOWN), and the server answers a valid request afterwards."""
    seen: dict[str, int] = {}

    @given(req=fuzzed_requests())
    @settings(
        max_examples=GRPC_EXAMPLES,
        deadline=None,
        derandomize=True,
        suppress_health_check=list(HealthCheck),
    )
    def check(req) -> None:
        code, detail = _call(perception, req)
        seen[code.name] = seen.get(code.name, 0) + 1
        assert code in (grpc.StatusCode.OK, grpc.StatusCode.INVALID_ARGUMENT), (
            f"{code}: {detail} for num_points={req.cloud.num_points}, {len(req.cloud.xyz)} "
            f"xyz bytes, options={req.options}"
        )
        if code != grpc.StatusCode.OK:
            assert detail.strip()
        if len(req.cloud.xyz) != 12 * req.cloud.num_points:
            assert code == grpc.StatusCode.INVALID_ARGUMENT and "cloud.xyz" in detail

    check()
    assert seen.get("INVALID_ARGUMENT", 0) > GRPC_EXAMPLES // 2, seen
    _still_serving(perception, valid_request)
