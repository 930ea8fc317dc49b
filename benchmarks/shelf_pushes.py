"""Where the robot can push in the shelf: the level hand of 5.4.4 and the upright one.

Run: ``python -m benchmarks.shelf_pushes [--no-png]``. One cylinder (r 3 cm, h 12 cm) stands at
each of 25 floor positions (x 0.56 to 0.80 m, y -0.2 to 0.2 m) and is pushed 10 cm to each side,
the hand starting 1 cm from it as the search planner places it
(:meth:`sqmanip.search.ActionSampler.push_poses`: the level hand's fingers, the upright hand's
palm side); then a cylinder 8 to 11 cm from the left board is pushed away from it by the
upright hand. Prints the executed pushes, the refusals by
reason and the mean distance moved; writes ``benchmarks/results/shelf_pushes.json`` and a map
(PNG) of the floor positions that were refused.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import time
from pathlib import Path

import numpy as np
from sqmanip.errors import PreconditionError
from sqmanip.grasping import PANDA_HAND
from sqmanip.search.actions import UPRIGHT_FLOOR_GAP
from sqmanip.sim import ObjectSpec, SceneSpec, Simulator

RESULTS = Path(__file__).parent / "results" / "shelf_pushes.json"
RADIUS, HEIGHT, GAP, PUSH = 0.03, 0.12, 0.01, 0.10


def push_once(sim: Simulator, x: float, y: float, direction: int, upright: bool):
    """``(outcome, moved)``: 'ok' or the refusal's reason, and how far the cylinder moved."""
    s = sim.config.shelf
    cyl = ObjectSpec("cylinder", radius=RADIUS, height=HEIGHT)
    sim.reset(
        SceneSpec(
            kind="shelf",
            objects=(cyl.with_pose((x, y, s.bottom_z + HEIGHT / 2 + 1e-4), (0, 0, 0, 1)),),
        )
    )
    hand = PANDA_HAND
    lead = hand.palm_size[0] / 2 if upright else hand.finger_thickness
    z = s.bottom_z + (hand.palm_size[1] / 2 + UPRIGHT_FLOOR_GAP if upright else HEIGHT / 2)
    p = np.array([x, y - direction * (RADIUS + GAP + lead), z])
    try:
        sim.push(p, np.array([0.0, direction * PUSH, 0.0]), upright=upright)
    except PreconditionError as exc:
        reason = str(exc).split(" at [")[0].split(" (IK")[0]
        return reason.replace("push unreachable: ", ""), 0.0
    return "ok", direction * float(sim.get_state().objects[0].pose[1, 3] - y)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-png", action="store_true", help="skip the map")
    args = ap.parse_args(argv)
    print("command:", " ".join([sys.executable, "-m", "benchmarks.shelf_pushes", *(argv or [])]))
    sim = Simulator()
    grid = [(x, y) for x in (0.56, 0.62, 0.68, 0.74, 0.80) for y in (-0.2, -0.1, 0.0, 0.1, 0.2)]
    out: dict = {"floor": {}, "near_board": {}}
    t0 = time.perf_counter()
    print(f"\n{'hand':<8} {'executed':>9} {'moved cm':>9}  refused by reason")
    refused_at = {}
    for upright in (False, True):
        name = "upright" if upright else "level"
        runs = [(x, y, d, *push_once(sim, x, y, d, upright)) for x, y in grid for d in (1, -1)]
        counts = collections.Counter(r[3] for r in runs)
        moved = [r[4] for r in runs if r[3] == "ok"]
        out["floor"][name] = {"runs": len(runs), "outcomes": dict(counts)}
        out["floor"][name]["moved_mean"] = float(np.mean(moved)) if moved else None
        refused_at[name] = [(x, y, d) for x, y, d, why, _ in runs if why != "ok"]
        why = ", ".join(f"{k}: {v}" for k, v in counts.items() if k != "ok")
        print(f"{name:<8} {counts['ok']:>4}/{len(runs):<4} {100 * np.mean(moved):>9.1f}  {why}")
    half_w = sim.config.shelf.inner_width / 2
    print(
        f"\nupright, pushed 10 cm away from the left board (x 0.6, 0.7, 0.78 m)\n{'gap cm':>6} ok"
    )
    for gap in (0.08, 0.09, 0.095, 0.10, 0.11):
        res = [push_once(sim, x, half_w - gap - RADIUS, -1, True)[0] for x in (0.6, 0.7, 0.78)]
        out["near_board"][f"{gap:.2f}"] = res
        print(f"{100 * gap:>6.1f} {sum(r == 'ok' for r in res)}/3  {[r for r in res if r != 'ok']}")
    print(f"\n{time.perf_counter() - t0:.0f} s")
    sim.close()
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {RESULTS}")
    if not args.no_png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axs = plt.subplots(1, 2, figsize=(9, 4.5), sharey=True)
        for ax, (name, bad) in zip(axs, refused_at.items(), strict=True):
            ax.plot([g[1] for g in grid], [g[0] for g in grid], "o", color="0.8", ms=14)
            for x, y, d in bad:
                ax.annotate("", (y + 0.04 * d, x), (y, x), arrowprops={"color": "r"})
            ax.set(title=f"{name} hand: refused pushes (red)", xlabel="y (m)", xlim=(-0.35, 0.35))
        axs[0].set_ylabel("x, depth into the shelf (m)")
        png = RESULTS.with_suffix(".png")
        fig.tight_layout()
        fig.savefig(png, dpi=80)
        print(f"wrote {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
