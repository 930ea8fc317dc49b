"""Scene specifications (plain data, JSON round trip) and their PyBullet bodies.

A :class:`SceneSpec` fully describes a scene: the layout (``tabletop`` or ``shelf``), the
objects with their poses, and the seed of the sensor-noise generator. Saving ``to_dict()`` and
resetting a simulator with ``SceneSpec.from_dict(d)`` replays the scene exactly.

Objects are boxes, cylinders, (deformable) superquadrics and mesh files (URDF or OBJ, paths
absolute or relative to ``pybullet_data``). Superquadrics are meshed with
:func:`sqmanip.geometry.mesh.superquadric_mesh`. PyBullet turns every dynamic mesh into convex
hulls, so a convex superquadric (plain superellipsoid, ``e1, e2 <= 1``) becomes one hull and any
other shape a compound of hulls of slabs (along the canonical z axis) or, for toroids, sectors;
a non-convex cross-section (``e > 1``) is filled within each slab (documented approximation).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import tempfile
from typing import Any, Literal

import numpy as np
import pybullet as p
import pybullet_data

from ..errors import ValidationError
from ..geometry.superquadric import SUPERTOROID
from ..geometry.types import Superquadric

ObjectKind = Literal["box", "cylinder", "superquadric", "mesh"]
OBJECT_KINDS = ("box", "cylinder", "superquadric", "mesh")
SCENE_KINDS = ("tabletop", "shelf")

BOX_SHAPE = (0.2, 0.2)
"""``(e1, e2)`` of the superquadric that stands for a box (ground truth labels)."""
CYLINDER_SHAPE = (0.2, 1.0)


def _vec(value, n: int, name: str) -> tuple[float, ...]:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (n,):
        raise ValidationError(f"{name} must have {n} numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValidationError(f"{name} must be finite, got {arr.tolist()}")
    return tuple(float(x) for x in arr)


@dataclasses.dataclass(frozen=True)
class ObjectSpec:
    """One object to spawn: shape, pose (position m, quaternion xyzw), physical properties.

    - ``box``: ``size`` = full extents (x, y, z) in m.
    - ``cylinder``: ``radius`` and ``height`` (axis = object z).
    - ``superquadric``: ``params`` (9, the packed ``a1 a2 a3 e1 e2 k b alpha a4``) and
      ``sq_kind`` (``superellipsoid`` | ``superparaboloid`` | ``supertoroid``).
    - ``mesh``: ``path`` (``.urdf`` or ``.obj``; relative paths resolve in ``pybullet_data``)
      and a uniform ``scale``.

    ``upright`` marks objects that must stay standing (the random generator rejects them when
    they tip over).
    """

    kind: ObjectKind
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    size: tuple[float, float, float] = (0.05, 0.05, 0.05)
    radius: float = 0.03
    height: float = 0.08
    params: tuple[float, ...] = (0.03, 0.03, 0.04, 0.5, 0.5, 0.0, 0.0, 0.0, 0.0)
    sq_kind: str = "superellipsoid"
    path: str = ""
    scale: float = 1.0
    mass: float = 0.2
    friction: float = 0.6
    color: tuple[float, float, float, float] = (0.8, 0.3, 0.2, 1.0)
    upright: bool = True
    name: str = ""

    def __post_init__(self) -> None:
        if self.kind not in OBJECT_KINDS:
            raise ValidationError(f"object kind must be one of {OBJECT_KINDS}, got {self.kind!r}")
        object.__setattr__(self, "position", _vec(self.position, 3, "position"))
        q = np.asarray(_vec(self.orientation, 4, "orientation"))
        nq = np.linalg.norm(q)
        if nq < 1e-6:
            raise ValidationError("orientation quaternion must be non-zero")
        object.__setattr__(self, "orientation", tuple(float(x) for x in q / nq))
        object.__setattr__(self, "size", _vec(self.size, 3, "size"))
        object.__setattr__(self, "params", _vec(self.params, 9, "params"))
        object.__setattr__(self, "color", _vec(self.color, 4, "color"))
        if self.kind == "box" and min(self.size) <= 0:
            raise ValidationError(f"box size must be positive, got {self.size}")
        if self.kind == "cylinder" and (self.radius <= 0 or self.height <= 0):
            raise ValidationError(
                f"cylinder radius/height must be positive, got {self.radius}, {self.height}"
            )
        if self.kind == "superquadric":
            self.superquadric()  # validates params and sq_kind
        if self.kind == "mesh" and not self.path:
            raise ValidationError("mesh objects need a path (.urdf or .obj)")
        if not (self.mass > 0 and np.isfinite(self.mass)):
            raise ValidationError(f"mass must be positive, got {self.mass}")
        if not (self.scale > 0 and np.isfinite(self.scale)):
            raise ValidationError(f"scale must be positive, got {self.scale}")

    @property
    def pose(self) -> np.ndarray:
        """Object-to-world 4 x 4 transform of the spec's pose."""
        return pose_matrix(self.position, self.orientation)

    def superquadric(self, pose: np.ndarray | None = None) -> Superquadric | None:
        """Ground-truth superquadric (boxes and cylinders as ``e ~ 0.2`` shapes); None for meshes."""
        pose = self.pose if pose is None else pose
        if self.kind == "box":
            return Superquadric(tuple(s / 2 for s in self.size), BOX_SHAPE, pose)
        if self.kind == "cylinder":
            return Superquadric((self.radius, self.radius, self.height / 2), CYLINDER_SHAPE, pose)
        if self.kind == "superquadric":
            a1, a2, a3, e1, e2, k, b, alpha, a4 = self.params
            try:
                return Superquadric(
                    (a1, a2, a3),
                    (e1, e2),
                    pose,
                    self.sq_kind,
                    k,
                    b,
                    alpha,
                    a4,  # type: ignore[arg-type]
                )
            except ValueError as exc:
                raise ValidationError(f"superquadric object: {exc}") from exc
        return None

    def with_pose(self, position, orientation) -> ObjectSpec:
        return dataclasses.replace(self, position=tuple(position), orientation=tuple(orientation))

    def to_dict(self) -> dict[str, Any]:
        return {f.name: _plain(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ObjectSpec:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValidationError(f"unknown object fields {sorted(unknown)}")
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        return cls(**kw)


@dataclasses.dataclass(frozen=True)
class SceneSpec:
    """A whole scene: layout, objects (index = object id) and the sensor-noise seed."""

    kind: str = "tabletop"
    objects: tuple[ObjectSpec, ...] = ()
    seed: int = 0

    def __post_init__(self) -> None:
        if self.kind not in SCENE_KINDS:
            raise ValidationError(f"scene kind must be one of {SCENE_KINDS}, got {self.kind!r}")
        object.__setattr__(self, "objects", tuple(self.objects))

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "seed": int(self.seed),
            "objects": [o.to_dict() for o in self.objects],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SceneSpec:
        return cls(
            kind=d.get("kind", "tabletop"),
            objects=tuple(ObjectSpec.from_dict(o) for o in d.get("objects", [])),
            seed=int(d.get("seed", 0)),
        )


def _plain(v):
    if isinstance(v, tuple | list):
        return [_plain(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    return v


def pose_matrix(position, orientation) -> np.ndarray:
    """4 x 4 from position (3,) and quaternion xyzw (4,)."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(p.getMatrixFromQuaternion(list(orientation))).reshape(3, 3)
    T[:3, 3] = position
    return T


def matrix_to_pq(T: np.ndarray) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """4 x 4 -> (position, quaternion xyzw)."""
    from scipy.spatial.transform import Rotation

    T = np.asarray(T, np.float64)
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    return tuple(float(x) for x in T[:3, 3]), tuple(float(x) for x in q)


# --- PyBullet bodies ------------------------------------------------------------------------------


_MESH_CACHE = os.path.join(tempfile.gettempdir(), f"sqmanip_sim_meshes_{os.getuid()}")


def _resolve(path: str) -> str:
    if os.path.isabs(path) and os.path.exists(path):
        return path
    cand = os.path.join(pybullet_data.getDataPath(), path)
    if os.path.exists(cand):
        return cand
    raise ValidationError(f"mesh path {path!r} not found (absolute or relative to pybullet_data)")


def _hull_pieces(spec: ObjectSpec, resolution: int = 16) -> tuple[np.ndarray, np.ndarray, list]:
    """Superquadric mesh ``(V, 3), (F, 3)`` and a list of vertex arrays, one per convex piece."""
    from ..geometry.mesh import superquadric_mesh

    sq = spec.superquadric()
    if sq is None:
        raise ValidationError(f"object kind {spec.kind!r} has no superquadric to mesh")
    params = sq.params()
    verts, faces = superquadric_mesh(params, sq.kind_index, resolution)
    a1, a2, a3, e1, e2, k, b = params[:7]
    convex = sq.kind == "superellipsoid" and e1 <= 1.0 and e2 <= 1.0 and k == 0 and b == 0
    if convex:
        return verts, faces, [verts]
    plain = params.copy()
    plain[5] = plain[6] = 0.0
    canon, _ = superquadric_mesh(plain, sq.kind_index, resolution)
    pieces = []
    n = 8
    if sq.kind_index == SUPERTOROID:
        ang = np.arctan2(canon[:, 1], canon[:, 0])
        edges = np.linspace(-np.pi, np.pi, n + 1)
        for i in range(n):
            lo, hi = edges[i] - 0.05, edges[i + 1] + 0.05
            m = (ang >= lo) & (ang <= hi)
            if i == 0:
                m |= ang >= np.pi - 0.05
            if m.sum() >= 4:
                pieces.append(verts[m])
    else:
        z = canon[:, 2]
        edges = np.linspace(z.min(), z.max(), n + 1)
        eps = 1e-3 * (z.max() - z.min())
        for i in range(n):
            m = (z >= edges[i] - eps) & (z <= edges[i + 1] + eps)
            if m.sum() >= 4:
                pieces.append(verts[m])
    return verts, faces, pieces


def _write_pieces_obj(pieces: list[np.ndarray]) -> str:
    """One OBJ with one ``o`` block per convex hull; PyBullet loads it as a compound of hulls."""
    import trimesh

    blob = b"".join(np.ascontiguousarray(x, np.float64).tobytes() for x in pieces)
    name = hashlib.sha1(blob).hexdigest()[:20] + ".obj"
    os.makedirs(_MESH_CACHE, exist_ok=True)
    path = os.path.join(_MESH_CACHE, name)
    if os.path.exists(path):
        return path
    lines, offset = [], 1
    for i, pts in enumerate(pieces):
        hull = trimesh.convex.convex_hull(pts)
        lines.append(f"o piece{i}")
        lines += [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in hull.vertices]
        lines += [f"f {a + offset} {b + offset} {c + offset}" for a, b, c in hull.faces]
        offset += len(hull.vertices)
    tmp = path + f".{os.getpid()}.tmp"
    with open(tmp, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    os.replace(tmp, path)
    return path


def object_shapes(spec: ObjectSpec, client: int, *, visual: bool = True) -> tuple[int, int]:
    """PyBullet ``(collision, visual)`` shape ids of a box, cylinder or superquadric ``spec``
    (``visual=False``: -1 for the visual, e.g. in a world that is never rendered). One pair can
    be given to :func:`spawn` for any number of bodies of the same shape."""
    if spec.kind == "mesh":
        raise ValidationError("mesh objects have no shared shapes (URDFs are loaded whole)")
    vis = -1
    if spec.kind == "box":
        half = [s / 2 for s in spec.size]
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client)
        if visual:
            vis = p.createVisualShape(
                p.GEOM_BOX, halfExtents=half, rgbaColor=list(spec.color), physicsClientId=client
            )
    elif spec.kind == "cylinder":
        col = p.createCollisionShape(
            p.GEOM_CYLINDER, radius=spec.radius, height=spec.height, physicsClientId=client
        )
        if visual:
            vis = p.createVisualShape(
                p.GEOM_CYLINDER,
                radius=spec.radius,
                length=spec.height,
                rgbaColor=list(spec.color),
                physicsClientId=client,
            )
    else:
        verts, faces, pieces = _hull_pieces(spec)
        obj = _write_pieces_obj(pieces)
        col = p.createCollisionShape(p.GEOM_MESH, fileName=obj, physicsClientId=client)
        if visual:
            vis = p.createVisualShape(
                p.GEOM_MESH,
                vertices=verts.tolist(),
                indices=faces.reshape(-1).astype(int).tolist(),
                rgbaColor=list(spec.color),
                physicsClientId=client,
            )
    return col, vis


def spawn(spec: ObjectSpec, client: int, shapes: tuple[int, int] | None = None) -> int:
    """Create the PyBullet body for ``spec`` at its pose; returns the body id.

    ``shapes``: the ``(collision, visual)`` ids of :func:`object_shapes` for this shape, to
    share them between bodies (made here when None; not used for ``mesh`` objects).
    """
    pos, orn = list(spec.position), list(spec.orientation)
    if spec.kind == "mesh":
        path = _resolve(spec.path)
        if path.endswith(".urdf"):
            body = p.loadURDF(path, pos, orn, globalScaling=spec.scale, physicsClientId=client)
        else:
            col = p.createCollisionShape(
                p.GEOM_MESH, fileName=path, meshScale=[spec.scale] * 3, physicsClientId=client
            )
            vis = p.createVisualShape(
                p.GEOM_MESH,
                fileName=path,
                meshScale=[spec.scale] * 3,
                rgbaColor=list(spec.color),
                physicsClientId=client,
            )
            body = p.createMultiBody(spec.mass, col, vis, pos, orn, physicsClientId=client)
    else:
        col, vis = object_shapes(spec, client) if shapes is None else shapes
        body = p.createMultiBody(spec.mass, col, vis, pos, orn, physicsClientId=client)
    p.changeDynamics(
        body,
        -1,
        lateralFriction=spec.friction,
        spinningFriction=0.001,
        rollingFriction=0.0001,
        physicsClientId=client,
    )
    return body


def random_object(rng: np.random.Generator, kinds=("box", "cylinder")) -> ObjectSpec:
    """A box or cylinder with dimensions in the ranges of the pushing objects (Fig. 4.5).

    Sizes stay graspable-ish and inside the workspace height: box sides 3-10 cm, heights
    3-15 cm; cylinder radius 2-5 cm, height 4-15 cm. Poses are set by the caller.
    """
    kind = kinds[int(rng.integers(len(kinds)))]
    color = tuple(float(c) for c in rng.uniform(0.2, 0.95, size=3)) + (1.0,)
    if kind == "box":
        size = (rng.uniform(0.03, 0.10), rng.uniform(0.03, 0.10), rng.uniform(0.03, 0.15))
        return ObjectSpec("box", size=tuple(float(s) for s in size), color=color)
    if kind == "cylinder":
        return ObjectSpec(
            "cylinder",
            radius=float(rng.uniform(0.02, 0.05)),
            height=float(rng.uniform(0.04, 0.15)),
            color=color,
        )
    a = rng.uniform(0.02, 0.05, size=3)
    e = rng.uniform(0.3, 1.0, size=2)
    params = (*a, *e, 0.0, 0.0, 0.0, 0.0)
    return ObjectSpec("superquadric", params=tuple(float(x) for x in params), color=color)


def half_height(spec: ObjectSpec) -> float:
    """Half the object's extent along its own z axis (upright resting height above the support)."""
    if spec.kind == "box":
        return spec.size[2] / 2
    if spec.kind == "cylinder":
        return spec.height / 2
    if spec.kind == "superquadric":
        return float(spec.params[2])
    return 0.05
