"""NumPy front end to the torch geometry core, for callers that hold ``np.ndarray`` data.

Every function here has the same name, arguments and shapes as its torch counterpart and calls
it (one implementation of the math): array-likes become tensors with numpy's dtype rules
(float64 arrays and lists of Python floats stay float64, float32 stays float32, integer arrays
become float32), Python scalars pass through unchanged (torch treats them as "weak", taking the
precision of the other inputs), the torch function runs without autograd, and tensors in the
result come back as ``np.ndarray`` (tuples stay tuples).

Usage::

    from sqmanip.geometry import np_api as gnp
    R = gnp.quat_to_matrix(np.array([0.0, 0.0, 0.0, 1.0]))
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from . import superquadric as _sq
from . import transforms as _tf


def _to_torch(value: Any) -> Any:
    if isinstance(value, torch.Tensor | int | float | bool) or value is None:
        return value  # Python scalars stay "weak": they take the precision of the other inputs
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiub":
        return value
    dtype = torch.float64 if arr.dtype == np.float64 else torch.float32
    return torch.as_tensor(arr, dtype=dtype)


def _to_numpy(value: Any) -> Any:
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    if isinstance(value, tuple):
        return tuple(_to_numpy(v) for v in value)
    return value


def numpy_wrapper(fn: Callable[..., Any], array_args: tuple[str, ...]) -> Callable[..., Any]:
    """Wrap torch function ``fn`` so the parameters named in ``array_args`` accept array-likes.

    Floating arrays keep their precision (float64 -> float64, float32 -> float32), integer arrays
    become float32, Python scalars pass through. Mixed precisions promote as in torch.
    """
    signature = inspect.signature(fn)

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        bound = signature.bind(*args, **kwargs)
        for name in array_args:
            if name in bound.arguments:
                bound.arguments[name] = _to_torch(bound.arguments[name])
        with torch.no_grad():
            return _to_numpy(fn(*bound.args, **bound.kwargs))

    wrapper.__doc__ = f"NumPy wrapper of :func:`sqmanip.geometry.{fn.__name__}`.\n\n{fn.__doc__}"
    return wrapper


# --- transforms ----------------------------------------------------------------------------------
quat_normalize = numpy_wrapper(_tf.quat_normalize, ("q",))
quat_conjugate = numpy_wrapper(_tf.quat_conjugate, ("q",))
quat_multiply = numpy_wrapper(_tf.quat_multiply, ("q1", "q2"))
quat_to_matrix = numpy_wrapper(_tf.quat_to_matrix, ("q",))
matrix_to_quat = numpy_wrapper(_tf.matrix_to_quat, ("R",))
skew = numpy_wrapper(_tf.skew, ("v",))
so3_exp = numpy_wrapper(_tf.so3_exp, ("v",))
so3_log = numpy_wrapper(_tf.so3_log, ("R",))
se3_inverse = numpy_wrapper(_tf.se3_inverse, ("T",))
se3_compose = numpy_wrapper(_tf.se3_compose, ("A", "B"))
transform_points = numpy_wrapper(_tf.transform_points, ("T", "points"))
transform_vectors = numpy_wrapper(_tf.transform_vectors, ("T", "vectors"))
pose_from_pq = numpy_wrapper(_tf.pose_from_pq, ("position", "quaternion"))
pose_to_pq = numpy_wrapper(_tf.pose_to_pq, ("T",))
rot_z = numpy_wrapper(_tf.rot_z, ("theta",))
se2_matrix = numpy_wrapper(_tf.se2_matrix, ("theta", "tx", "ty"))
se2_params = numpy_wrapper(_tf.se2_params, ("C",))
is_se2 = numpy_wrapper(_tf.is_se2, ("C",))
se2_transform_action = numpy_wrapper(_tf.se2_transform_action, ("C", "p", "v"))
decompose_pose = numpy_wrapper(_tf.decompose_pose, ("T",))

# --- superquadric core ---------------------------------------------------------------------------
implicit = numpy_wrapper(_sq.implicit, ("x", "params"))
implicit_homogeneous = numpy_wrapper(_sq.implicit_homogeneous, ("x", "params"))
radial_distance = numpy_wrapper(_sq.radial_distance, ("x", "params"))
normal = numpy_wrapper(_sq.normal, ("x", "params"))

__all__ = [
    "decompose_pose",
    "implicit",
    "implicit_homogeneous",
    "is_se2",
    "matrix_to_quat",
    "normal",
    "numpy_wrapper",
    "pose_from_pq",
    "pose_to_pq",
    "quat_conjugate",
    "quat_multiply",
    "quat_normalize",
    "quat_to_matrix",
    "radial_distance",
    "rot_z",
    "se2_matrix",
    "se2_params",
    "se2_transform_action",
    "se3_compose",
    "se3_inverse",
    "skew",
    "so3_exp",
    "so3_log",
    "transform_points",
    "transform_vectors",
]
