"""Training of SQPD-Net and its baseline on pushing tuples (Ch. 4.3 "Training", 4.6.2, 4.7.1).

Adam on the loss (4.3.3); one epoch is one shuffled pass over the training split. Every
``checkpoint_every`` epochs (and at the end) ``out_dir`` gets:

- ``checkpoint.pt``: model + optimizer state, epoch, RNG states (for exact resume);
- ``model.pt``: the model state dict alone, and ``model_best.pt`` at the best validation loss;
- ``config.json``: the :class:`SQPDNetConfig`; ``log.csv``: one row per epoch.

Re-running the same command resumes from ``checkpoint.pt`` (``--no-resume`` starts over).
Seeds fix initialisation, shuffling and augmentation; on CPU a resumed run reproduces an
uninterrupted one exactly.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import logging
import random
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from .baselines import se2_augment
from .config import PRESETS, SQPDNetConfig, baseline_config, get_config
from .data import PushBatch, PushTensors, load_split, synthetic_tuples, tensors_from_tuples
from .model import SQPDNet, make_model, sqpd_loss

__all__ = [
    "add_cli",
    "load_model",
    "main",
    "resolve_device",
    "seed_everything",
    "train",
    "train_step",
    "validate",
]

log = logging.getLogger(__name__)
LOG_FIELDS = [
    "epoch",
    "train_loss",
    "train_translation",
    "train_rotation",
    "val_loss",
    "val_position_cm",
    "val_orientation_deg",
    "seconds",
]


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def resolve_device(config: SQPDNetConfig) -> torch.device:
    if config.device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if config.device == "cuda" and not torch.cuda.is_available():
        raise ValueError("config.device is 'cuda' but no CUDA device is available")
    return torch.device(config.device)


def train_step(
    model: SQPDNet,
    batch: PushBatch,
    optimizer: torch.optim.Optimizer,
    generator: torch.Generator | None = None,
) -> dict[str, float]:
    """One optimiser step on ``batch`` (SE(2)-augmented first if ``config.augment_se2``)."""
    cfg = model.config
    model.train()
    if cfg.augment_se2:
        batch = se2_augment(batch, generator, cfg.augment_translation)
    loss, stats = model.loss(batch)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if cfg.grad_clip is not None:
        torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
    optimizer.step()
    return stats


@torch.no_grad()
def validate(model: SQPDNet, data: PushTensors, batch_size: int = 256) -> dict[str, float]:
    """Loss (4.3.3) and pose errors over a split (object-weighted means)."""
    from .metrics import pose_errors

    model.eval()
    device = next(model.parameters()).device
    dtype = next(model.parameters()).dtype
    preds, targets, masks = [], [], []
    for batch in data.batches(batch_size):
        batch = batch.to(device, dtype)
        preds.append(model.forward_batch(batch))
        targets.append(batch.next_poses)
        masks.append(batch.mask)
    if not preds:
        return {"loss": 0.0, "position_cm": 0.0, "orientation_deg": 0.0}
    pred, target, mask = torch.cat(preds), torch.cat(targets), torch.cat(masks)
    loss, _ = sqpd_loss(pred, target, mask, model.config.alpha)
    return {"loss": loss.item(), **pose_errors(pred, target, mask)}


def _resume_key(config: dict[str, Any]) -> dict[str, Any]:
    """Config fields that must match to resume (epochs may grow, device may change)."""
    return {k: v for k, v in config.items() if k not in ("epochs", "device", "checkpoint_every")}


def _save(path: Path, obj: Any) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    tmp.replace(path)


def train(
    config: SQPDNetConfig,
    train_data: PushTensors,
    val_data: PushTensors | None,
    out_dir: str | Path,
    *,
    resume: bool = True,
    progress: bool = True,
    init_from: str | Path | None = None,
    time_limit_s: float | None = None,
) -> dict[str, Any]:
    """Train and checkpoint into ``out_dir``; returns ``{"history": [...], "model": model}``.

    ``init_from``: a weights file (``model.pt`` state dict) or a directory holding one, loaded
    before the first epoch of a fresh run (fine-tuning a shipped checkpoint on more data; a
    resumed run ignores it). ``time_limit_s``: stop after the first epoch that ends past this
    many seconds of wall time, writing the checkpoint so the same command resumes.
    """
    if len(train_data) == 0:
        raise ValueError("train_data is empty")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    device = resolve_device(config)
    seed_everything(config.seed)
    model = make_model(config).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    generator = torch.Generator().manual_seed(config.seed)
    start_epoch, best = 1, float("inf")
    ckpt_path = out / "checkpoint.pt"
    if resume and ckpt_path.is_file():
        ckpt = torch.load(ckpt_path, map_location=device, weights_only=False)
        if _resume_key(ckpt["config"]) != _resume_key(config.to_dict()):
            raise ValueError(
                f"{ckpt_path} was written with a different config (beyond epochs, device and "
                "checkpoint_every); pass --no-resume or another out dir"
            )
        model.load_state_dict(ckpt["model"])
        optimizer.load_state_dict(ckpt["optimizer"])
        generator.set_state(ckpt["generator"])
        torch.set_rng_state(ckpt["torch_rng"])
        start_epoch, best = ckpt["epoch"] + 1, ckpt["best_val"]
        log.info("resuming from epoch %d", ckpt["epoch"])
    else:
        if init_from is not None:
            src = Path(init_from)
            src = src / "model.pt" if src.is_dir() else src
            model.load_state_dict(torch.load(src, map_location=device, weights_only=True))
            log.info("initialised from %s", src)
        with open(out / "log.csv", "w", newline="") as f:
            csv.writer(f).writerow(LOG_FIELDS)
    started = time.perf_counter()
    config.save(out / "config.json")
    history: list[dict[str, float]] = []
    epochs = range(start_epoch, config.epochs + 1)
    bar = tqdm(epochs, desc="sqpdnet", disable=not progress, unit="epoch")
    for epoch in bar:
        t0 = time.perf_counter()
        sums: dict[str, float] = {}
        n = 0
        for batch in train_data.batches(config.batch_size, shuffle=True, generator=generator):
            stats = train_step(model, batch.to(device), optimizer, generator)
            k = len(batch)
            for key, value in stats.items():
                sums[key] = sums.get(key, 0.0) + value * k
            n += k
        row: dict[str, float] = {
            "epoch": epoch,
            "train_loss": sums["loss"] / n,
            "train_translation": sums["translation"] / n,
            "train_rotation": sums["rotation"] / n,
        }
        if val_data is not None and len(val_data):
            v = validate(model, val_data)
            row |= {
                "val_loss": v["loss"],
                "val_position_cm": v["position_cm"],
                "val_orientation_deg": v["orientation_deg"],
            }
        row["seconds"] = time.perf_counter() - t0
        history.append(row)
        with open(out / "log.csv", "a", newline="") as f:
            csv.writer(f).writerow([row.get(k, "") for k in LOG_FIELDS])
        score = row.get("val_loss", row["train_loss"])
        if score < best:
            best = score
            _save(out / "model_best.pt", model.state_dict())
        out_of_time = time_limit_s is not None and time.perf_counter() - started > time_limit_s
        if epoch % config.checkpoint_every == 0 or epoch == config.epochs or out_of_time:
            _save(out / "model.pt", model.state_dict())
            _save(
                ckpt_path,
                {
                    "model": model.state_dict(),
                    "optimizer": optimizer.state_dict(),
                    "generator": generator.get_state(),
                    "torch_rng": torch.get_rng_state(),
                    "epoch": epoch,
                    "best_val": best,
                    "config": config.to_dict(),
                },
            )
        bar.set_postfix(
            loss=f"{row['train_loss']:.3g}", val=f"{row.get('val_loss', float('nan')):.3g}"
        )
        if out_of_time:
            log.info("time limit reached after epoch %d; re-run the command to resume", epoch)
            break
    return {"history": history, "model": model}


def load_model(path: str | Path, *, best: bool = False, device: str = "cpu") -> SQPDNet:
    """A trained model from a training ``out_dir`` (``config.json`` + ``model.pt``)."""
    path = Path(path)
    config = SQPDNetConfig.load(path / "config.json")
    config = dataclasses.replace(config, device="cpu" if device == "cpu" else config.device)
    model = make_model(config)
    state = torch.load(path / ("model_best.pt" if best else "model.pt"), map_location=device)
    model.load_state_dict(state)
    return model.to(device).eval()


# --- command line ---------------------------------------------------------------------------------


def _load_data(
    args: argparse.Namespace, max_objects: int
) -> tuple[PushTensors, PushTensors | None]:
    if args.synthetic:
        tuples = synthetic_tuples(args.synthetic, seed=args.seed, max_objects=max_objects)
        n_val = max(1, args.synthetic // 10)
        val = synthetic_tuples(n_val, seed=args.seed + 1, max_objects=max_objects)
        return tensors_from_tuples(tuples, max_objects), tensors_from_tuples(val, max_objects)
    root = Path(args.data)
    train_root = root / "train" if (root / "train").is_dir() else root
    val_root = root / "val"
    return load_split(train_root), load_split(val_root) if val_root.is_dir() else None


def _run(args: argparse.Namespace) -> int:
    overrides: dict[str, Any] = {"seed": args.seed}
    if args.epochs is not None:
        overrides["epochs"] = args.epochs
    if args.batch_size is not None:
        overrides["batch_size"] = args.batch_size
    if args.device is not None:
        overrides["device"] = args.device
    if args.no_alignment:
        overrides["shape_alignment"] = False
    if args.lr is not None:
        overrides["lr"] = args.lr
    config = (
        baseline_config(args.config, **overrides)
        if args.baseline
        else get_config(args.config, **overrides)
    )
    if args.data is None and not args.synthetic:
        raise SystemExit("give --data DIR (with train/ [val/]) or --synthetic N")
    train_data, val_data = _load_data(args, config.max_objects)
    result = train(
        config, train_data, val_data, args.out, resume=not args.no_resume,
        init_from=args.init_from,
        time_limit_s=None if args.time_limit is None else 60.0 * args.time_limit,
    )  # fmt: skip
    last = result["history"][-1] if result["history"] else {}
    print({k: round(v, 5) if isinstance(v, float) else v for k, v in last.items()})
    return 0


def add_cli(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``sqpdnet`` under a ``train`` command's sub-parsers (``sqmanip train sqpdnet``)."""
    p = subparsers.add_parser(
        "sqpdnet",
        help="train SQPD-Net (or the 4.7.1 baseline) on pushing tuples",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--config", choices=sorted(PRESETS), default="cpu", help="preset (default cpu)")
    p.add_argument("--data", help="split directory, or a directory with train/ and val/")
    p.add_argument("--synthetic", type=int, default=0, metavar="N",
                   help="train on N analytic synthetic tuples instead of --data")  # fmt: skip
    p.add_argument("--out", required=True, help="output directory (checkpoints, log.csv)")
    p.add_argument("--baseline", action="store_true",
                   help="world-frame network with SE(2) augmentation (4.7.1)")  # fmt: skip
    p.add_argument("--no-alignment", action="store_true", help="disable the 4.6 shape alignment")
    p.add_argument("--epochs", type=int)
    p.add_argument("--batch-size", type=int)
    p.add_argument("--device", choices=["cpu", "cuda", "auto"])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-resume", action="store_true", help="ignore an existing checkpoint")
    p.add_argument("--lr", type=float, help="Adam learning rate (default: the preset's)")
    p.add_argument(
        "--init-from",
        metavar="PATH",
        help="fresh run: start from these weights (model.pt or its directory)",
    )
    p.add_argument("--time-limit", type=float, metavar="MIN",
                   help="stop (with a checkpoint, resumable) after the first epoch past MIN "
                        "minutes of wall time")  # fmt: skip
    p.set_defaults(func=_run)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sqmanip.dynamics.train")
    sub = parser.add_subparsers(dest="model", required=True)
    add_cli(sub)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
