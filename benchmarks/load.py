"""Load, memory and fault benchmark of ``POST /recognize`` on a launcher stack (issue 11, item 4).

``python -m benchmarks.load [--quick] [--fault] [--duration S] [--clients C] [--requests N]``

Everything runs on loopback and stops by itself (every phase is bounded in time and count):

1. start a stack with :func:`sqmanip.launch.running_stack` (perception + gateway, free loopback
   ports, no Zenoh, ``restart=True``: the launcher's supervisor restarts a dead service with
   back-off);
2. warm up (each scene once), read the RSS of every service process;
3. **load**: ``--clients`` asyncio clients (httpx) post a fixed set of synthetic scenes
   (:mod:`sqmanip.perception.synthetic`, fixed seeds, binary bodies as the SDK sends them) for
   ``--duration`` seconds: throughput, p50/p95/p99 latency, errors by status;
4. **soak** until ``--requests`` requests have been answered in total (capped by
   ``--max-soak-s``), then the RSS again: before/after shows whether the services leak;
5. **fault** (``--fault``): the same load; after ``--kill-at`` seconds the perception process is
   SIGKILLed; the supervisor restarts it. Reported: how many requests failed, whether every
   failure was a 503 answered before the deadline (``--deadline``, also the gateway's
   ``request_timeout_s``; a client-side timeout would be a hang), the outage (kill -> first
   success), and the time from the restarted service's first SERVING health answer to the first
   successful ``/recognize``.

Writes ``benchmarks/results/load.json`` and a latency-over-time plot
``benchmarks/results/load_latency.png`` (matplotlib when installed, otherwise a plain raster
drawn with numpy: green 200, red 503, orange other errors, black client timeouts; blue line =
kill, purple line = restarted service ready).
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import os
import platform
import signal
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


# --- measurements ---------------------------------------------------------------------------------


@dataclasses.dataclass
class Sample:
    start_s: float
    """Request start, seconds since the phase started."""
    latency_s: float
    status: int | str
    """HTTP status, or ``"timeout"`` (no answer within the client timeout) / ``"connect"``."""
    detail: str = ""


def rss_bytes(pid: int) -> int | None:
    """Resident set size of ``pid`` (psutil when installed, else ``/proc/<pid>/status``)."""
    try:
        import psutil

        return int(psutil.Process(pid).memory_info().rss)
    except ImportError:
        pass
    except Exception:  # noqa: BLE001 - process gone
        return None
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def service_rss(stack) -> dict[str, dict[str, Any]]:
    out = {}
    for proc in stack.procs:
        if proc.popen is not None:
            rss = rss_bytes(proc.popen.pid)
            out[proc.name] = {"pid": proc.popen.pid, "rss_mb": None if rss is None else rss / 2**20}
    return out


def percentiles(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"p50": None, "p95": None, "p99": None, "max": None}
    a = np.asarray(values) * 1e3
    return {
        "p50": float(np.percentile(a, 50)),
        "p95": float(np.percentile(a, 95)),
        "p99": float(np.percentile(a, 99)),
        "max": float(a.max()),
    }


def summarize(samples: list[Sample], wall_s: float) -> dict[str, Any]:
    ok = [s.latency_s for s in samples if s.status == 200]
    errors = Counter(str(s.status) for s in samples if s.status != 200)
    return {
        "requests": len(samples),
        "ok": len(ok),
        "errors": sum(errors.values()),
        "errors_by_status": dict(errors),
        "wall_s": wall_s,
        "throughput_rps": len(ok) / wall_s if wall_s > 0 else 0.0,
        "latency_ms": percentiles(ok),
    }


# --- the load driver ------------------------------------------------------------------------------


def scene_requests(method: str, n_scenes: int) -> list[dict[str, Any]]:
    """Fixed synthetic scenes (seeds 0..n-1): tabletops with 1-4 objects, 10k-40k points, as
    the SDK would send them (binary body, viewpoint as a query parameter)."""
    from sqmanip.perception.synthetic import make_tabletop_scene
    from sqmanip_client.client import build_request

    reqs = []
    for i in range(n_scenes):
        scene = make_tabletop_scene(1 + i % 4, seed=i, n_points=10_000 * (1 + i % 4))
        req = build_request(scene.points, viewpoint=scene.viewpoint, options={"method": method})
        req["n_points"] = len(scene.points)
        reqs.append(req)
    return reqs


async def drive(
    url: str,
    reqs: list[dict[str, Any]],
    *,
    clients: int,
    deadline_s: float,
    should_stop: Callable[[float, int], bool],
    samples: list[Sample] | None = None,
) -> tuple[list[Sample], float]:
    """``clients`` concurrent loops posting ``reqs`` round robin until ``should_stop(elapsed_s,
    n_answered)``; the client timeout is ``deadline_s + 5`` so a hang past the deadline shows up
    as a latency over ``deadline_s`` or a ``"timeout"``."""
    samples = [] if samples is None else samples
    t0 = time.perf_counter()
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
    async with httpx.AsyncClient(base_url=url, timeout=deadline_s + 5.0, limits=limits) as http:

        async def worker(cid: int) -> None:
            k = 0
            while not should_stop(time.perf_counter() - t0, len(samples)):
                req = reqs[(cid + k * clients) % len(reqs)]
                k += 1
                start = time.perf_counter()
                try:
                    r = await http.post(
                        "/recognize",
                        content=req["content"],
                        headers=req["headers"],
                        params=req["params"],
                    )
                    status: int | str = r.status_code
                    detail = "" if r.status_code == 200 else r.text[:200]
                except httpx.TimeoutException as exc:
                    status, detail = "timeout", str(exc)[:200]
                except httpx.HTTPError as exc:
                    status, detail = "connect", str(exc)[:200]
                end = time.perf_counter()
                samples.append(Sample(start - t0, end - start, status, detail))
                if status != 200:
                    await asyncio.sleep(0.1)  # a failing backend answers at once: don't spin

        await asyncio.gather(*(worker(c) for c in range(clients)))
    return samples, time.perf_counter() - t0


async def fault_run(stack, reqs, args) -> tuple[dict[str, Any], list[Sample], dict[str, float]]:
    """Load with a SIGKILL of perception after ``args.kill_at`` s; see the module docstring."""
    from sqmanip.rpc.health_probe import check_async

    proc = stack._proc("perception")
    old_pid = proc.popen.pid
    address = stack.address("perception")
    events: dict[str, float] = {}
    t0 = time.perf_counter()
    samples: list[Sample] = []

    async def killer_and_monitor() -> None:
        await asyncio.sleep(args.kill_at)
        stack.kill("perception", signal.SIGKILL)
        events["kill_s"] = time.perf_counter() - t0
        while time.perf_counter() - t0 < args.fault_cap_s:
            await asyncio.sleep(0.05)
            if "respawn_s" not in events and proc.popen.pid != old_pid:
                events["respawn_s"] = time.perf_counter() - t0
            if "respawn_s" in events and await check_async(address, timeout=0.3) == "SERVING":
                events["ready_s"] = time.perf_counter() - t0
                return

    def should_stop(elapsed: float, _n: int) -> bool:
        if elapsed >= args.fault_cap_s:
            return True
        if elapsed < args.fault_duration or "ready_s" not in events:
            return False
        # run on until a request started after the restart has succeeded (plus 3 s of load)
        after = [s for s in samples if s.start_s > events["ready_s"] and s.status == 200]
        return bool(after) and elapsed > after[0].start_s + after[0].latency_s + 3.0

    monitor = asyncio.create_task(killer_and_monitor())
    samples, wall = await drive(
        stack.gateway_url,
        reqs,
        clients=args.clients,
        deadline_s=args.deadline,
        should_stop=should_stop,
        samples=samples,
    )
    monitor.cancel()
    kill = events.get("kill_s", float("nan"))
    after_kill = [s for s in samples if s.start_s + s.latency_s >= kill]
    failed = [s for s in after_kill if s.status != 200]
    successes_after = [
        s.start_s + s.latency_s for s in samples if s.start_s >= kill and s.status == 200
    ]
    first_ok = min(successes_after) if successes_after else None
    ready = events.get("ready_s")
    report = {
        **summarize(samples, wall),
        "kill_at_s": kill,
        "respawn_at_s": events.get("respawn_s"),
        "ready_at_s": ready,
        "failed_requests": len(failed),
        "failed_by_status": dict(Counter(str(s.status) for s in failed)),
        "all_failures_503": all(s.status == 503 for s in failed),
        "max_failure_latency_ms": max((s.latency_s for s in failed), default=0.0) * 1e3,
        "deadline_s": args.deadline,
        "none_past_deadline": all(
            s.status != "timeout" and s.latency_s < args.deadline for s in samples
        ),
        "failure_window_s": (
            max(s.start_s + s.latency_s for s in failed) - min(s.start_s for s in failed)
            if failed
            else 0.0
        ),
        "outage_s": None if first_ok is None else first_ok - kill,
        "restart_to_first_success_s": (
            None if first_ok is None or ready is None else first_ok - ready
        ),
        "respawn_to_first_success_s": (
            None
            if first_ok is None or events.get("respawn_s") is None
            else first_ok - events["respawn_s"]
        ),
        "restarts": proc.restarts,
        "example_failure": failed[0].detail if failed else "",
    }
    return report, samples, events


# --- plot -----------------------------------------------------------------------------------------

_COLORS = {200: (40, 160, 60), 503: (220, 40, 40), "timeout": (0, 0, 0)}
_OTHER = (240, 150, 20)


def _color(status: int | str) -> tuple[int, int, int]:
    return _COLORS.get(status, _OTHER)


def plot(path: Path, panels: list[tuple[str, list[Sample], dict[str, float]]]) -> str:
    """Latency (ms) over request start time (s), one panel per phase. Returns the backend."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        _raster_plot(path, panels)
        return "numpy raster (matplotlib is not installed: no axis labels)"
    fig, axes = plt.subplots(len(panels), 1, figsize=(10, 3.2 * len(panels)), squeeze=False)
    for ax, (title, samples, events) in zip(axes[:, 0], panels, strict=True):
        for status in sorted({str(s.status) for s in samples}):
            sel = [s for s in samples if str(s.status) == status]
            c = np.array(_color(sel[0].status)) / 255
            ax.scatter(
                [s.start_s for s in sel], [s.latency_s * 1e3 for s in sel], s=4, color=c,
                label=status,
            )  # fmt: skip
        for key, col in (("kill_s", "blue"), ("ready_s", "purple")):
            if key in events:
                ax.axvline(events[key], color=col, lw=1, label=key.removesuffix("_s"))
        ax.set_title(title)
        ax.set_xlabel("request start (s)")
        ax.set_ylabel("latency (ms)")
        ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return "matplotlib"


