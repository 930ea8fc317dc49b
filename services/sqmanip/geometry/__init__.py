"""Superquadric geometry: implicit functions, deformations, poses, sampling, meshing, ray casting,
occupancy, IoU and depth rendering. Batched torch; no I/O and no services."""

from . import np_api
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
from .iou import (
    IoUEstimate,
    mesh_contains,
    occupancy,
    shapes_bounds,
    volume_iou,
    volume_iou_estimate,
)
from .mesh import superquadric_mesh, superquadric_trimesh, surface_area, union_mesh
from .numerics import E_MAX, E_MIN, signed_pow
from .raycast import (
    LineHits,
    farthest_intersection,
    first_hits,
    line_intersections,
    world_line_intersections,
)
from .render import (
    PinholeCamera,
    depth_to_points,
    range_to_z,
    raycast_depth,
    render_depth,
    render_parts_depth,
    render_point_cloud,
)
from .sampling import farthest_point_sampling, sample_parts, sample_surface, sample_surface_angles
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
from .transforms import (
    check_se3,
    decompose_pose,
    is_se2,
    matrix_to_quat,
    pose_from_pq,
    pose_to_pq,
    quat_conjugate,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
    rot_z,
    se2_matrix,
    se2_params,
    se2_transform_action,
    se3_compose,
    se3_inverse,
    skew,
    so3_exp,
    so3_log,
    transform_points,
    transform_vectors,
)
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
