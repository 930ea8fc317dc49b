"""Superquadric geometry: implicit functions, deformations, poses, sampling, meshing, ray casting,
occupancy, IoU and depth rendering. Batched torch; no I/O and no services."""

from .deform import (
    bend,
    bend_inverse,
    bend_jacobian,
    deform,
    deform_inverse,
    deform_jacobian,
    deform_normal,
    taper,
    taper_inverse,
    taper_jacobian,
)
from .numerics import E_MAX, E_MIN, signed_pow
from .superquadric import (
    KINDS,
    N_PARAMS,
    PARAM_NAMES,
    SUPERELLIPSOID,
    SUPERPARABOLOID,
    SUPERTOROID,
    implicit,
    implicit_homogeneous,
    normal,
    radial_distance,
    superellipsoid_implicit,
    superellipsoid_parametric_normal,
    superellipsoid_surface,
    superparaboloid_implicit,
    superparaboloid_surface,
    supertoroid_implicit,
    supertoroid_surface,
)
from .transforms import se3_inverse, transform_points
from .types import Superquadric, SuperquadricTensors, pack
from .world import (
    occupied,
    soft_occupancy,
    to_object_frames,
    union_implicit,
    world_implicit,
    world_normal,
)

__all__ = [name for name in dir() if not name.startswith("_")]