def _raster_plot(path: Path, panels: list[tuple[str, list[Sample], dict[str, float]]]) -> None:
    from sqmanip.planning.episode import write_png

    W, H, M = 1000, 300, 30
    img = np.full((H * len(panels), W, 3), 255, np.uint8)
    for i, (_title, samples, events) in enumerate(panels):
        top = i * H
        t_max = max([s.start_s for s in samples] + [1.0]) * 1.02
        y_max = max([s.latency_s * 1e3 for s in samples] + [1.0]) * 1.1
        step = next(v for v in (50, 100, 200, 500, 1000, 2000, 5000, 10000, 1e9) if y_max / v <= 8)

        def px(t: float, ms: float, *, _top=top, _t=t_max, _y=y_max) -> tuple[int, int]:
            x = M + int((W - 2 * M) * t / _t)
            y = _top + H - M - int((H - 2 * M) * ms / _y)
            return x, y

        for ms in np.arange(0, y_max, step):  # horizontal grid every `step` ms
            img[px(0, ms)[1], M : W - M] = (225, 225, 225)
        for t in np.arange(0, t_max, 10.0):  # vertical grid every 10 s
            img[top + M : top + H - M, px(t, 0)[0]] = (225, 225, 225)
        img[top + H - M, M : W - M] = img[top + M : top + H - M, M] = (0, 0, 0)
        for key, col in (("kill_s", (40, 40, 230)), ("ready_s", (150, 40, 180))):
            if key in events:
                img[top + M : top + H - M, px(events[key], 0)[0]] = col
        for s in samples:
            x, y = px(s.start_s, s.latency_s * 1e3)
            img[max(top, y - 1) : y + 2, max(0, x - 1) : x + 2] = _color(s.status)
    write_png(path, img)


