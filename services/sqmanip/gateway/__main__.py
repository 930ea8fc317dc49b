"""``python -m sqmanip.gateway [--host H] [--port P]``: serve the gateway with uvicorn."""

from __future__ import annotations

import argparse
import logging
import sys

import uvicorn

from .app import create_app
from .config import GatewaySettings


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sqmanip.gateway", description=__doc__)
    parser.add_argument("--host", default=None, help="default: settings.gateway_host (127.0.0.1)")
    parser.add_argument("--port", type=int, default=None, help="default: settings.gateway_port")
    parser.add_argument("--log-level", default="info")
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    settings = GatewaySettings()
    if args.host:
        settings.gateway_host = args.host
    if args.port is not None:
        settings.gateway_port = args.port
    uvicorn.run(
        create_app(settings),
        host=settings.gateway_host,
        port=settings.gateway_port,
        log_level=args.log_level,
        access_log=False,  # the app logs one line per request itself
        timeout_graceful_shutdown=5,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
