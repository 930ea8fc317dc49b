"""Train DSQNet / SQNet / DSQNet+ / the segmentation network (A.2): ``sqmanip train <model>``.

Adam, learning rate 1e-3, batch size 16 (A.2). DSQNet and SQNet train on the primitive dataset
(300-point segments), DSQNet+ on the parts of the object dataset (whole object with the segment
channel), the segmentation network on the object dataset with the Hungarian-matched loss.

Outputs in ``--out``: ``checkpoint.pt`` (model + optimiser state + step, loadable with
``torch.load(weights_only=True)``), ``model.pt`` (state dict only), ``config.toml`` (model and
train config, what :class:`~.infer.NetworkRecognizer` loads) and ``log.csv``. ``--resume``
continues from ``checkpoint.pt``; batches depend only on ``(seed, step)``, so a resumed run sees
the same batches as an uninterrupted one. ``--max-minutes`` stops at a wall-clock budget.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import logging
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .config import (
    MODEL_NAMES,
    ModelConfig,
    TrainConfig,
    as_table,
    load_preset,
    to_toml,
)
from .datasets import ObjectPartDataset, PrimitiveDataset, SegBatch, SegmentationDataset, SQBatch
from .losses import (
    dsq_loss,
    matched_accuracy,
    segmentation_loss,
    shape_parameter_loss,
    surface_to_points,
)
from .models import build_model, count_parameters

__all__ = [
    "add_cli",
    "build_datasets",
    "evaluate",
    "load_initial_weights",
    "save_model_dir",
    "train",
    "train_step",
]

log = logging.getLogger(__name__)
LOG_FIELDS = ("step", "epoch", "elapsed_s", "split", "loss", "dist", "z_reg", "surface", "shape",
              "acc", "iou")  # fmt: skip


def _device(cfg: TrainConfig) -> torch.device:
    if cfg.device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(cfg.device)


def build_datasets(name: str, data: str | Path, mcfg: ModelConfig, tcfg: TrainConfig):
    """(train, test) datasets for model ``name`` from a generated data directory."""
    if name in ("dsqnet", "sqnet"):
        train_ds = PrimitiveDataset(data, "train", n_points=mcfg.n_points, n_gt=tcfg.n_gt)
        test_ds = PrimitiveDataset(
            data, "test", n_points=mcfg.n_points, n_gt=tcfg.n_gt, data=train_ds.data
        )
    elif name == "dsqnet_plus":
        train_ds = ObjectPartDataset(data, "train", n_points=mcfg.n_points, n_gt=tcfg.n_gt)
        test_ds = ObjectPartDataset(
            data, "test", n_points=mcfg.n_points, n_gt=tcfg.n_gt, data=train_ds.data
        )
    elif name == "segnet":
        train_ds = SegmentationDataset(data, "train", n_points=mcfg.n_points)
        test_ds = SegmentationDataset(data, "test", n_points=mcfg.n_points, data=train_ds.data)
    else:
        raise ValueError(f"Unknown model name {name!r}. Available models: {list(MODEL_NAMES)}")
    if len(train_ds) == 0:
        raise ValueError(f"no training items for {name!r} under {data}")
    return train_ds, test_ds


def load_initial_weights(model: nn.Module, source: str | Path) -> list[str]:
    """Start ``model`` from the weights in ``source`` (``model.pt`` or its directory).

    Every tensor must match in shape, except a first layer that reads more input channels than
    the source's (DSQNet+ from DSQNet, 3.6.2: 4-d points instead of 3-d): its weights on the
    source's channels are copied and those on the new channels start at zero, so the network
    begins as the source network that ignores the segment channel. Returns the names of the
    tensors widened that way; any other mismatch is a ``ValueError`` naming the tensor.
    """
    src = Path(source)
    src = src / "model.pt" if src.is_dir() else src
    if not src.is_file():
        raise FileNotFoundError(f"no weights at {src}")
    theirs = torch.load(src, map_location="cpu", weights_only=True)
    ours = model.state_dict()
    if set(theirs) != set(ours):
        missing, extra = sorted(set(ours) - set(theirs)), sorted(set(theirs) - set(ours))
        raise ValueError(f"{src} does not fit this model: missing {missing}, unexpected {extra}")
    widened = []
    first = "encoder.edges.0.mlp.0.weight"  # EdgeConv weight over [x_j - x_i, x_i]
    for name, t in theirs.items():
        if t.shape == ours[name].shape:
            ours[name] = t
        elif name == first and t.shape[1] < ours[name].shape[1] and t.shape[1] % 2 == 0:
            c_old, c_new = t.shape[1] // 2, ours[name].shape[1] // 2
            w = torch.zeros_like(ours[name])
            w[:, :c_old] = t[:, :c_old]
            w[:, c_new : c_new + c_old] = t[:, c_old:]
            ours[name] = w
            widened.append(name)
        else:
            raise ValueError(
                f"{src}: tensor {name} has shape {tuple(t.shape)}, this model "
                f"{tuple(ours[name].shape)}"
            )
    model.load_state_dict(ours)
    return widened


def _loss(model: nn.Module, batch, tcfg: TrainConfig):
    if isinstance(batch, SegBatch):
        return segmentation_loss(model(batch.x), batch.labels)
    pred = model(batch.x)
    loss, logs = dsq_loss(pred, batch.gt, batch.gt_z, z_weight=tcfg.z_weight)
    if tcfg.surface_weight > 0:
        term = surface_to_points(pred, batch.gt)
        loss = loss + tcfg.surface_weight * term
        logs["surface"] = float(term.detach())
    if tcfg.shape_weight > 0:
        gt_rotation = batch.frame.rotation.transpose(1, 2) @ batch.gt_pose[:, :3, :3]
        term = shape_parameter_loss(
            pred,
            batch.frame.params_to_normalized(batch.gt_params),
            gt_rotation,
            deformable=model.config.deformable,
            size_weight=tcfg.size_weight,
            bend_bounds=model.config.bend_bounds,
        )
        loss = loss + tcfg.shape_weight * term
        logs["shape"] = float(term.detach())
    logs["loss"] = float(loss.detach())
    return loss, logs


def train_step(
    model: nn.Module, batch: SQBatch | SegBatch, optimizer: torch.optim.Optimizer, tcfg: TrainConfig
) -> dict[str, float]:
    """One Adam step on ``batch``; returns the logged loss terms."""
    model.train()
    optimizer.zero_grad(set_to_none=True)
    loss, logs = _loss(model, batch, tcfg)
    if not torch.isfinite(loss):
        raise FloatingPointError(f"non-finite training loss {float(loss)}")
    loss.backward()
    optimizer.step()
    return logs


def _sq_iou(model: nn.Module, batch: SQBatch, n_samples: int = 20_000) -> list[float]:
    from sqmanip.geometry.iou import volume_iou

    from .infer import to_superquadric

    pred = model(batch.x)
    pose = batch.frame.pose_to_world(pred.pose()).double().cpu().numpy()
    params = batch.frame.params_to_world(pred.params()).double().cpu().numpy()
    gp, gT = batch.gt_params.double().cpu().numpy(), batch.gt_pose.double().cpu().numpy()
    return [
        volume_iou(
            [to_superquadric(params[i], pose[i])],
            [to_superquadric(gp[i], gT[i])],
            n=n_samples,
            generator=i,
        )  # fmt: skip
        for i in range(len(pose))
    ]


@torch.no_grad()
def evaluate(
    model: nn.Module, dataset, tcfg: TrainConfig, device: torch.device | str = "cpu"
) -> dict[str, float]:
    """Mean test loss terms over ``dataset``; plus matched accuracy (segmentation) or the mean
    volumetric IoU of the first ``eval_iou_items`` evenly spaced items (superquadrics)."""
    model.eval()
    n = len(dataset)
    if n == 0:
        return {}
    sums: dict[str, float] = {}
    bs = max(tcfg.batch_size, 32)
    for s in range(0, n, bs):
        idx = list(range(s, min(n, s + bs)))
        batch = dataset.batch(idx, torch.Generator().manual_seed(s)).to(device)
        _, logs = _loss(model, batch, tcfg)
        if isinstance(batch, SegBatch):
            logs["acc"] = float(matched_accuracy(model(batch.x), batch.labels).mean())
        for k, v in logs.items():
            sums[k] = sums.get(k, 0.0) + v * len(idx)
    out = {k: v / n for k, v in sums.items()}
    if tcfg.eval_iou_items > 0 and not isinstance(dataset, SegmentationDataset):
        m = min(n, tcfg.eval_iou_items)
        pick = np.unique(np.linspace(0, n - 1, m).round().astype(int))
        ious: list[float] = []
        for s in range(0, len(pick), bs):
            b = dataset.batch(pick[s : s + bs], torch.Generator().manual_seed(s)).to(device)
            ious += _sq_iou(model, b)
        out["iou"] = float(np.mean(ious))
    return out


def save_model_dir(
    out: str | Path, model: nn.Module, mcfg: ModelConfig, tcfg: TrainConfig, info: dict
) -> None:
    """``model.pt`` (state dict) and ``config.toml`` (what :class:`NetworkRecognizer` loads)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.save({k: v.detach().cpu() for k, v in model.state_dict().items()}, out / "model.pt")
    tables = {"model": as_table(mcfg), "train": as_table(tcfg), "info": info}
    (out / "config.toml").write_text(to_toml(tables))


