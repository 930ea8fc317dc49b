"""Configuration of the learned recognition networks (Ch. 3.3, 3.6.2, Appendix A.2, B.2).

Two dataclasses in the lerobot style (fields grouped under comments, odd defaults explained,
``__post_init__`` naming the field at fault): :class:`RecognitionNetConfig` for DSQNet, SQNet and
DSQNet+ (one architecture, the name picks the heads and the input width) and
:class:`SegNetConfig` for the DGCNN segmentation network. :class:`TrainConfig` holds the schedule.

The defaults are the thesis' full-size networks; ``configs/cpu.toml`` and ``configs/gpu.toml``
hold the reduced CPU and full GPU presets per model (:func:`load_preset`).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path
from typing import Any, Literal

SQ_MODELS = ("dsqnet", "sqnet", "dsqnet_plus")
"""Superquadric recognition networks: deformable, plain (3.5.2) and with object context (3.6.2)."""
SEG_MODELS = ("segnet",)
MODEL_NAMES = SQ_MODELS + SEG_MODELS
PRESET_DIR = Path(__file__).parent / "configs"

Device = Literal["cpu", "cuda", "auto"]


def _check_widths(value: tuple[int, ...], field: str, min_len: int = 1) -> tuple[int, ...]:
    value = tuple(int(v) for v in value)
    if len(value) < min_len or any(v <= 0 for v in value):
        raise ValueError(
            f"`{field}` must hold at least {min_len} positive widths, got {value} for `{field}`"
        )
    return value


@dataclasses.dataclass
class RecognitionNetConfig:
    """DSQNet / SQNet / DSQNet+ hyper-parameters. Defaults are the full-size network of 3.3.1."""

    name: str = "dsqnet"

    # Input. DSQNet sees one segment resampled to 300 points (A.2); DSQNet+ sees the whole
    # object cloud (1000 points, A.1) with a 4th channel that marks the segment (3.6.2).
    n_points: int = 300

    # Feature extractor (3.3.1): EdgeConv layers with point-wise widths (64, 64, 128, 256), then
    # a point-wise layer to a 1024-d feature that is max-pooled. DGCNN [72] uses k = 20.
    k: int = 20
    edge_widths: tuple[int, ...] = (64, 64, 128, 256)
    global_dim: int = 1024
    # Seven heads (Table 3.1), each an MLP (512, 256) with leaky ReLU, then a linear output layer.
    head_widths: tuple[int, ...] = (512, 256)
    leaky_slope: float = 0.2

    # Output bounds (Table 3.1), in the normalised frame (farthest pair of input points = 1).
    size_bounds: tuple[float, float] = (0.03, 0.53)
    shape_bounds: tuple[float, float] = (0.2, 1.7)
    taper_bounds: tuple[float, float] = (-0.9, 0.9)
    # b' = max(a1, a2) b; the lower bound 0.01 keeps the bend direction learnable (A.1).
    bend_bounds: tuple[float, float] = (0.01, 0.75)

    def __post_init__(self) -> None:
        if self.name not in SQ_MODELS:
            raise ValueError(f"`name` must be one of {list(SQ_MODELS)}, got {self.name!r}")
        if self.n_points < 4:
            raise ValueError(f"`n_points` must be >= 4, got {self.n_points}")
        if not 1 <= self.k < self.n_points:
            raise ValueError(
                f"`k` must be in [1, n_points), got {self.k} for `k` and "
                f"{self.n_points} for `n_points`"
            )
        self.edge_widths = _check_widths(self.edge_widths, "edge_widths")
        self.head_widths = _check_widths(self.head_widths, "head_widths")
        if self.global_dim <= 0:
            raise ValueError(f"`global_dim` must be positive, got {self.global_dim}")
        for field in ("size_bounds", "shape_bounds", "taper_bounds", "bend_bounds"):
            lo, hi = (float(v) for v in getattr(self, field))
            if not lo < hi:
                raise ValueError(f"`{field}` must be (low, high) with low < high, got {(lo, hi)}")
            setattr(self, field, (lo, hi))
        if self.size_bounds[0] <= 0 or self.bend_bounds[0] < 0:
            raise ValueError(
                f"`size_bounds` must be positive and `bend_bounds` non-negative, got "
                f"{self.size_bounds} for `size_bounds` and {self.bend_bounds} for `bend_bounds`"
            )
        if self.shape_bounds[0] < 0.2 or self.shape_bounds[1] > 1.7:
            raise ValueError(
                f"`shape_bounds` must lie in the geometry core's [0.2, 1.7], got {self.shape_bounds}"
            )

    @property
    def in_dim(self) -> int:
        """3 (xyz) or 4 for DSQNet+ (xyz plus the segment indicator of 3.6.2)."""
        return 4 if self.name == "dsqnet_plus" else 3

    @property
    def deformable(self) -> bool:
        """SQNet predicts plain superquadrics (k = b = 0): four heads instead of seven (B.2)."""
        return self.name != "sqnet"


@dataclasses.dataclass
class SegNetConfig:
    """DGCNN part-segmentation network [72] (A.2): per-point logits over ``max_labels`` labels."""

    name: str = "segnet"
    # Object clouds are resampled to 1000 points (A.2).
    n_points: int = 1000
    # Labels the network can emit; objects have at most 3 parts (Table A.2). The Hungarian loss
    # matches ground-truth labels to any of these, so spare labels just stay unused.
    max_labels: int = 4

    # DGCNN segmentation: three EdgeConv layers (64, 64, 64), a 1024-d max-pooled global feature
    # concatenated back to every point, then a point-wise MLP (256, 256, 128) to the logits.
    k: int = 20
    edge_widths: tuple[int, ...] = (64, 64, 64)
    global_dim: int = 1024
    head_widths: tuple[int, ...] = (256, 256, 128)
    dropout: float = 0.5
    leaky_slope: float = 0.2

    def __post_init__(self) -> None:
        if self.name not in SEG_MODELS:
            raise ValueError(f"`name` must be one of {list(SEG_MODELS)}, got {self.name!r}")
        if not 1 <= self.k < self.n_points:
            raise ValueError(
                f"`k` must be in [1, n_points), got {self.k} for `k` and "
                f"{self.n_points} for `n_points`"
            )
        if self.max_labels < 2:
            raise ValueError(f"`max_labels` must be >= 2, got {self.max_labels}")
        self.edge_widths = _check_widths(self.edge_widths, "edge_widths")
        self.head_widths = _check_widths(self.head_widths, "head_widths")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"`dropout` must be in [0, 1), got {self.dropout}")

    @property
    def in_dim(self) -> int:
        return 3


ModelConfig = RecognitionNetConfig | SegNetConfig


@dataclasses.dataclass
class TrainConfig:
    """Training schedule (A.2: Adam, learning rate 1e-3, batch size 16)."""

    lr: float = 1e-3
    # "constant" (A.2) or "cosine": the learning rate falls from ``lr`` to ``lr_final`` over
    # ``max_steps`` (a short CPU run ends at a low rate instead of mid-way at 1e-3).
    lr_schedule: Literal["constant", "cosine"] = "constant"
    lr_final: float = 1e-5
    batch_size: int = 16
    # Upper bounds; whichever of max_steps / epochs / --max-minutes comes first ends training.
    epochs: int = 1000
    max_steps: int = 3_000_000
    # Ground-truth surface points per item used in the loss (A.1 stores 1500; B.2 uses 512).
    n_gt: int = 1500
    # Weight w of the z-axis regulariser ||z x z_g||^2 of (3.3.6).
    z_weight: float = 0.01
    # Extra terms, not in the thesis (0 = the loss of 3.3.6 alone; see learned/losses.py): the
    # predicted surface's distance to the ground-truth points, and the supervised exponents,
    # taper and bending, with the sizes weighted ``size_weight`` times more inside that term.
    # They make a CPU budget go further; the gpu preset leaves them off.
    surface_weight: float = 0.0
    shape_weight: float = 0.0
    size_weight: float = 0.0
    seed: int = 0
    # Evaluate on the test split every this many steps, and always at the end.
    eval_every: int = 1000
    # Test items scored by volumetric IoU at each evaluation (0: loss only).
    eval_iou_items: int = 64
    checkpoint_every: int = 500
    # Mean training losses are written to log.csv every this many steps.
    log_every: int = 25
    num_threads: int = 0
    """torch intra-op threads on the CPU; 0 keeps torch's default."""
    device: Device = "auto"

    def __post_init__(self) -> None:
        positive = ("lr", "batch_size", "epochs", "max_steps", "n_gt", "eval_every", "log_every")
        for field in positive:
            if not getattr(self, field) > 0:
                raise ValueError(f"`{field}` must be positive, got {getattr(self, field)}")
        for field in ("z_weight", "surface_weight", "shape_weight", "size_weight"):
            if getattr(self, field) < 0:
                raise ValueError(f"`{field}` must be >= 0, got {getattr(self, field)}")
        if self.lr_schedule not in ("constant", "cosine"):
            raise ValueError(
                f"`lr_schedule` must be 'constant' or 'cosine', got {self.lr_schedule!r}"
            )
        if self.device not in ("cpu", "cuda", "auto"):
            raise ValueError(f"`device` must be 'cpu', 'cuda' or 'auto', got {self.device!r}")

    def lr_at(self, step: int) -> float:
        """Learning rate for optimiser step ``step`` (a function of the step, so resume-safe)."""
        if self.lr_schedule == "constant":
            return self.lr
        t = min(1.0, step / self.max_steps)
        return self.lr_final + 0.5 * (self.lr - self.lr_final) * (1.0 + math.cos(math.pi * t))


