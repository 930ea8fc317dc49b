"""The ``Superquadric`` value type shared by every service, and its packed tensor form."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Literal

import numpy as np
import torch

from .superquadric import KINDS, N_PARAMS

Kind = Literal["superellipsoid", "superparaboloid", "supertoroid"]


@dataclasses.dataclass(frozen=True)
class Superquadric:
    """One (deformable) superquadric part with its pose.

    Lengths in metres, angles in radians; ``pose`` maps object to world coordinates (4 x 4).
    """

    size: tuple[float, float, float]
    """``(a1, a2, a3)``, half extents along the object x, y, z axes (m)."""
    shape: tuple[float, float]
    """``(e1, e2)``, in [0.2, 1.7]: ~0.2 box-like, 1 ellipsoid, ~1.7 pinched."""
    pose: np.ndarray = dataclasses.field(default_factory=lambda: np.eye(4))
    """Object-to-world transform, 4 x 4."""
    kind: Kind = "superellipsoid"
    taper: float = 0.0
    """Tapering ``k`` in [-1, 1] (2.3.12)."""
    bend: float = 0.0
    """Bending curvature ``b`` >= 0 (1/m) (2.3.15)."""
    bend_direction: float = 0.0
    """Bending direction ``alpha`` in the object x-y plane (rad)."""
    a4: float = 0.0
    """Supertoroid hole parameter (2.2.9); unused for other kinds."""

    def __post_init__(self) -> None:
        pose = np.asarray(self.pose, dtype=np.float64)
        if pose.shape != (4, 4):
            raise ValueError(f"pose must have shape (4, 4), got {pose.shape}")
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")
        if len(self.size) != 3 or min(self.size) <= 0:
            raise ValueError(f"size must be three positive lengths, got {self.size}")
        if len(self.shape) != 2:
            raise ValueError(f"shape must be (e1, e2), got {self.shape}")
        object.__setattr__(self, "pose", pose)

    @property
    def kind_index(self) -> int:
        return KINDS.index(self.kind)

    def params(self) -> np.ndarray:
        """Packed ``(9,)`` parameters in ``PARAM_NAMES`` order."""
        a1, a2, a3 = self.size
        e1, e2 = self.shape
        p = [a1, a2, a3, e1, e2, self.taper, self.bend, self.bend_direction, self.a4]
        return np.asarray(p, dtype=np.float64)

    def with_pose(self, pose: np.ndarray) -> Superquadric:
        return dataclasses.replace(self, pose=np.asarray(pose, dtype=np.float64))


@dataclasses.dataclass
class SuperquadricTensors:
    """A set of ``M`` superquadrics as tensors: ``params (M, 9)``, ``kinds (M,)``, ``poses (M, 4, 4)``."""

    params: torch.Tensor
    kinds: torch.Tensor
    poses: torch.Tensor

    def __len__(self) -> int:
        return self.params.shape[0]


def pack(
    parts: Sequence[Superquadric], dtype: torch.dtype = torch.float32, device=None
) -> SuperquadricTensors:
    """Stack superquadrics into tensors for the batched geometry functions."""
    if len(parts) == 0:
        return SuperquadricTensors(
            torch.zeros(0, N_PARAMS, dtype=dtype, device=device),
            torch.zeros(0, dtype=torch.long, device=device),
            torch.zeros(0, 4, 4, dtype=dtype, device=device),
        )
    params = torch.as_tensor(np.stack([p.params() for p in parts]), dtype=dtype, device=device)
    kinds = torch.as_tensor([p.kind_index for p in parts], dtype=torch.long, device=device)
    poses = torch.as_tensor(np.stack([p.pose for p in parts]), dtype=dtype, device=device)
    return SuperquadricTensors(params, kinds, poses)