class _CsvLog:
    def __init__(self, path: Path, append: bool) -> None:
        new = not (append and path.exists())
        self.fh = path.open("w" if new else "a", newline="")
        self.w = csv.DictWriter(self.fh, LOG_FIELDS, extrasaction="ignore")
        if new:
            self.w.writeheader()

    def row(self, **kw) -> None:
        self.w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in kw.items()})
        self.fh.flush()

    def close(self) -> None:
        self.fh.close()


def train(
    name: str,
    mcfg: ModelConfig,
    tcfg: TrainConfig,
    data: str | Path,
    out: str | Path,
    *,
    resume: bool = False,
    max_minutes: float | None = None,
    progress: bool = True,
    datasets=None,
    init_from: str | Path | None = None,
) -> dict:
    """Train ``name`` and write checkpoints, ``model.pt``, ``config.toml`` and ``log.csv``.

    Returns ``{"steps", "train", "test", "parameters", "minutes"}`` (last train-window and final
    test metrics). ``datasets`` may pass prebuilt ``(train, test)`` datasets. ``init_from``: a
    fresh run starts from those weights (:func:`load_initial_weights`); a resumed one ignores it.
    """
    from tqdm import tqdm

    t0 = time.time()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if tcfg.num_threads > 0:
        torch.set_num_threads(tcfg.num_threads)
    torch.manual_seed(tcfg.seed)
    device = _device(tcfg)
    train_ds, test_ds = datasets if datasets is not None else build_datasets(name, data, mcfg, tcfg)
    model = build_model(name, mcfg).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=tcfg.lr)
    step = 0
    ckpt_path = out / "checkpoint.pt"
    if resume and ckpt_path.exists():
        ckpt = torch.load(ckpt_path, map_location=device, weights_only=True)
        model.load_state_dict(ckpt["model"])
        opt.load_state_dict(ckpt["optimizer"])
        step = int(ckpt["step"])
        log.info("resumed %s at step %d", name, step)
    elif init_from is not None:
        widened = load_initial_weights(model, init_from)
        log.info("initialised %s from %s (widened: %s)", name, init_from, widened or "none")
    csv_log = _CsvLog(out / "log.csv", append=resume and step > 0)
    n = len(train_ds)
    per_epoch = max(1, n // tcfg.batch_size)
    total = min(tcfg.max_steps, tcfg.epochs * per_epoch)
    info = {"model": name, "data": str(data), "train_items": n, "test_items": len(test_ds),
            "parameters": count_parameters(model)}  # fmt: skip
    if init_from is not None:
        info["init_from"] = str(init_from)

    def save() -> None:
        torch.save(
            {"model": model.state_dict(), "optimizer": opt.state_dict(), "step": step},
            ckpt_path.with_suffix(".tmp"),
        )
        ckpt_path.with_suffix(".tmp").replace(ckpt_path)
        save_model_dir(out, model, mcfg, tcfg, {**info, "step": step})

    window: dict[str, list[float]] = {}
    last_train: dict[str, float] = {}
    bar = tqdm(total=total, initial=step, disable=not progress, unit="step", desc=name)
    perm, perm_epoch = None, -1
    budget_hit = False
    while step < total:
        epoch = step // per_epoch
        if epoch != perm_epoch:
            g_epoch = torch.Generator().manual_seed(tcfg.seed * 100_003 + epoch)
            perm, perm_epoch = torch.randperm(n, generator=g_epoch).numpy(), epoch
        j = step % per_epoch
        idx = perm[j * tcfg.batch_size : (j + 1) * tcfg.batch_size]
        batch = train_ds.batch(idx, torch.Generator().manual_seed(tcfg.seed * 1_000_003 + step))
        for group in opt.param_groups:
            group["lr"] = tcfg.lr_at(step)
        logs = train_step(model, batch.to(device), opt, tcfg)
        step += 1
        for k, v in logs.items():
            window.setdefault(k, []).append(v)
        bar.update()
        if step % tcfg.log_every == 0 or step == total:
            last_train = {k: float(np.mean(v)) for k, v in window.items()}
            bar.set_postfix(loss=f"{last_train['loss']:.4g}")
            csv_log.row(step=step, epoch=epoch, elapsed_s=time.time() - t0, split="train",
                        **last_train)  # fmt: skip
            window = {}
        budget_hit = max_minutes is not None and time.time() - t0 > 60 * max_minutes
        if step % tcfg.checkpoint_every == 0:
            save()
        if step % tcfg.eval_every == 0 and step < total and not budget_hit:
            ev = evaluate(model, test_ds, tcfg, device)
            csv_log.row(step=step, epoch=epoch, elapsed_s=time.time() - t0, split="test", **ev)
            log.info("step %d test %s", step, ev)
        if budget_hit:
            log.info("time budget of %s min reached at step %d", max_minutes, step)
            break
    bar.close()
    if window:
        last_train = {k: float(np.mean(v)) for k, v in window.items()}
    save()
    ev = evaluate(model, test_ds, tcfg, device)
    csv_log.row(step=step, epoch=step // per_epoch, elapsed_s=time.time() - t0, split="test", **ev)
    csv_log.close()
    info.update(step=step, minutes=round((time.time() - t0) / 60, 2))
    info.update({f"test_{k}": v for k, v in ev.items()})
    save_model_dir(out, model, mcfg, tcfg, info)
    return {"steps": step, "train": last_train, "test": ev, "parameters": info["parameters"],
            "minutes": info["minutes"]}  # fmt: skip


# --- CLI -------------------------------------------------------------------------------------------


def _run_cli(args: argparse.Namespace) -> int:
    mcfg, tcfg = load_preset(args.model, args.config)
    keys = ("seed", "batch_size", "max_steps", "epochs", "device", "lr_schedule")
    over = {k: getattr(args, k) for k in keys}
    over = {k: v for k, v in over.items() if v is not None}
    if over:
        tcfg = dataclasses.replace(tcfg, **over)
    res = train(args.model, mcfg, tcfg, args.data, args.out, resume=args.resume,
                max_minutes=args.max_minutes, init_from=args.init_from)  # fmt: skip
    print({k: (round(v, 5) if isinstance(v, float) else v) for k, v in res.items()})
    return 0


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """Register ``dsqnet``, ``sqnet``, ``dsqnet_plus`` and ``segnet`` under a ``train`` command."""
    helps = {
        "dsqnet": "DSQNet (3.3) on the primitive dataset",
        "sqnet": "SQNet (plain superquadrics, 3.5.2) on the primitive dataset",
        "dsqnet_plus": "DSQNet+ (object context, 3.6.2) on the object dataset",
        "segnet": "DGCNN segmentation with the Hungarian loss (A.2) on the object dataset",
    }
    for name in MODEL_NAMES:
        p = subparsers.add_parser(name, help=helps[name], description=__doc__,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
        p.add_argument("--config", default="cpu",
                       help="preset name (cpu | gpu) or a TOML file (default cpu)")  # fmt: skip
        p.add_argument("--data", required=True, help="directory from `sqmanip data recognition`")
        p.add_argument("--out", required=True, help="output directory")
        p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
        p.add_argument("--max-minutes", type=float, default=None, help="wall-clock budget")
        p.add_argument("--init-from", default=None, metavar="PATH",
                       help="fresh run: start from these weights (model.pt or its directory); "
                            "DSQNet+ can start from a DSQNet")  # fmt: skip
        p.add_argument("--seed", type=int, default=None)
        p.add_argument("--batch-size", type=int, default=None)
        p.add_argument("--max-steps", type=int, default=None)
        p.add_argument("--epochs", type=int, default=None)
        p.add_argument("--device", choices=["cpu", "cuda", "auto"], default=None)
        p.add_argument("--lr-schedule", choices=["constant", "cosine"], default=None,
                       help="cosine: decay the learning rate to lr_final over --max-steps")  # fmt: skip
        p.set_defaults(func=_run_cli, model=name)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sqmanip.perception.learned.train")
    sub = parser.add_subparsers(dest="command", required=True)
    add_cli(sub)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