def model_config(name: str, **overrides: Any) -> ModelConfig:
    """The config dataclass for model ``name``; unknown names list the valid ones."""
    if name in SQ_MODELS:
        if name == "dsqnet_plus":
            overrides.setdefault("n_points", 1000)
        return RecognitionNetConfig(name=name, **overrides)
    if name in SEG_MODELS:
        return SegNetConfig(name=name, **overrides)
    raise ValueError(f"Unknown model name {name!r}. Available models: {list(MODEL_NAMES)}")


def _fields(cls) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)}


def config_from_dict(name: str, table: dict[str, Any]) -> tuple[ModelConfig, TrainConfig]:
    """Split a flat ``{field: value}`` table into (model config, train config)."""
    cls = RecognitionNetConfig if name in SQ_MODELS else SegNetConfig
    model_keys, train_keys = _fields(cls) - {"name"}, _fields(TrainConfig)
    unknown = set(table) - model_keys - train_keys - {"name"}
    if unknown:
        raise ValueError(
            f"unknown config keys {sorted(unknown)} for model {name!r}; valid keys: "
            f"{sorted(model_keys | train_keys)}"
        )

    def norm(v):
        return tuple(v) if isinstance(v, list) else v

    m = {k: norm(v) for k, v in table.items() if k in model_keys}
    t = {k: norm(v) for k, v in table.items() if k in train_keys}
    return model_config(name, **m), TrainConfig(**t)