# --- main -----------------------------------------------------------------------------------------


def machine_facts() -> dict[str, Any]:
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    return {
        "cpu_count": os.cpu_count(),
        "processor": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "loadavg_at_start": load,
        "niceness": os.nice(0),
    }


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.load", description=__doc__)
    ap.add_argument("--quick", action="store_true", help="10 s load, 100 requests, short fault")
    ap.add_argument("--fault", action="store_true", help="also run the SIGKILL fault phase")
    ap.add_argument("--duration", type=float, default=None, help="load phase (s), default 60")
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--requests", type=int, default=None, help="RSS after N requests (1000)")
    ap.add_argument("--max-soak-s", type=float, default=900.0, help="cap of the soak phase (s)")
    ap.add_argument("--method", default="optimization", help="recognition method")
    ap.add_argument("--scenes", type=int, default=8, help="number of fixed synthetic scenes")
    ap.add_argument("--deadline", type=float, default=30.0, help="request deadline (s)")
    ap.add_argument("--kill-at", type=float, default=None, help="fault: kill after S s (5)")
    ap.add_argument("--fault-duration", type=float, default=None, help="fault phase (s), 30")
    ap.add_argument("--fault-cap-s", type=float, default=120.0, help="fault phase hard cap (s)")
    ap.add_argument("--torch-threads", type=int, default=1, help="perception's torch threads")
    ap.add_argument("--out", default=str(RESULTS / "load.json"))
    args = ap.parse_args(argv)
    q = args.quick
    args.duration = args.duration if args.duration is not None else (10.0 if q else 60.0)
    args.requests = args.requests if args.requests is not None else (100 if q else 1000)
    args.kill_at = args.kill_at if args.kill_at is not None else (3.0 if q else 5.0)
    args.fault_duration = args.fault_duration or (12.0 if q else 30.0)
    return args


