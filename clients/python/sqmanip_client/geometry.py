"""Meshes and surface points of recognized objects, computed by ``sqmanip.geometry``.

The SDK stays light (httpx + numpy); the superquadric math lives once, in the ``sqmanip``
package, imported lazily here. Without it these helpers raise an ImportError that says what to
install.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .types import RecognizedObject, SuperquadricPart


def _geometry() -> Any:
    try:
        import sqmanip.geometry as geometry
    except ImportError as exc:
        raise ImportError(
            "to_mesh/surface_points need the superquadric math of the 'sqmanip' package "
            "(and trimesh): pip install sqmanip (or, in the repository, pip install -e .)"
        ) from exc
    return geometry


def to_superquadric(part: SuperquadricPart) -> Any:
    """The ``sqmanip.geometry.Superquadric`` of an SDK part."""
    g = _geometry()
    size = tuple(part.size)
    return g.Superquadric(
        size=size[:3],
        shape=part.shape,
        pose=part.pose.matrix(),
        kind=part.kind,
        taper=part.taper,
        bend=part.bend,
        bend_direction=part.bend_direction,
        a4=size[3] if len(size) > 3 else 0.0,
    )


def to_mesh(obj: RecognizedObject, resolution: int = 32) -> Any:
    """World-frame ``trimesh.Trimesh`` of all parts of ``obj`` (each part watertight)."""
    g = _geometry()
    return g.union_mesh([to_superquadric(p) for p in obj.parts], resolution)


def surface_points(obj: RecognizedObject, n: int, *, seed: int = 0) -> np.ndarray:
    """``(n, 3)`` world-frame points on the surfaces of ``obj``'s parts (area-weighted)."""
    g = _geometry()
    pts, _, _ = g.sample_parts([to_superquadric(p) for p in obj.parts], n, generator=seed)
    return np.asarray(pts)
