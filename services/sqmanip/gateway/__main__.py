"""``python -m sqmanip.gateway [--host H] [--port P] [--insecure]``: serve the gateway with uvicorn.

Binds 127.0.0.1 by default; a non-loopback ``--host`` needs ``SQMANIP_API_TOKEN`` (clients then
send ``Authorization: Bearer <token>``) or ``--insecure`` on purpose, else start-up stops with
one error line and exit code 2 (:mod:`sqmanip.gateway.security`).
"""

from __future__ import annotations

import argparse
import logging
import sys

import pydantic

from .config import GatewaySettings
from .security import bind_error, is_loopback


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sqmanip.gateway", description=__doc__)
    parser.add_argument("--host", default=None, help="default: settings.gateway_host (127.0.0.1)")
    parser.add_argument("--port", type=int, default=None, help="default: settings.gateway_port")
    parser.add_argument("--log-level", default="info")
    parser.add_argument(
        "--insecure",
        action="store_true",
        help="allow a non-loopback --host without SQMANIP_API_TOKEN (no authentication!)",
    )
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    try:
        settings = GatewaySettings()
    except pydantic.ValidationError as exc:
        first = exc.errors()[0]
        print(f"sqmanip.gateway: {first['loc'][0]}: {first['msg']}", file=sys.stderr)
        return 2
    if args.host:
        settings.gateway_host = args.host
    if args.port is not None:
        settings.gateway_port = args.port
    insecure = args.insecure or settings.gateway_insecure
    error = bind_error(settings.gateway_host, settings.token(), insecure)
    if error:
        print(f"sqmanip.gateway: {error}", file=sys.stderr)
        return 2
    if insecure and not settings.token() and not is_loopback(settings.gateway_host):
        logging.getLogger("sqmanip.gateway").warning(
            "serving on %s WITHOUT authentication (--insecure)", settings.gateway_host
        )
    # Imported after the checks: the app pulls in the whole stack (torch, pybullet prints a
    # line on import), and a refused start-up should print its one error line only.
    import uvicorn

    from .app import create_app

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
