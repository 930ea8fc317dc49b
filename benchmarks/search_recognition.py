"""Recognition on the shelf: recognized against true shapes of the surrounding objects, per
recognition method, on saved shelf scenarios (the first camera image of each).

Prints, per method, how far the recognized grasp width (the smaller level extent, what the C.3
side grasps close across) is off for boxes and cylinders, and how many objects the 7.5 cm grasp
rule of the search accepts on the true shape but rejects on the recognized one ("lost"): such
an object cannot be picked, and its inflated shape also narrows the gaps a push needs. Saves a
JSON under ``benchmarks/results/``.

    python -m benchmarks.search_recognition [--objects 8] [--scenes 12] [--methods ...]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

RESULTS = os.path.join(os.path.dirname(__file__), "results")
SCENARIOS = os.path.join(RESULTS, "search_scenarios_seed700_35x.json")


def grasp_width(part) -> float:
    """Smaller level full extent of a standing shape (its axis nearest vertical excluded)."""
    a = np.abs(np.asarray(part.size, np.float64))
    vertical = int(np.argmax(np.abs(np.asarray(part.pose)[2, :3])))
    return 2.0 * min(a[i] for i in range(3) if i != vertical)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--objects", type=int, default=8, choices=(6, 8))
    ap.add_argument("--scenes", type=int, default=12, help="first N saved scenarios")
    ap.add_argument("--methods", nargs="+", default=["optimization", "hybrid"])
    ap.add_argument("--scenarios", default=SCENARIOS)
    ap.add_argument("--out", default=os.path.join(RESULTS, "search_recognition.json"))
    args = ap.parse_args(argv)

    import torch
    from sqmanip.search import KinematicPushDynamics, SearchPlanner
    from sqmanip.search.config import SearchConfig
    from sqmanip.search.episode import SHELF_CAMERA, EpisodeRunner
    from sqmanip.search.scenarios import ShelfScenario
    from sqmanip.sim import Simulator

    torch.set_num_threads(1)
    with open(args.scenarios) as f:
        scenes = json.load(f)[str(args.objects)][: args.scenes]
    max_width = SearchConfig().grasp_max_width
    sim = Simulator()
    planner = SearchPlanner(KinematicPushDynamics())
    rows = []
    for method in args.methods:
        runner = EpisodeRunner(sim, planner, shapes="recognized", recognition=method)
        err = {"box": [], "cylinder": []}
        lost = gained = holdable = 0
        t_rec = []
        for k, sc in enumerate(scenes):
            scenario = ShelfScenario.from_dict(sc)
            sim.reset(scenario.scene)
            obs = sim.observe("shelf", intrinsics=SHELF_CAMERA)
            t = time.perf_counter()
            parts, ids = runner.recognize(obs, scenario.target_index)
            t_rec.append(time.perf_counter() - t)
            for o in obs.objects:
                if o.id == scenario.target_index or o.superquadric is None:
                    continue
                mine = [p for p, i in zip(parts, ids, strict=True) if i == o.id]
                if not mine:
                    continue
                w_true, w_rec = grasp_width(o.superquadric), grasp_width(mine[0])
                kind = "box" if scenario.scene.objects[o.id].kind == "box" else "cylinder"
                err[kind].append(w_rec - w_true)
                holdable += w_true <= max_width
                lost += w_true <= max_width < w_rec
                gained += w_rec <= max_width < w_true
            print(f"  {method}: scene {k + 1}/{len(scenes)}", file=sys.stderr, flush=True)
        row = dict(
            method=method,
            holdable=int(holdable),
            lost=int(lost),
            gained=int(gained),
            recognize_ms=float(np.median(t_rec) * 1e3),
        )
        for kind, v in err.items():
            v = np.asarray(v) * 100
            row[f"{kind}_n"] = len(v)
            row[f"{kind}_width_err_cm"] = float(v.mean()) if len(v) else float("nan")
            row[f"{kind}_width_abs90_cm"] = float(np.percentile(np.abs(v), 90)) if len(v) else 0.0
        rows.append(row)

    print(f"{args.objects}-object shelf scenes: {len(scenes)} ({args.scenarios}); grasp rule "
          f"<= {max_width * 100:.1f} cm")  # fmt: skip
    print("| method | holdable (true) | lost by recognition | gained | box width err (mean, "
          "|90%|) cm | cylinder width err cm | recognize ms (median) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['method']} | {r['holdable']} | {r['lost']} | {r['gained']} | "
            f"{r['box_width_err_cm']:+.2f}, {r['box_width_abs90_cm']:.2f} | "
            f"{r['cylinder_width_err_cm']:+.2f}, {r['cylinder_width_abs90_cm']:.2f} | "
            f"{r['recognize_ms']:.0f} |"
        )
    with open(args.out, "w") as f:
        json.dump({"args": vars(args), "rows": rows}, f, indent=1)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
