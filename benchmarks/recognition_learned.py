"""Learned vs optimisation recognition on the synthetic datasets of Appendix A.1 (Tables 3.2,
3.3, 3.5; Figs. 3.6, 3.10).

Run: ``python -m benchmarks.recognition_learned [--quick]``. Writes
``benchmarks/results/recognition_learned.json``, ``recognition_learned_iou_time.png`` (Fig. 3.6)
and ``recognition_learned_occlusion.png`` (Fig. 3.10).

Methods, each on one segment cloud resampled to 300 points (3.5.3, the pipeline's
``preprocess.resample``), with the camera position of the view known (the datasets store it):

- ``MVBB``: PCA bounding box (3.5.2);
- ``DSQOpt``: the plain radial-distance fit (3.5.1; ``fit_segments(amodal=False)``);
- ``optimization``: SQManip's amodal fitter (free space seen by the camera; there is no support
  plane in these datasets, the shapes float in random orientations);
- one column per network directory given (``--models``; default the shipped SQNet, DSQNet and
  DSQNet+ under ``models/``); DSQNet+ sees the whole object's cloud as its context (3.6.2);
- ``hybrid``: the DSQNet column refined by the fitter (:mod:`sqmanip.perception.learned.hybrid`).

Tables: (3.2) volumetric IoU per primitive type on the test split of the *primitive* dataset
(``--data``); (3.3) IoU per object type on the test split of the *object* dataset, the parts
cut out with the ground-truth labels (``--segmentation network``: by the shipped segmentation
network, as the thesis does), IoU of the union
of predicted parts against the union of all ground-truth parts (hidden parts included); (3.5) the
multi-part rows of the same with the thesis' SQNet / DSQNet / DSQNet+ beside. Recognition time
per object (ms, median, 1 torch thread, on this shared machine). Fig. 3.10: IoU of DSQNet (else
the first network) against the occlusion ratio of a virtual square occluder (single-primitive
object types, ratio bins of 5 %, the remaining points resampled to 300). Fig. 3.6: mean IoU
against median time per object on the object dataset.

If ``--object-data`` holds no object dataset, a small one is generated there first
(``--object-shapes`` shapes per type, ``--object-views`` views; its test split is the last shape
of each type), which takes a few minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch
from sqmanip.geometry import Superquadric, volume_iou
from sqmanip.perception.config import PerceptionSettings
from sqmanip.perception.fit import fit_segments
from sqmanip.perception.learned.datasets import (
    MULTI_PART_TYPES,
    OBJECT_TYPES,
    PRIMITIVE_TYPES,
    GenerationSpec,
    generate,
    load_dataset,
)
from sqmanip.perception.learned.hybrid import refine_parts
from sqmanip.perception.learned.infer import NetworkRecognizer, NetworkSegmenter, to_superquadric
from sqmanip.perception.mvbb import mvbb_fit
from sqmanip.perception.preprocess import resample

RESULTS = Path(__file__).parent / "results" / "recognition_learned.json"
PNG = Path(__file__).parent / "results" / "recognition_learned_iou_time.png"
OCCLUSION_PNG = Path(__file__).parent / "results" / "recognition_learned_occlusion.png"
DEFAULT_MODELS = ["models/sqnet_cpu", "models/dsqnet_cpu", "models/dsqnet_plus_cpu"]
NAMES = {"B": "B", "E": "E", "CY": "CY", "C": "C", "TC": "TC", "TT": "TT", "bottle": "Bottle",
         "hammer": "Hammer", "mug": "Mug", "dumbbell": "Dumbbell", "padlock": "Padlock",
         "screwdriver": "Screwdriver"}  # fmt: skip
THESIS_32 = {
    "DSQOpt": {"B": .4194, "E": .8640, "CY": .3924, "C": .2637, "TC": .4116, "TT": .1378},
    "DSQNet": {"B": .8288, "E": .8423, "CY": .8575, "C": .8394, "TC": .8292, "TT": .7584},
}  # fmt: skip
THESIS_33 = {  # MVBB, PS-CNN, SQNet, DSQNet
    "B": (.3795, .6442, .8517, .8759), "E": (.3026, .7429, .8483, .8666),
    "CY": (.5283, .7988, .8903, .8939), "C": (.3065, .5946, .5421, .8039),
    "TC": (.4448, .7504, .7340, .8264), "TT": (.3546, .6141, .3691, .6759),
    "hammer": (.5293, .8101, .8358, .8208), "mug": (.4666, .8282, .7786, .8483),
    "screwdriver": (.5535, .8346, .8631, .8655), "padlock": (.4343, .6751, .8182, .8312),
    "dumbbell": (.4367, .7976, .7589, .7017), "bottle": (.4045, .7610, .8120, .8189),
    "Average": (.4284, .7376, .7588, .8191),
}  # fmt: skip
THESIS_35 = {  # SQNet, DSQNet, DSQNet+
    "hammer": (.8266, .8143, .8359), "mug": (.7497, .7976, .8474),
    "screwdriver": (.8354, .8310, .8033), "padlock": (.7673, .7848, .8090),
    "dumbbell": (.7583, .7196, .8764), "bottle": (.7758, .7887, .8324),
    "Average": (.7855, .7893, .8324),
}  # fmt: skip
BINS = (0.0, 0.05, 0.10, 0.15, 0.20, 0.25, 0.30)
N_INPUT = 300
MIN_POINTS = 10


def machine_facts() -> dict:
    return {
        "command": "python -m benchmarks.recognition_learned " + " ".join(sys.argv[1:]),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
    }


# --- methods -------------------------------------------------------------------------------------


class Methods:
    """Every method maps ``(segments: list[(300, 3)], eye (3,), cloud)`` -> list of world parts."""

    def __init__(
        self, model_dirs: list[Path], settings: PerceptionSettings, only: list[str] | None = None
    ) -> None:
        self.settings = settings
        self.nets: dict[str, NetworkRecognizer] = {}
        for d in model_dirs:
            rec = NetworkRecognizer.load(d, device="cpu")
            self.nets[f"{rec.name}:{d.name}"] = rec
        names = ["MVBB", "DSQOpt", "optimization", *self.nets]
        deformable = [r for r in self.nets.values() if r.name == "dsqnet"]
        self.hybrid_base = deformable[0] if deformable else None
        if self.hybrid_base is not None:
            names.append("hybrid")
        if only:  # "network" selects every network column
            names = [n for n in names if n in only or ("network" in only and n in self.nets)]
        self.names = names

    def run(
        self, name: str, segs: list[np.ndarray], eye: np.ndarray, cloud: np.ndarray
    ) -> list[Superquadric]:
        """Parts for the segments ``segs`` of one view; ``cloud`` is the whole view (DSQNet+'s
        context, with each part's natural share of the points)."""
        s = self.settings
        if name == "MVBB":
            return [mvbb_fit(x) for x in segs]
        if name in ("DSQOpt", "optimization"):
            amodal = name == "optimization"
            fits = fit_segments(segs, viewpoint=eye if amodal else None, settings=s,
                                amodal=amodal)  # fmt: skip
            return [f.part for f in fits]
        if name == "hybrid":
            net = self.hybrid_base.predict(segs)
            return [f.part for f in refine_parts(segs, net, viewpoint=eye, settings=s)]
        return self.nets[name].predict(segs, context=cloud)


def _gt_parts(data: dict, shape: int) -> list[Superquadric]:
    n = int(data["n_parts"][shape])
    return [to_superquadric(data["params"][shape, j], data["poses"][shape, j]) for j in range(n)]


def _segments(partial: np.ndarray, labels: np.ndarray, rng: np.random.Generator):
    out = []
    for lab in np.unique(labels):
        pts = partial[labels == lab].astype(np.float64)
        if len(pts) >= MIN_POINTS:
            out.append(resample(pts, N_INPUT, rng))
    return out


def _pick(data: dict, types: tuple[str, ...], per_type: int | None, seed: int) -> list[int]:
    """Test items of each type, ``per_type`` of them evenly spread (all when None)."""
    is_test = data["test"][data["shape_idx"]]
    type_of = data["type_id"][data["shape_idx"]]
    out = []
    for t in types:
        idx = np.flatnonzero(is_test & (type_of == OBJECT_TYPES.index(t)))
        if per_type is not None and len(idx) > per_type:
            idx = idx[np.linspace(0, len(idx) - 1, per_type).round().astype(int)]
        out += idx.tolist()
    return out


def evaluate(
    methods: Methods,
    data: dict,
    items: list[int],
    iou_n: int,
    seed: int,
    segmenter: NetworkSegmenter | None = None,
) -> dict:
    """Per item and method: IoU and time; returns ``{type: {method: {"iou": [..], "ms": [..]}}}``.

    Parts are cut out by the ground-truth labels, or by ``segmenter``'s (not timed)."""
    rng = np.random.default_rng(seed)
    out: dict[str, dict[str, dict[str, list[float]]]] = {}
    for it in items:
        shape = int(data["shape_idx"][it])
        tname = OBJECT_TYPES[int(data["type_id"][shape])]
        cloud = data["partial"][it].astype(np.float64)
        labels = data["labels"][it] if segmenter is None else segmenter.segment(cloud)
        segs = _segments(data["partial"][it], labels, rng)
        if not segs:
            continue
        eye = data["camera"][it][:3, 3].astype(np.float64)
        gt = _gt_parts(data, shape)
        for name in methods.names:
            t0, c0 = time.perf_counter(), time.process_time()
            parts = methods.run(name, segs, eye, cloud)
            ms, cpu_ms = 1e3 * (time.perf_counter() - t0), 1e3 * (time.process_time() - c0)
            iou = volume_iou(parts, gt, n=iou_n, generator=it)
            rec = out.setdefault(tname, {}).setdefault(name, {"iou": [], "ms": [], "cpu_ms": []})
            rec["iou"].append(float(iou))
            rec["ms"].append(ms)
            rec["cpu_ms"].append(cpu_ms)
    return out


def occlude(
    points: np.ndarray, eye: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, float]:
    """A virtual thin square occluder between the camera and the cloud (3.6.1): points whose
    projection (on the plane through the centroid facing the camera) falls in a random square
    are removed. Returns the remaining points and the occlusion ratio."""
    c = points.mean(0)
    z = c - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    uv = (points - c) @ np.stack([x, y], 1)
    ext = np.ptp(uv, 0).max()
    side = rng.uniform(0.1, 0.6) * ext
    centre = uv[rng.integers(len(uv))] + rng.uniform(-0.5, 0.5, 2) * side
    inside = (np.abs(uv - centre) < side / 2).all(1)
    return points[~inside], float(inside.mean())


def occlusion_curve(
    net: NetworkRecognizer, data: dict, items: list[int], per_bin: int, iou_n: int, seed: int
) -> dict:
    """IoU per occlusion-ratio bin and type (Fig. 3.10), ``per_bin`` samples per type and bin."""
    rng = np.random.default_rng(seed)
    bins = list(zip(BINS[:-1], BINS[1:], strict=True))
    res: dict[str, dict[str, list[float]]] = {}
    by_type: dict[str, list[int]] = {}
    for it in items:
        t = OBJECT_TYPES[int(data["type_id"][int(data["shape_idx"][it])])]
        if t in PRIMITIVE_TYPES:
            by_type.setdefault(t, []).append(it)
    for t, its in by_type.items():
        counts = [0] * len(bins)
        tries = 0
        while min(counts) < per_bin and tries < 60 * per_bin * len(bins):
            tries += 1
            it = its[tries % len(its)]
            pts = data["partial"][it].astype(np.float64)
            eye = data["camera"][it][:3, 3].astype(np.float64)
            kept, ratio = occlude(pts, eye, rng) if tries % 7 else (pts, 0.0)
            b = next((i for i, (lo, hi) in enumerate(bins) if lo <= ratio < hi), None)
            if b is None or counts[b] >= per_bin or len(kept) < MIN_POINTS:
                continue
            counts[b] += 1
            parts = net.predict([resample(kept, N_INPUT, rng)])
            iou = volume_iou(parts, _gt_parts(data, int(data["shape_idx"][it])), n=iou_n,
                             generator=tries)  # fmt: skip
            key = f"{int(100 * bins[b][0])}-{int(100 * bins[b][1])}%"
            res.setdefault(t, {}).setdefault(key, []).append(float(iou))
    return res


# --- printing ------------------------------------------------------------------------------------


def _mean(x) -> float:
    return float(np.mean(x)) if len(x) else float("nan")


def _table(title: str, rows: list[str], cols: list[str], cell, thesis_cols=(), thesis=None):
    print(f"\n{title}")
    head = ["type", *cols, *[f"{c} (thesis)" for c in thesis_cols]]
    widths = [max(12, len(h) + 1) for h in head]
    print("".join(h.rjust(w) for h, w in zip(head, widths, strict=True)))
    for r in rows:
        vals = [cell(r, c) for c in cols]
        th = list(thesis.get(r, ())) if thesis else []
        line = [NAMES.get(r, r)] + [f"{v:.4f}" if v == v else "-" for v in vals]
        line += [f"{v:.4f}" for v in th] + ["-"] * (len(thesis_cols) - len(th))
        print("".join(s.rjust(w) for s, w in zip(line, widths, strict=True)))


def summarise(res: dict, types: tuple[str, ...], names: list[str]) -> dict:
    """Mean IoU, median wall and CPU ms per type and method, and the mean over the types."""

    def stats(recs: list[dict]) -> dict:
        def pool(key: str) -> list[float]:
            return [v for r in recs for v in r[key]]

        return {"iou": _mean(pool("iou")), "ms_median": float(np.median(pool("ms"))),
                "cpu_ms_median": float(np.median(pool("cpu_ms"))), "n": len(pool("iou"))}  # fmt: skip

    out = {t: {m: stats([res[t][m]]) for m in names} for t in types if t in res}
    present = [t for t in types if t in out]
    out["Average"] = {m: stats([res[t][m] for t in present]) for m in names}
    for m in names:  # the thesis averages per type, not per item
        out["Average"][m]["iou"] = _mean([out[t][m]["iou"] for t in present])
    return out


def iou_time_png(points: dict[str, tuple[float, float]]) -> str:
    """Fig. 3.6: mean IoU against median recognition time per object, one point per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.2))
    for name, (ms, iou) in points.items():
        ax.scatter([ms], [iou], s=40)
        ax.annotate(name, (ms, iou), textcoords="offset points", xytext=(5, 4), fontsize=8)
    ax.axhline(THESIS_33["Average"][3], ls="--", lw=0.8, color="gray")
    ax.annotate("thesis DSQNet (RTX 3090, 43 ms)", (ax.get_xlim()[0], THESIS_33["Average"][3]),
                textcoords="offset points", xytext=(4, 3), fontsize=7, color="gray")  # fmt: skip
    ax.set_xscale("log")
    ax.set_xlabel("recognition time per object (ms, median, 1 CPU thread)")
    ax.set_ylabel("mean volumetric IoU (object dataset)")
    ax.set_title("IoU against recognition time (Fig. 3.6 layout)", fontsize=10)
    fig.tight_layout()
    PNG.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(PNG, dpi=120)
    plt.close(fig)
    return str(PNG)


def occlusion_png(per_type: dict[str, dict[str, float]], mean: dict[str, float], name: str) -> str:
    """Fig. 3.10: IoU against occlusion ratio, one line per primitive type and the mean."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = list(mean)
    x = [0.5 * (lo + hi) * 100 for lo, hi in zip(BINS[:-1], BINS[1:], strict=True)]
    fig, (left, right) = plt.subplots(1, 2, figsize=(9, 3.8), sharey=True)
    for t, curve in per_type.items():
        left.plot(x, [curve.get(k, float("nan")) for k in keys], marker="o", ms=3, label=t)
    right.plot(x, [mean[k] for k in keys], marker="o", color="k", label="mean")
    right.axhline(0.7, ls="--", lw=0.8, color="gray")
    for ax in (left, right):
        ax.set_xlabel("occlusion ratio (%)")
        ax.legend(fontsize=7)
    left.set_ylabel(f"volumetric IoU ({name})")
    fig.suptitle("IoU against occlusion ratio (Fig. 3.10 layout; dashed: 0.7)", fontsize=10)
    fig.tight_layout()
    fig.savefig(OCCLUSION_PNG, dpi=120)
    plt.close(fig)
    return str(OCCLUSION_PNG)


# --- main ----------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="few items per type (minutes)")
    ap.add_argument("--data", default="runs/recognition_data", help="primitive dataset root")
    ap.add_argument("--object-data", default="runs/recognition_bench_objects")
    ap.add_argument("--object-shapes", type=int, default=2)
    ap.add_argument("--object-views", type=int, default=8)
    ap.add_argument(
        "--models",
        nargs="*",
        default=DEFAULT_MODELS,
        help="network checkpoint directories, one column each (default: %(default)s)",
    )
    ap.add_argument(
        "--segmentation",
        choices=["labels", "network"],
        default="labels",
        help="cut object clouds into parts by the ground-truth labels or by the "
        "segmentation network (--segnet)",
    )
    ap.add_argument("--segnet", default="models/segnet_cpu", help="segmentation checkpoint")
    ap.add_argument("--per-type", type=int, default=None, help="test items per type (all)")
    ap.add_argument("--occlusion-per-bin", type=int, default=None)
    ap.add_argument("--methods", nargs="*", default=None,
                    help="subset of MVBB DSQOpt optimization network hybrid (default: all)")  # fmt: skip
    ap.add_argument("--no-occlusion", action="store_true", help="skip the Fig. 3.10 curve")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    per_type = args.per_type if args.per_type is not None else (4 if args.quick else None)
    per_bin = args.occlusion_per_bin or (2 if args.quick else 10)
    iou_n = 10_000 if args.quick else 40_000
    facts = machine_facts()
    print(f"command: {facts['command']}")
    print(f"machine: {facts['processor']}, {facts['cores']} cores, torch {facts['torch']}, "
          f"{facts['torch_threads']} torch thread, load {facts['load_average']}")  # fmt: skip

    models = [Path(m) for m in args.models if (Path(m) / "model.pt").exists()]
    for m in args.models:
        if Path(m) not in models:
            print(f"note: no checkpoint in {m}, skipped")
    methods = Methods(models, PerceptionSettings(), args.methods)
    results: dict = {"machine": facts, "methods": methods.names, "models": [str(m) for m in
                     models], "per_type": per_type}  # fmt: skip

    prim = load_dataset(args.data, "primitive")
    items = _pick(prim, PRIMITIVE_TYPES, per_type, args.seed)
    t0 = time.time()
    res = evaluate(methods, prim, items, iou_n, args.seed)
    t32 = summarise(res, PRIMITIVE_TYPES, methods.names)
    results["table_3_2_primitive"] = t32
    _table(f"Table 3.2 layout: IoU, primitive dataset test split ({len(items)} views, "
           f"{time.time() - t0:.0f} s)", [*PRIMITIVE_TYPES, "Average"], methods.names,
           lambda r, c: t32.get(r, {}).get(c, {}).get("iou", float("nan")),
           ("DSQOpt", "DSQNet"),
           {t: (THESIS_32["DSQOpt"][t], THESIS_32["DSQNet"][t]) for t in PRIMITIVE_TYPES}
           | {"Average": (np.mean(list(THESIS_32["DSQOpt"].values())),
                          np.mean(list(THESIS_32["DSQNet"].values())))})  # fmt: skip

    obj_root = Path(args.object_data)
    if not (obj_root / "object").is_dir():
        print(f"\ngenerating the object test set in {obj_root} ...", flush=True)
        spec = GenerationSpec(out=str(obj_root), datasets=("object",), shapes=args.object_shapes,
                              n_views=args.object_views, seed=args.seed)  # fmt: skip
        generate(spec, workers=1, progress=False)
    obj = load_dataset(obj_root, "object")
    items = _pick(obj, OBJECT_TYPES, per_type, args.seed)
    segmenter = None
    if args.segmentation == "network":
        segmenter = NetworkSegmenter.load(args.segnet, device="cpu")
    results["segmentation"] = args.segmentation
    t0 = time.time()
    res = evaluate(methods, obj, items, iou_n, args.seed + 1, segmenter)
    t33 = summarise(res, OBJECT_TYPES, methods.names)
    results["table_3_3_object"] = t33
    cut = "ground-truth part labels" if segmenter is None else "segmentation network"
    _table(f"Table 3.3 layout: IoU, object dataset test split ({len(items)} views, {cut}, "
           f"{time.time() - t0:.0f} s)", [*OBJECT_TYPES, "Average"], methods.names,
           lambda r, c: t33.get(r, {}).get(c, {}).get("iou", float("nan")),
           ("MVBB", "PS-CNN", "SQNet", "DSQNet"), THESIS_33)  # fmt: skip
    t35 = summarise(res, MULTI_PART_TYPES, methods.names)
    results["table_3_5_multipart"] = t35
    _table("Table 3.5 layout: IoU, multi-part objects", [*MULTI_PART_TYPES, "Average"],
           methods.names, lambda r, c: t35.get(r, {}).get(c, {}).get("iou", float("nan")),
           ("SQNet", "DSQNet", "DSQNet+"), THESIS_35)  # fmt: skip

    print("\nRecognition time per object (median over the object test items, 1 torch thread;"
          " CPU ms is this process's CPU time, less sensitive to the machine's load)")  # fmt: skip
    timing = {m: t33["Average"][m]["ms_median"] for m in methods.names}
    for m in methods.names:
        a = t33["Average"][m]
        print(f"  {m:>28s} {a['ms_median']:9.1f} ms wall {a['cpu_ms_median']:9.1f} ms CPU"
              f"   IoU {a['iou']:.4f}")  # fmt: skip
    results["time_ms_per_object"] = timing
    results["cpu_ms_per_object"] = {m: t33["Average"][m]["cpu_ms_median"] for m in methods.names}
    fig36 = {m: (timing[m], t33["Average"][m]["iou"]) for m in methods.names}
    results["fig_3_6_iou_vs_ms"] = fig36
    print(f"Fig. 3.6 PNG: {iou_time_png(fig36)}")

    if methods.nets and not args.no_occlusion:
        # Fig. 3.10 is DSQNet's; the first network given stands in when there is none
        name, net = next(
            ((n, r) for n, r in methods.nets.items() if r is methods.hybrid_base),
            next(iter(methods.nets.items())),
        )
        t0 = time.time()
        occ = occlusion_curve(net, obj, _pick(obj, PRIMITIVE_TYPES, None, args.seed), per_bin,
                              iou_n, args.seed + 2)  # fmt: skip
        keys = [f"{int(100 * lo)}-{int(100 * hi)}%" for lo, hi in zip(BINS[:-1], BINS[1:],
                                                                    strict=True)]  # fmt: skip
        print(
            f"\nFig. 3.10 layout: {name} IoU vs occlusion ratio ({per_bin} per type and bin, "
            f"{time.time() - t0:.0f} s)"
        )
        print("type".rjust(8) + "".join(k.rjust(9) for k in keys))
        curve = {}
        for t in PRIMITIVE_TYPES:
            if t in occ:
                print(t.rjust(8) + "".join(f"{_mean(occ[t].get(k, [])):9.3f}" for k in keys))
        for k in keys:
            curve[k] = _mean([v for t in occ for v in occ[t].get(k, [])])
        print("mean".rjust(8) + "".join(f"{curve[k]:9.3f}" for k in keys))
        per_type = {t: {k: _mean(v) for k, v in d.items()} for t, d in occ.items()}
        results["fig_3_10_occlusion"] = {"network": name, "per_type": per_type, "mean": curve}
        print("thesis Fig. 3.10: mean IoU stays above 0.7 up to 25-30 % occlusion")
        print(f"Fig. 3.10 PNG: {occlusion_png(per_type, curve, name)}")

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1, default=float))
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
