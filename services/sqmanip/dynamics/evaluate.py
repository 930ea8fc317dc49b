"""Test metrics of a trained pushing dynamics model over a split (Tables 4.2, 4.4).

``python -m sqmanip.dynamics.evaluate --model OUT_DIR --data SPLIT_DIR [--iou3d] [--json F]``
prints the loss (4.3.3), pose errors (cm, deg), full / surface / visible flow RMSE (cm), the
full and visible flow as the authors' code computes them (``*_flow_code``, cm^2,
:func:`.metrics.coordinate_flow_mse`, the definition the thesis' tables are comparable with) and,
when asked, 3D and 2D mask IoU (2D needs a camera: ``meta.camera`` in the split manifest as
``{"fx", "fy", "cx", "cy", "width", "height", "pose"}``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sqmanip.geometry.render import PinholeCamera

from .data import PushTensors, load_split
from .metrics import (
    coordinate_flow_mse,
    flow_rmse,
    mask_iou_2d,
    mask_iou_3d,
    pose_errors,
    surface_points,
    visible_flow_rmse,
    volume_points,
)
from .model import SQPDNet, sqpd_loss

__all__ = [
    "add_code_flows",
    "camera_from_meta",
    "evenly_spaced",
    "evaluate",
    "main",
    "predict_split",
]


@torch.no_grad()
def predict_split(model: SQPDNet, data: PushTensors, batch_size: int = 256) -> torch.Tensor:
    """Predicted next poses ``(S, M, 4, 4)`` of every tuple (in the data's dtype, on CPU)."""
    model.eval()
    ref = next(model.parameters())
    out = [
        model.forward_batch(b.to(ref.device, ref.dtype)).to("cpu", data.batch.poses.dtype)
        for b in data.batches(batch_size)
    ]
    return torch.cat(out) if out else data.batch.poses.clone()


def evenly_spaced(n: int, max_tuples: int | None) -> torch.Tensor:
    """Indices of the tuples a slow metric (mask IoUs, physics) uses: all of the ``n``, or
    ``max_tuples`` evenly spaced.

    Not the first ones: a split is ordered (``unknown`` by object count, its first 300 tuples
    are single-object scenes whose one object is always the pushed one).
    """
    if max_tuples is None or max_tuples >= n:
        return torch.arange(n)
    return torch.linspace(0, n - 1, max_tuples).round().long().unique()


def add_code_flows(res: dict[str, float]) -> dict[str, float]:
    """Add ``full_flow_code`` / ``visible_flow_code`` (cm^2) beside the RMSE entries of ``res``."""
    for kind in ("full", "visible"):
        if f"{kind}_flow_cm" in res:
            res[f"{kind}_flow_code"] = coordinate_flow_mse(res[f"{kind}_flow_cm"])
    return res


def camera_from_meta(meta: dict[str, Any]) -> PinholeCamera | None:
    cam = meta.get("camera")
    if not cam:
        return None
    return PinholeCamera(**{**cam, "pose": np.asarray(cam.get("pose", np.eye(4)))})


@torch.no_grad()
def evaluate(
    model: SQPDNet,
    data: PushTensors,
    *,
    n_points: int = 256,
    iou_3d: bool = False,
    camera: PinholeCamera | None = None,
    max_iou_tuples: int | None = None,
    seed: int = 0,
) -> dict[str, float]:
    """Metrics of ``model`` on ``data`` (object-weighted means; flows are RMSE over points)."""
    b = data.batch
    pred = predict_split(model, data)
    loss, _ = sqpd_loss(pred, b.next_poses, b.mask, model.config.alpha)
    vol, vol_mask = volume_points(b.params, b.kinds, n_points, seed=seed)
    surf = surface_points(b.params, b.kinds, n_points, seed=seed)
    res: dict[str, float] = {
        "tuples": float(len(data)),
        "objects": float(b.mask.sum()),
        "loss": loss.item(),
        **pose_errors(pred, b.next_poses, b.mask),
        "full_flow_cm": flow_rmse(pred, b.next_poses, vol, b.mask, vol_mask),
        "surface_flow_cm": flow_rmse(pred, b.next_poses, surf, b.mask),
    }
    if data.cloud is not None and data.cloud_labels is not None:
        res["visible_flow_cm"] = visible_flow_rmse(
            b.poses, pred, b.next_poses, data.cloud, data.cloud_labels
        )
    add_code_flows(res)
    sel = evenly_spaced(len(data), max_iou_tuples)
    if iou_3d:
        res["mask_iou_3d"] = mask_iou_3d(
            b.params[sel], b.kinds[sel], pred[sel], b.next_poses[sel], b.mask[sel]
        )
    if camera is not None:
        res["mask_iou_2d"] = mask_iou_2d(
            b.params[sel], b.kinds[sel], pred[sel], b.next_poses[sel], b.mask[sel], camera
        )
    return res


def main(argv: list[str] | None = None) -> int:
    from .train import load_model

    parser = argparse.ArgumentParser(
        prog="python -m sqmanip.dynamics.evaluate", description=__doc__
    )
    parser.add_argument("--model", required=True, help="training output directory")
    parser.add_argument("--data", required=True, help="split directory (manifest.json + shards)")
    parser.add_argument("--best", action="store_true", help="use model_best.pt")
    parser.add_argument("--points", type=int, default=256, help="points per object for flows")
    parser.add_argument("--iou3d", action="store_true", help="also compute 3D mask IoU")
    parser.add_argument("--iou-tuples", type=int, help="compute IoUs on the first N tuples only")
    parser.add_argument("--json", help="write the metrics to this file")
    args = parser.parse_args(argv)
    model = load_model(args.model, best=args.best)
    data = load_split(args.data, with_cloud=True)
    res = evaluate(
        model,
        data,
        n_points=args.points,
        iou_3d=args.iou3d,
        camera=camera_from_meta(data.meta),
        max_iou_tuples=args.iou_tuples,
    )
    for key, value in res.items():
        print(f"{key:>18s}  {value:.4f}")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
