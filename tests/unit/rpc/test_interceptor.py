"""The one server interceptor maps domain exceptions to gRPC statuses; clients map them back."""

import grpc
import numpy as np
import pytest
from sqmanip import errors
from sqmanip.perception.server import PerceptionServicer, registrar
from sqmanip.perception.types import RecognizeRequest, Scene
from sqmanip.rpc import convert
from sqmanip.rpc.client import AsyncRemoteRecognizer
from sqmanip.rpc.server import start_server
from sqmanip.settings import StackSettings
from sqmanip.v1 import perception_pb2_grpc


class RaisingRecognizer:
    """Raises the exception selected by the request's first x coordinate (test double)."""

    EXCEPTIONS = [
        errors.ValidationError("points: expected at most 10 points, got 11"),
        errors.NotFoundError("object 3 not found"),
        errors.PreconditionError("pose unreachable"),
        errors.ResourceExhaustedError("busy"),
        errors.UnavailableError("grasp service down"),
        errors.UnimplementedError("method 'network' needs a trained model"),
        ValueError("plain value error"),
        KeyError("key"),
        RuntimeError("secret internal detail"),
    ]

    def recognize(self, request: RecognizeRequest) -> Scene:
        i = int(request.points[0, 0])
        if i < 0:
            return Scene([], timings_ms={"total": 1.0})
        raise self.EXCEPTIONS[i]


EXPECTED = [
    (grpc.StatusCode.INVALID_ARGUMENT, errors.ValidationError),
    (grpc.StatusCode.NOT_FOUND, errors.NotFoundError),
    (grpc.StatusCode.FAILED_PRECONDITION, errors.PreconditionError),
    (grpc.StatusCode.RESOURCE_EXHAUSTED, errors.ResourceExhaustedError),
    (grpc.StatusCode.UNAVAILABLE, errors.UnavailableError),
    (grpc.StatusCode.UNIMPLEMENTED, errors.UnimplementedError),
    (grpc.StatusCode.INVALID_ARGUMENT, errors.ValidationError),
    (grpc.StatusCode.NOT_FOUND, errors.NotFoundError),
    (grpc.StatusCode.INTERNAL, errors.SQManipError),
]


@pytest.fixture
async def server():
    running = await start_server(
        registrar(PerceptionServicer(RaisingRecognizer())), StackSettings(), port=0
    )
    yield running
    await running.stop(0)


def _request(i: int) -> RecognizeRequest:
    return RecognizeRequest(points=np.full((1, 3), float(i), np.float32))


@pytest.mark.parametrize("index", range(len(EXPECTED)))
async def test_exception_becomes_status_and_client_error(server, index, caplog) -> None:
    code, cls = EXPECTED[index]
    async with grpc.aio.insecure_channel(f"127.0.0.1:{server.port}") as ch:
        stub = perception_pb2_grpc.PerceptionStub(ch)
        msg = convert.recognize_request_to_proto(_request(index))
        with pytest.raises(grpc.aio.AioRpcError) as info:
            await stub.Recognize(msg, timeout=5)
    assert info.value.code() == code
    if code is grpc.StatusCode.INTERNAL:
        assert "secret" not in info.value.details() and "request id" in info.value.details()
        assert "secret internal detail" in caplog.text  # logged with its traceback
    remote = AsyncRemoteRecognizer(f"127.0.0.1:{server.port}", StackSettings())
    with pytest.raises(cls) as err:
        await remote.recognize(_request(index), timeout=5)
    await remote.close()
    assert type(err.value) is cls


async def test_success_and_one_log_line_per_request(server, caplog) -> None:
    caplog.set_level("INFO", logger="sqmanip.rpc")
    remote = AsyncRemoteRecognizer(f"127.0.0.1:{server.port}", StackSettings())
    scene = await remote.recognize(_request(-1), timeout=5)
    await remote.close()
    assert scene.objects == [] and scene.timings_ms == {"total": 1.0}
    lines = [r.getMessage() for r in caplog.records if "Recognize" in r.getMessage()]
    assert len(lines) == 1 and "status=OK" in lines[0] and "size=" in lines[0] and "ms=" in lines[0]


async def test_health_service_reports_serving(server) -> None:
    from sqmanip.rpc.health_probe import check_async

    assert await check_async(f"127.0.0.1:{server.port}") == "SERVING"
    assert await check_async(f"127.0.0.1:{server.port}", "sqmanip.v1.Perception") == "SERVING"
