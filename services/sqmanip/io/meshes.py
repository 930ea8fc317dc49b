"""Triangle meshes of recognized superquadrics, written as OBJ or PLY.

Why these formats: every mesh tool (MeshLab, Blender, Open3D, trimesh, RViz) reads them, so a
user can overlay the recognized shapes on their own cloud. The surfaces come from the geometry
core (:func:`sqmanip.geometry.mesh.superquadric_mesh`: watertight, outward-oriented meshes of
plain and deformed superquadrics, Ch. 2.2-2.3), posed object-to-world.

- OBJ: one file, an ``o object_<id>`` per object and a ``g object_<id>_part_<j>`` group per part
  (vertex indices are global, 1-based); ``usemtl``-free, so nothing else to ship.
- PLY: binary little-endian, ``vertex`` (x y z float, red green blue uchar: one color per
  object) and ``face`` (``list uchar int vertex_indices``).

With ``split=True`` one file per part is written instead (``<stem>_<id>_<j><suffix>``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sqmanip.errors import ValidationError

MESH_SUFFIXES = (".obj", ".ply")

PALETTE = np.array(
    [
        [0.894, 0.102, 0.110], [0.216, 0.494, 0.722], [0.302, 0.686, 0.290],
        [0.596, 0.306, 0.639], [1.000, 0.498, 0.000], [0.651, 0.337, 0.157],
        [0.969, 0.506, 0.749], [0.600, 0.600, 0.600], [0.894, 0.769, 0.004],
        [0.090, 0.745, 0.812],
    ]
)  # fmt: skip
"""Per-object colors (Set1-like), cycled by object index."""


@dataclasses.dataclass(frozen=True)
class PartMesh:
    """One world-frame part mesh: ``vertices (V, 3)`` float64, ``faces (F, 3)`` int64."""

    vertices: np.ndarray
    faces: np.ndarray


@dataclasses.dataclass(frozen=True)
class ObjectMeshes:
    """The part meshes of one object, with its id and display color (RGB in [0, 1])."""

    id: int
    parts: tuple[PartMesh, ...]
    color: tuple[float, float, float]


def part_mesh(sq, resolution: int = 24) -> PartMesh:
    """World-frame mesh of a posed :class:`sqmanip.geometry.Superquadric` (``pose`` 4 x 4)."""
    from sqmanip.geometry.mesh import superquadric_mesh

    verts, faces = superquadric_mesh(sq.params(), sq.kind_index, resolution)
    pose = np.asarray(sq.pose, dtype=np.float64)
    return PartMesh(verts @ pose[:3, :3].T + pose[:3, 3], np.asarray(faces, dtype=np.int64))


def object_meshes(
    objects: Sequence[tuple[int, Sequence]], resolution: int = 24
) -> list[ObjectMeshes]:
    """``objects``: ``(id, [Superquadric, ...])`` pairs -> meshes, colored by object index."""
    if resolution < 2:
        raise ValidationError(f"resolution: expected at least 2 cells, got {resolution}")
    out = []
    for i, (oid, parts) in enumerate(objects):
        color = tuple(float(c) for c in PALETTE[i % len(PALETTE)])
        meshes = tuple(part_mesh(sq, resolution) for sq in parts)
        out.append(ObjectMeshes(int(oid), meshes, color))  # type: ignore[arg-type]
    return out


def _obj_text(objects: Sequence[ObjectMeshes]) -> str:
    lines = ["# superquadric meshes written by sqmanip (metres, world frame)"]
    base = 1
    for obj in objects:
        lines.append(f"o object_{obj.id}")
        for j, part in enumerate(obj.parts):
            lines.append(f"g object_{obj.id}_part_{j}")
            lines.extend(f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in part.vertices)
            lines.extend(f"f {a + base} {b + base} {c + base}" for a, b, c in part.faces)
            base += len(part.vertices)
    return "\n".join(lines) + "\n"


def _ply_bytes(objects: Sequence[ObjectMeshes]) -> bytes:
    verts, faces, colors = [], [], []
    base = 0
    for obj in objects:
        rgb = np.rint(np.clip(obj.color, 0.0, 1.0) * 255).astype(np.uint8)
        for part in obj.parts:
            verts.append(part.vertices)
            faces.append(part.faces + base)
            colors.append(np.broadcast_to(rgb, (len(part.vertices), 3)))
            base += len(part.vertices)
    v = np.concatenate(verts) if verts else np.zeros((0, 3))
    f = np.concatenate(faces) if faces else np.zeros((0, 3), dtype=np.int64)
    c = np.concatenate(colors) if colors else np.zeros((0, 3), dtype=np.uint8)
    header = "\n".join([
        "ply", "format binary_little_endian 1.0",
        "comment superquadric meshes written by sqmanip (metres, world frame)",
        f"element vertex {len(v)}",
        "property float x", "property float y", "property float z",
        "property uchar red", "property uchar green", "property uchar blue",
        f"element face {len(f)}", "property list uchar int vertex_indices", "end_header",
    ]) + "\n"  # fmt: skip
    vt = np.zeros(len(v), dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)])
    vt["xyz"], vt["rgb"] = v, c
    ft = np.zeros(len(f), dtype=[("n", "u1"), ("idx", "<i4", 3)])
    ft["n"], ft["idx"] = 3, f
    return header.encode("ascii") + vt.tobytes() + ft.tobytes()


def write_meshes(
    path: str | Path, objects: Sequence[ObjectMeshes], *, split: bool = False
) -> list[Path]:
    """Write ``objects`` to ``path`` (``.obj`` or ``.ply``, by suffix); returns the files written.

    ``split``: one file per part, named ``<stem>_<object id>_<part index><suffix>``.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValidationError(
            f"{path}: unknown mesh format {suffix or '(no suffix)'!r}; expected .obj or .ply"
        )
    write = _obj_text if suffix == ".obj" else _ply_bytes
    if not split:
        jobs = [(path, list(objects))]
    else:
        jobs = [
            (
                path.with_name(f"{path.stem}_{obj.id}_{j}{path.suffix}"),
                [ObjectMeshes(obj.id, (part,), obj.color)],
            )
            for obj in objects
            for j, part in enumerate(obj.parts)
        ]
    written = []
    for target, objs in jobs:
        data = write(objs)
        if isinstance(data, str):
            target.write_text(data)
        else:
            target.write_bytes(data)
        written.append(target)
    return written
