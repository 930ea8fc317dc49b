"""gRPC health probe for container health checks and the launcher.

``python -m sqmanip.rpc.health_probe HOST:PORT [--service NAME] [--timeout S]`` exits 0 when the
server reports SERVING (grpcio-health-checking), 1 otherwise, printing the status or the error.
"""

from __future__ import annotations

import argparse
import sys

import grpc
from grpc_health.v1 import health_pb2, health_pb2_grpc


def check(address: str, service: str = "", timeout: float = 2.0) -> str:
    """Health status name (``SERVING``, ``NOT_SERVING``, ...) or ``UNREACHABLE: <reason>``."""
    with grpc.insecure_channel(address) as ch:
        stub = health_pb2_grpc.HealthStub(ch)
        try:
            resp = stub.Check(health_pb2.HealthCheckRequest(service=service), timeout=timeout)
        except grpc.RpcError as err:
            return f"UNREACHABLE: {err.code().name} {err.details() or ''}".strip()
    return health_pb2.HealthCheckResponse.ServingStatus.Name(resp.status)


async def check_async(address: str, service: str = "", timeout: float = 1.0) -> str:
    """asyncio variant of :func:`check` (used by the gateway's ``/healthz``)."""
    async with grpc.aio.insecure_channel(address) as ch:
        stub = health_pb2_grpc.HealthStub(ch)
        try:
            resp = await stub.Check(health_pb2.HealthCheckRequest(service=service), timeout=timeout)
        except grpc.aio.AioRpcError as err:
            return f"UNREACHABLE: {err.code().name}"
    return health_pb2.HealthCheckResponse.ServingStatus.Name(resp.status)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sqmanip.rpc.health_probe", description=__doc__)
    parser.add_argument("address", help="host:port of a gRPC server")
    parser.add_argument("--service", default="", help="service name ('' = whole server)")
    parser.add_argument("--timeout", type=float, default=2.0, help="seconds (default 2)")
    args = parser.parse_args(argv)
    status = check(args.address, args.service, args.timeout)
    print(status)
    return 0 if status == "SERVING" else 1


if __name__ == "__main__":
    sys.exit(main())