def load_preset(name: str, preset: str | Path) -> tuple[ModelConfig, TrainConfig]:
    """Model and train config of ``name`` from a preset (``cpu`` | ``gpu``) or a TOML file path.

    The file has one table per model name (``[dsqnet]``, ``[segnet]``, ...) and an optional
    ``[common]`` table whose keys every model inherits.
    """
    if name not in MODEL_NAMES:
        raise ValueError(f"Unknown model name {name!r}. Available models: {list(MODEL_NAMES)}")
    path = Path(preset)
    if not path.suffix:
        path = PRESET_DIR / f"{preset}.toml"
        if not path.exists():
            choices = sorted(p.stem for p in PRESET_DIR.glob("*.toml"))
            raise ValueError(f"Unknown preset {preset!r}. Available presets: {choices}")
    with path.open("rb") as fh:
        data = tomllib.load(fh)
    table = dict(data.get("common", {}))
    table.update(data.get(name, {}))
    return config_from_dict(name, table)


def to_toml(tables: dict[str, dict[str, Any]]) -> str:
    """Write flat tables of str / bool / int / float / list values as TOML (no dependency)."""

    def value(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int | float):
            return repr(v)
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(x) for x in v) + "]"
        raise ValueError(f"cannot write {type(v).__name__} value {v!r} to TOML")

    lines: list[str] = []
    for name, table in tables.items():
        lines.append(f"[{name}]")
        lines.extend(f"{k} = {value(v)}" for k, v in table.items() if v is not None)
        lines.append("")
    return "\n".join(lines)


def as_table(cfg) -> dict[str, Any]:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(cfg).items()}
