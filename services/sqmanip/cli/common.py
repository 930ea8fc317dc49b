"""Shared pieces of the ``sqmanip`` sub-commands: the gateway URL, the SDK client, number
parsing, the recognized-scene JSON, tables and the episode follower (tqdm).

Kept light at import time (stdlib only): ``sqmanip --help`` must not load numpy, torch or the
SDK; each command imports what it needs inside its function.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any
from urllib.parse import urlsplit

GATEWAY_ENV = "SQMANIP_GATEWAY_URL"
VIEWER_ENV = "SQMANIP_VIEWER_URL"


class CLIError(Exception):
    """A user-facing error: ``main`` prints ``error: <message>`` and exits with ``code``."""

    def __init__(self, message: str, code: int = 1) -> None:
        super().__init__(message)
        self.code = code


def parser_kwargs(description: str, examples: str) -> dict[str, Any]:
    """``add_parser`` keywords: the description, an ``examples:`` epilog kept verbatim."""
    import textwrap

    return {
        "description": textwrap.fill(" ".join(description.split()), 90),
        "epilog": "examples:\n" + examples.strip("\n"),
        "formatter_class": argparse.RawDescriptionHelpFormatter,
    }


# --- gateway --------------------------------------------------------------------------------------


def default_gateway_url() -> str:
    """``$SQMANIP_GATEWAY_URL``, else ``http://<gateway_host>:<gateway_port>`` from the stack's
    settings (``SQMANIP_GATEWAY_HOST`` / ``SQMANIP_GATEWAY_PORT``; 127.0.0.1:8080)."""
    url = os.environ.get(GATEWAY_ENV, "").strip()
    if url:
        return url
    from sqmanip.settings import get_settings

    s = get_settings()
    return f"http://{s.gateway_host}:{s.gateway_port}"


def add_gateway_args(parser: argparse.ArgumentParser, timeout: float = 120.0) -> None:
    g = parser.add_argument_group("gateway")
    g.add_argument(
        "--gateway",
        metavar="URL",
        default=None,
        help=f"gateway base URL (default: ${GATEWAY_ENV}, else http://127.0.0.1:8080 from the "
        "stack settings)",
    )
    g.add_argument(
        "--timeout", type=float, default=timeout, help=f"seconds per request ({timeout:g})"
    )


def client(args: argparse.Namespace):
    """The SDK client for ``args.gateway`` (tests replace this function to inject one)."""
    from sqmanip_client import Client

    url = args.gateway or default_gateway_url()
    if not urlsplit(url).scheme.startswith("http"):
        raise CLIError(f"--gateway: expected an http(s):// URL, got {url!r}", 2)
    return Client(url, timeout=args.timeout)


def viewer_url(gateway_url: str) -> str:
    """The viewer's URL: ``$SQMANIP_VIEWER_URL``; else the link on the gateway's ``/`` page (it
    knows the stack's viewer port, offsets included); else the gateway's host and the settings'
    ``viewer_port``."""
    url = os.environ.get(VIEWER_ENV, "").strip()
    if url:
        return url
    try:
        import re

        import httpx

        page = httpx.get(gateway_url.rstrip("/") + "/", timeout=3.0).text
        m = re.search(r'<a href="(https?://[^"]+)">3D viewer</a>', page)
        if m:
            return m.group(1).replace("&amp;", "&").rstrip("/")
    except Exception:  # noqa: BLE001 - best effort: fall back to the settings
        pass
    from sqmanip.settings import get_settings

    port = getattr(get_settings(), "viewer_port", 8090)
    host = urlsplit(gateway_url).hostname or "127.0.0.1"
    return f"http://{host}:{port}"


def open_viewer(gateway_url: str) -> None:
    """Print the viewer URL; open a browser when there is a desktop to open it on."""
    url = viewer_url(gateway_url)
    print(f"viewer: {url}")
    if (
        sys.platform in ("darwin", "win32")
        or os.environ.get("DISPLAY")
        or os.environ.get("WAYLAND_DISPLAY")
    ):
        import webbrowser

        webbrowser.open(url)


# --- parsing numbers ------------------------------------------------------------------------------


def floats(text: str, n: int, name: str) -> list[float]:
    """``"x,y,z"`` -> ``n`` floats; a CLIError names the option otherwise."""
    try:
        vals = [float(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        raise CLIError(f"{name}: expected {n} comma-separated numbers, got {text!r}", 2) from None
    if len(vals) != n:
        raise CLIError(f"{name}: expected {n} comma-separated numbers, got {len(vals)}", 2)
    return vals


def id_and_floats(text: str, n: int, name: str) -> tuple[int, list[float]]:
    """``"ID:x,y,z"`` -> ``(ID, [x, y, z])``."""
    head, sep, tail = text.partition(":")
    if not sep:
        raise CLIError(f"{name}: expected ID:x,y,z, got {text!r}", 2)
    try:
        oid = int(head)
    except ValueError:
        raise CLIError(
            f"{name}: expected an integer object id before ':', got {head!r}", 2
        ) from None
    return oid, floats(tail, n, name)


# --- scenes ---------------------------------------------------------------------------------------


def scene_json(scene, *, point_indices: bool = True) -> dict[str, Any]:
    """An SDK :class:`Scene` -> the gateway's ``/recognize`` JSON (``scene_from_json`` reads it
    back; ``sqmanip grasp|predict|plan --scene-json`` take it)."""
    from sqmanip_client.grasps import part_json

    plane = scene.support_plane
    return {
        "objects": [
            {
                "id": int(o.id),
                "parts": [part_json(p) for p in o.parts],
                "point_indices": [int(i) for i in o.point_indices] if point_indices else [],
                "mean_color": None if o.mean_color is None else [float(c) for c in o.mean_color],
                "residual": float(o.residual),
                "confidence": float(o.confidence),
            }
            for o in scene.objects
        ],
        "support_plane": None
        if plane is None
        else {"normal": [float(v) for v in plane.normal], "offset": float(plane.offset)},
        "timings_ms": dict(scene.timings_ms),
    }


def load_scene_json(path) -> Any:
    """An SDK :class:`Scene` from a ``recognize --out shapes.json`` / ``--json`` file."""
    import json
    from pathlib import Path

    from sqmanip_client.types import scene_from_json

    p = Path(path)
    try:
        data = json.loads(p.read_text())
    except FileNotFoundError:
        raise CLIError(f"{p}: no such file") from None
    except json.JSONDecodeError as exc:
        raise CLIError(f"{p}: not valid JSON ({exc})") from None
    if isinstance(data, dict) and "scene" in data and "objects" not in data:
        data = data["scene"]
    try:
        return scene_from_json(data)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise CLIError(
            f"{p}: not a recognized scene (the JSON of `sqmanip recognize --json`): {exc!r}"
        ) from None


def yaw_deg(pose) -> float:
    """Rotation about world z of a pose (deg), from its quaternion (x, y, z, w)."""
    import math

    x, y, z, w = pose.orientation
    return math.degrees(math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A plain aligned text table (numbers right-aligned)."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    numeric = [
        all(_is_number(r[i]) for r in cells[1:]) and len(cells) > 1 for i in range(len(headers))
    ]
    out = []
    for r in cells:
        out.append(
            "  ".join(
                c.rjust(w) if num else c.ljust(w)
                for c, w, num in zip(r, widths, numeric, strict=True)
            ).rstrip()
        )
    return "\n".join(out)


def _is_number(s: str) -> bool:
    try:
        float(s.replace("%", ""))
    except ValueError:
        return s in ("-", "")
    return True


def fmt_vec(v: Sequence[float], digits: int = 3) -> str:
    return "(" + ", ".join(f"{float(x):.{digits}f}" for x in v) + ")"


# --- episodes -------------------------------------------------------------------------------------


def follow_episode(
    get: Callable[[str], Any],
    episode_id: str,
    *,
    total: int | None,
    describe: Callable[[dict[str, Any]], str],
    poll_s: float = 0.5,
    timeout_s: float = 3600.0,
    quiet: bool = False,
) -> Any:
    """Poll ``get(episode_id)`` until it is finished, printing each new event's line
    (``describe(event)``) above a tqdm bar that counts the episode's steps (``event["step"]``, out
    of ``total``). Returns the final EpisodeStatus."""
    from tqdm import tqdm

    seen = 0
    deadline = time.monotonic() + timeout_s
    with tqdm(total=total, unit="step", desc=f"episode {episode_id[:8]}", disable=quiet or None,
              file=sys.stderr, leave=False) as bar:  # fmt: skip
        while True:
            status = get(episode_id)
            new = status.n_events - seen
            if new > 0:
                for ev in list(status.events)[-min(new, len(status.events)) :]:
                    line = describe(ev)
                    if line and not quiet:
                        tqdm.write(line, file=sys.stdout)
                    step = ev.get("step")
                    if isinstance(step, int) and step > bar.n:
                        bar.update(min(step, total or step) - bar.n)
                seen = status.n_events
            if status.finished:
                return status
            if time.monotonic() > deadline:
                raise CLIError(f"episode {episode_id} still running after {timeout_s:g} s")
            time.sleep(poll_s)
