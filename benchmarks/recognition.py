"""Recognition quality and latency: single-view IoU per primitive type, and /recognize latency.

Run: ``python -m benchmarks.recognition [--quick]``. Writes ``benchmarks/results/recognition.json``.

(a) Volumetric IoU (Monte-Carlo, :func:`sqmanip.geometry.volume_iou`) between the recognized part and
the ground truth, on single-view partial clouds of one primitive on a table (A.1 noise, sigma =
1 mm; :func:`make_single_view`), per primitive type of Table 3.2 (B, E, CY, C, TC; the truncated
torus is not in this set), for: the amodal optimisation fitter (``method="optimization"``), the
plain radial-distance fit without amodal terms (the thesis' DSQOpt), and the PCA bounding box
(MVBB, 3.5.2), plus the upright MVBB that reaches down to the plane, and the shipped DSQNet
(``method="network"``, ``models/dsqnet_cpu``) and its refinement by the fitter (``"hybrid"``).
The object's points are given as labels so segmentation errors do not enter (as in 3.5.1). The
thesis' numbers are printed beside ours: Table 3.2 (DSQOpt / DSQNet, primitive dataset) and
Table 3.3 (MVBB, object dataset).

(b) Latency of a 40,000-point tabletop cloud with 4 objects (segmentation by clustering): per
stage (``timings_ms``) and end to end, in-process (``Recognizer.recognize``) and through the
gateway (``POST /recognize``, binary body) of a stack started with :func:`sqmanip.launch.running_stack`,
interleaved request by request so load on the machine hits both alike. The CPU time of the
in-process requests (``time.process_time``, all threads) is printed too: on a shared machine it
is less sensitive to other processes than wall time.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch
from sqmanip.geometry import volume_iou
from sqmanip.perception.pipeline import Recognizer
from sqmanip.perception.synthetic import KINDS_ALL, make_single_view, make_tabletop_scene
from sqmanip.perception.types import RecognizeOptions, RecognizeRequest

RESULTS = Path(__file__).parent / "results" / "recognition.json"
SHORT = {"box": "B", "ellipsoid": "E", "cylinder": "CY", "cone": "C", "truncated_cone": "TC"}
THESIS = {
    "DSQOpt (T3.2)": {"B": 0.4194, "E": 0.8640, "CY": 0.3924, "C": 0.2637, "TC": 0.4116},
    "DSQNet (T3.2)": {"B": 0.8288, "E": 0.8423, "CY": 0.8575, "C": 0.8394, "TC": 0.8292},
    "MVBB (T3.3)": {"B": 0.3795, "E": 0.3026, "CY": 0.5283, "C": 0.3065, "TC": 0.4448},
}
METHODS = {
    "amodal": RecognizeOptions(method="optimization", amodal=True),
    "dsqopt": RecognizeOptions(method="optimization", amodal=False),
    "mvbb": RecognizeOptions(method="mvbb", amodal=False),
    "mvbb_upright": RecognizeOptions(method="mvbb", amodal=True),
    "network": RecognizeOptions(method="network"),
    "hybrid": RecognizeOptions(method="hybrid"),
}


def machine_facts() -> dict:
    return {
        "command": " ".join(
            [sys.executable.split("/")[-1], "-m", "benchmarks.recognition", *sys.argv[1:]]
        ),
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "load_average": os.getloadavg(),
    }


def iou_benchmark(samples: int, iou_points: int) -> dict:
    rec = Recognizer()
    per_kind: dict[str, dict[str, list[float]]] = {}
    for kind in KINDS_ALL:
        scores: dict[str, list[float]] = {m: [] for m in METHODS}
        for i in range(samples):
            scene = make_single_view(kind, seed=1000 + i)
            for name, options in METHODS.items():
                req = RecognizeRequest(
                    scene.points,
                    labels=scene.object_ids,
                    viewpoint=scene.viewpoint,
                    options=options,
                )
                out = rec.recognize(req)
                iou = (
                    volume_iou(out.objects[0].parts, scene.objects[0], n=iou_points)
                    if out.objects
                    else 0.0
                )
                scores[name].append(iou)
        per_kind[SHORT[kind]] = scores
        means = "  ".join(f"{m}={np.mean(v):.3f}" for m, v in scores.items())
        print(f"  {SHORT[kind]:>2}: {means}", flush=True)
    return per_kind


def _pct(values: list[float]) -> dict:
    a = np.asarray(values)
    return {"p50": float(np.percentile(a, 50)), "p95": float(np.percentile(a, 95)), "n": len(a)}


def latency_benchmark(requests: int, warmup: int, gateway: bool) -> dict:
    scene = make_tabletop_scene(4, seed=0, n_points=40_000)
    req = RecognizeRequest(scene.points, viewpoint=scene.viewpoint)
    rec = Recognizer()
    stages: dict[str, list[float]] = {"preprocess": [], "segment": [], "fit": [], "total": []}
    inproc: list[float] = []
    cpu: list[float] = []
    via_gateway: list[float] = []
    n_objects: list[int] = []
    gateway_error = None
    gateway_objects: list[int] = []

    def run_inprocess(record: bool) -> None:
        t0, c0 = time.perf_counter(), time.process_time()
        out = rec.recognize(req)
        dt = 1e3 * (time.perf_counter() - t0)
        if record:
            inproc.append(dt)
            cpu.append(1e3 * (time.process_time() - c0))
            for k in stages:
                stages[k].append(out.timings_ms[k])
            n_objects.append(len(out.objects))

    stack = None
    cleanup = contextlib.ExitStack()
    if gateway:
        try:
            from sqmanip.launch import running_stack

            stack = cleanup.enter_context(running_stack(services=("perception",)))
        except Exception as exc:  # launcher missing or the stack failed to start
            gateway_error = f"stack unavailable: {type(exc).__name__}: {exc}"
            cleanup.close()
    if stack is None:
        for i in range(warmup + requests):
            run_inprocess(i >= warmup)
    else:
        import httpx

        body = np.ascontiguousarray(scene.points, dtype="<f4").tobytes()
        params = {"viewpoint": ",".join(f"{v:.6f}" for v in scene.viewpoint)}
        with cleanup, httpx.Client(timeout=120.0) as client:
            url = stack.gateway_url + "/recognize"

            def run_gateway(record: bool) -> None:
                t0 = time.perf_counter()
                r = client.post(
                    url,
                    content=body,
                    params=params,
                    headers={"content-type": "application/octet-stream"},
                )
                dt = 1e3 * (time.perf_counter() - t0)
                r.raise_for_status()
                if record:
                    via_gateway.append(dt)
                    gateway_objects.append(len(r.json()["objects"]))

            for i in range(warmup + requests):
                run_inprocess(i >= warmup)
                run_gateway(i >= warmup)

    ious = []
    out = rec.recognize(req)
    for obj in out.objects:
        ids = scene.object_ids[obj.point_indices]
        gt = int(np.bincount(ids + 1).argmax() - 1)
        ious.append(volume_iou(obj.parts, scene.objects[gt], n=20000) if gt >= 0 else 0.0)
    result = {
        "points": len(scene.points),
        "objects_expected": 4,
        "objects_found": sorted(set(n_objects)),
        "objects_found_gateway": sorted(set(gateway_objects)),
        "scene_iou_per_object": ious,
        "stages_ms": {k: _pct(v) for k, v in stages.items()},
        "in_process_ms": _pct(inproc),
        "in_process_cpu_ms": _pct(cpu),
    }
    if via_gateway:
        result["gateway_ms"] = _pct(via_gateway)
        result["gateway_overhead_ratio_p50"] = (
            result["gateway_ms"]["p50"] / result["in_process_ms"]["p50"] - 1.0
        )
    if gateway_error:
        result["gateway_error"] = gateway_error
    return result


def run_iou_table(samples: int, quick: bool) -> dict:
    """Part (a): run, print the table, return the JSON section."""
    print(f"\n(a) single-view volumetric IoU, {samples} samples per type")
    t0 = time.time()
    per_kind = iou_benchmark(samples, 10_000 if quick else 20_000)
    cols = list(METHODS)
    header = f"{'type':>4} | " + " | ".join(f"{c:>12}" for c in cols)
    header += " | " + " | ".join(f"{c:>13}" for c in THESIS)
    print(header)
    print("-" * len(header))
    summary = {}
    for t, scores in per_kind.items():
        row = {c: float(np.mean(scores[c])) for c in cols}
        summary[t] = row
        line = f"{t:>4} | " + " | ".join(f"{row[c]:>12.4f}" for c in cols)
        line += " | " + " | ".join(f"{THESIS[m][t]:>13.4f}" for m in THESIS)
        print(line)
    mean = {c: float(np.mean([summary[t][c] for t in summary])) for c in cols}
    line = f"{'mean':>4} | " + " | ".join(f"{mean[c]:>12.4f}" for c in cols)
    line += " | " + " | ".join(f"{np.mean(list(THESIS[m].values())):>13.4f}" for m in THESIS)
    print(line)
    print(f"(IoU part took {time.time() - t0:.0f} s)")

    return {"per_type": summary, "mean": mean, "raw": per_kind, "thesis": THESIS}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="few samples and requests")
    ap.add_argument("--samples", type=int, default=None, help="single views per type (20)")
    ap.add_argument("--requests", type=int, default=None, help="timed requests (60)")
    ap.add_argument("--no-gateway", action="store_true", help="in-process latency only")
    ap.add_argument(
        "--latency-only",
        action="store_true",
        help="skip (a); keep the IoU results already in the results file",
    )
    args = ap.parse_args(argv)
    samples = args.samples or (4 if args.quick else 20)
    requests = args.requests or (10 if args.quick else 60)
    facts = machine_facts()
    for k, v in facts.items():
        print(f"# {k}: {v}")
    torch.manual_seed(0)

    previous = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    if args.latency_only and "iou" in previous:
        iou_result = previous["iou"]
        samples = previous.get("samples_per_type", samples)
        print(f"\n(a) skipped (--latency-only); IoU kept from {RESULTS}: {iou_result['mean']}")
    else:
        iou_result = run_iou_table(samples, args.quick)
    print(f"\n(b) latency, 40,000-point 4-object tabletop scene, {requests} requests")
    lat = latency_benchmark(requests, 3, not args.no_gateway)
    print(f"{'stage':>22} | {'p50 ms':>8} | {'p95 ms':>8}")
    for k, v in lat["stages_ms"].items():
        print(f"{'in-process ' + k:>22} | {v['p50']:>8.1f} | {v['p95']:>8.1f}")
    v = lat["in_process_ms"]
    print(f"{'in-process end-to-end':>22} | {v['p50']:>8.1f} | {v['p95']:>8.1f}")
    v = lat["in_process_cpu_ms"]
    print(f"{'in-process CPU time':>22} | {v['p50']:>8.1f} | {v['p95']:>8.1f}")
    if "gateway_ms" in lat:
        v = lat["gateway_ms"]
        print(f"{'gateway end-to-end':>22} | {v['p50']:>8.1f} | {v['p95']:>8.1f}")
        print(f"gateway overhead (p50): {100 * lat['gateway_overhead_ratio_p50']:.1f} %")
    else:
        print(f"gateway not measured: {lat.get('gateway_error', '--no-gateway')}")
    print(
        f"objects found per request: {lat['objects_found']} (expected 4); "
        f"scene IoU per object: {[round(x, 3) for x in lat['scene_iou_per_object']]}"
    )

    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(
        json.dumps(
            {
                "machine": facts,
                "samples_per_type": samples,
                "iou": iou_result,
                "latency": lat,
                "targets": {"e2e_p50_ms": 150, "mean_iou": 0.8, "gateway_overhead": 0.15},
            },
            indent=2,
        )
    )
    print(f"\nwrote {RESULTS}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
