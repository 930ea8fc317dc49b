"""Domain types of recognition: requests, options and the recognized scene.

These mirror the JSON contract of ``POST /recognize`` (see README) and the protobuf messages;
the converters in ``sqmanip.rpc`` are the only place that maps between them.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

from sqmanip.geometry import Superquadric

Method = Literal["optimization", "network", "hybrid", "mvbb"]
Segmentation = Literal["clustering", "color", "labels", "network"]


@dataclasses.dataclass(frozen=True)
class Workspace:
    """Axis-aligned crop box in the world frame (m)."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class RecognizeOptions:
    method: Method = "optimization"
    segmentation: Segmentation = "clustering"
    points_per_segment: int = 300
    """Each segment is voxel-down / tangent-plane up-sampled to this count (3.5.3)."""
    remove_support: bool = True
    """Find and remove the dominant support plane (RANSAC, B.2)."""
    amodal: bool = True
    """Use the support plane and free space seen from ``viewpoint`` to complete hidden sides."""
    deformable: bool = True
    """Fit taper/bend too (deformable superquadrics, Ch. 2.3)."""
    seed: int = 0


@dataclasses.dataclass(frozen=True)
class RecognizeRequest:
    points: np.ndarray
    """(N, 3) float32 world-frame points (m)."""
    colors: np.ndarray | None = None
    """(N, 3) float32 in [0, 1], or None."""
    labels: np.ndarray | None = None
    """(N,) int32 instance labels, -1 = background, or None."""
    viewpoint: np.ndarray | None = None
    """(3,) sensor origin in the world frame, or None."""
    workspace: Workspace | None = None
    options: RecognizeOptions = dataclasses.field(default_factory=RecognizeOptions)


@dataclasses.dataclass(frozen=True)
class SupportPlane:
    """Plane ``normal . x + offset = 0`` with ``normal`` a unit vector pointing up (into free space)."""

    normal: tuple[float, float, float]
    offset: float


@dataclasses.dataclass(frozen=True)
class RecognizedObject:
    id: int
    parts: list[Superquadric]
    point_indices: np.ndarray
    """(K,) int indices into the request cloud."""
    mean_color: tuple[float, float, float] | None = None
    residual: float = 0.0
    """Mean squared radial distance of the object's points to its parts (m^2)."""
    confidence: float = 1.0


@dataclasses.dataclass(frozen=True)
class Scene:
    objects: list[RecognizedObject]
    support_plane: SupportPlane | None = None
    timings_ms: dict[str, float] = dataclasses.field(default_factory=dict)