def _raise_interrupt(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    # SIGTERM (and SIGINT, which a background job ignores) tear the stack down cleanly.
    signal.signal(signal.SIGTERM, _raise_interrupt)
    signal.signal(signal.SIGINT, _raise_interrupt)
    from sqmanip.launch import running_stack, settings_on_free_ports

    command = " ".join([sys.executable, "-m", "benchmarks.load", *(argv or sys.argv[1:])])
    facts = machine_facts()
    print("command:", command)
    print(
        f"machine: {facts['processor']}, cores={facts['cpu_count']}, python {facts['python']}, "
        f"load average {facts['loadavg_at_start']}, nice {facts['niceness']}; perception torch "
        f"threads={args.torch_threads}, {args.clients} clients, method={args.method}"
    )
    reqs = scene_requests(args.method, args.scenes)
    print(f"scenes: {len(reqs)} fixed tabletops, points {[r['n_points'] for r in reqs]}")
    settings = settings_on_free_ports(
        torch_threads=args.torch_threads, request_timeout_s=args.deadline
    )
    result: dict[str, Any] = {"command": command, "machine": facts, "config": vars(args).copy()}
    panels = []
    t_start = time.perf_counter()
    with running_stack(settings, services=("perception",), zenoh=False, restart=True) as stack:
        print(f"stack up in {time.perf_counter() - t_start:.1f} s: {stack.gateway_url}")
        warm, _ = asyncio.run(
            drive(
                stack.gateway_url,
                reqs,
                clients=1,
                deadline_s=args.deadline,
                should_stop=lambda _e, n: n >= len(reqs),
            )
        )
        result["warmup"] = summarize(warm, sum(s.latency_s for s in warm))
        rss_before = service_rss(stack)

        samples, wall = asyncio.run(
            drive(
                stack.gateway_url,
                reqs,
                clients=args.clients,
                deadline_s=args.deadline,
                should_stop=lambda e, _n: e >= args.duration,
            )
        )
        load = summarize(samples, wall)
        result["load"] = load
        panels.append((f"load: {args.clients} clients, {args.duration:.0f} s", samples, {}))
        print_table("load", load)

        answered = len(samples)
        soak_wall = 0.0
        if answered < args.requests:
            soak, soak_wall = asyncio.run(
                drive(
                    stack.gateway_url,
                    reqs,
                    clients=args.clients,
                    deadline_s=args.deadline,
                    should_stop=lambda e, n: n >= args.requests - answered or e >= args.max_soak_s,
                )
            )
            result["soak"] = summarize(soak, soak_wall)
            print_table("soak", result["soak"])
            answered += len(soak)
        rss_after = service_rss(stack)
        result["rss"] = {
            "requests_between": answered,
            "before": rss_before,
            "after": rss_after,
            "growth_mb": {
                n: (rss_after[n]["rss_mb"] or 0) - (rss_before[n]["rss_mb"] or 0)
                for n in rss_before
                if n in rss_after
            },
        }
        print(f"\nRSS (MB) before -> after {answered} requests:")
        for n in rss_before:
            b, a = rss_before[n]["rss_mb"], rss_after.get(n, {}).get("rss_mb")
            print(f"  {n:<11} {b:8.1f} -> {a:8.1f}  ({a - b:+.1f})")

        if args.fault:
            fault, fsamples, events = asyncio.run(fault_run(stack, reqs, args))
            result["fault"] = fault
            panels.append(
                ("fault: perception SIGKILLed, restarted by the launcher", fsamples, events)
            )
            print_fault(fault)

    result["total_wall_s"] = time.perf_counter() - t_start
    RESULTS.mkdir(parents=True, exist_ok=True)
    png = Path(args.out).with_name(Path(args.out).stem + "_latency.png")
    result["plot"] = {
        "path": os.path.relpath(png, RESULTS.parent.parent),
        "backend": plot(png, panels),
    }
    Path(args.out).write_text(json.dumps(result, indent=2, default=str) + "\n")
    print(f"\nwrote {args.out} and {png} (plot: {result['plot']['backend']})")
    return 0


def print_table(name: str, s: dict[str, Any]) -> None:
    lat = s["latency_ms"]
    fmt = lambda v: "-" if v is None else f"{v:.0f}"  # noqa: E731
    print(f"\n{'phase':<8}{'requests':>9}{'ok':>6}{'errors':>7}{'req/s':>8}"
          f"{'p50 ms':>8}{'p95 ms':>8}{'p99 ms':>8}{'max ms':>8}  errors by status")  # fmt: skip
    print(
        f"{name:<8}{s['requests']:>9}{s['ok']:>6}{s['errors']:>7}{s['throughput_rps']:>8.2f}"
        f"{fmt(lat['p50']):>8}{fmt(lat['p95']):>8}{fmt(lat['p99']):>8}{fmt(lat['max']):>8}  "
        f"{s['errors_by_status'] or '-'}"
    )


def print_fault(f: dict[str, Any]) -> None:
    def sec(v: float | None) -> str:
        return "-" if v is None else f"{v:.2f} s"

    print_table("fault", f)
    print(
        f"\nfault: kill at {sec(f['kill_at_s'])}, respawn at {sec(f['respawn_at_s'])}, "
        f"ready at {sec(f['ready_at_s'])} (restarts={f['restarts']})\n"
        f"  failed requests: {f['failed_requests']} {f['failed_by_status']}; all 503: "
        f"{f['all_failures_503']}; slowest failure {f['max_failure_latency_ms']:.0f} ms; none "
        f"past the {f['deadline_s']:.0f} s deadline: {f['none_past_deadline']}\n"
        f"  outage (kill -> first success): {sec(f['outage_s'])}; failure window "
        f"{sec(f['failure_window_s'])}; ready -> first success "
        f"{sec(f['restart_to_first_success_s'])}; respawn -> first success "
        f"{sec(f['respawn_to_first_success_s'])}"
    )


if __name__ == "__main__":
    sys.exit(main())
