"""``python -m sqmanip.viewer``: run the viewer until SIGTERM / Ctrl-C."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading

from sqmanip.settings import get_settings


def main(argv: list[str] | None = None) -> int:
    settings = get_settings()
    parser = argparse.ArgumentParser(
        prog="python -m sqmanip.viewer",
        description="Live 3D viewer (viser): subscribes to the stack's Zenoh streams "
        f"({settings.zenoh_endpoint}) and acts through the gateway.",
    )
    parser.add_argument("--host", default=settings.gateway_host, help="address to bind")
    parser.add_argument("--port", type=int, default=settings.viewer_port, help="HTTP port")
    parser.add_argument("--gateway-url", default=None, help="gateway for the panel's actions")
    parser.add_argument("--log-level", default="info", choices=("debug", "info", "warning"))
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    from .app import Viewer  # heavy imports after argument parsing

    viewer = Viewer(settings, host=args.host, port=args.port, gateway_url=args.gateway_url)
    viewer.start()
    logging.getLogger("sqmanip.viewer").info(
        "viewer on http://%s:%d (gateway %s)", args.host, args.port, viewer.gateway_url
    )
    done = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: done.set())
    done.wait()
    viewer.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
