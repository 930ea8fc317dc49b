"""Scene-tree drawing: domain objects -> viser nodes (one function per kind of thing shown).

Every function replaces the nodes under its own prefix, so re-drawing after a new message is
idempotent and the scene tree keeps one stable layout:

``/cloud``, ``/objects/obj_<id>/part_<j>``, ``/support``, ``/shelf/<board>``, ``/grasps``,
``/push/predicted/obj_<id>``, ``/push/observed/obj_<id>``, ``/push/arrows``, ``/search/f``,
``/search/fg``.

Shapes are the watertight superquadric meshes of :func:`sqmanip.geometry.mesh.superquadric_mesh`
(Ch. 2.2-2.3, deformations included) posed by their object-to-world matrix.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from sqmanip.geometry.mesh import superquadric_mesh
from sqmanip.geometry.types import Superquadric

from .decode import colormap, label_colors, object_color

MESH_RESOLUTION = 20
"""Cells per cube edge of a part's mesh: 2.4 k vertices, smooth enough on screen, fast to send."""


def wxyz(rotation: np.ndarray) -> np.ndarray:
    """``(3, 3)`` rotation -> viser's ``(w, x, y, z)`` quaternion."""
    x, y, z, w = Rotation.from_matrix(np.asarray(rotation, dtype=np.float64)).as_quat()
    return np.array([w, x, y, z])


def yaw_pose(template: np.ndarray, x: float, y: float, z: float, yaw: float) -> np.ndarray:
    """``template`` (4 x 4) moved to ``(x, y, z)`` and turned about world z so that its yaw is
    ``yaw`` (roll and pitch kept): the ``ObjectXYZYaw`` poses of the MPC events (4.4)."""
    out = np.array(template, dtype=np.float64)
    current = float(np.arctan2(out[1, 0], out[0, 0]))
    out[:3, :3] = Rotation.from_euler("z", yaw - current).as_matrix() @ out[:3, :3]
    out[:3, 3] = (x, y, z)
    return out


def clear(server, prefix: str) -> None:
    server.scene.remove_by_name(prefix)


def shade(color: Sequence[int], factor: float) -> tuple[int, int, int]:
    r, g, b = (int(np.clip(c * factor, 0, 255)) for c in color)
    return r, g, b


def part_mesh(
    server,
    name: str,
    sq: Superquadric,
    color: Sequence[int],
    *,
    opacity: float | None = None,
    wireframe: bool = False,
) -> None:
    verts, faces = superquadric_mesh(sq.params(), sq.kind_index, MESH_RESOLUTION)
    server.scene.add_mesh_simple(
        name,
        verts.astype(np.float32),
        faces.astype(np.uint32),
        color=tuple(int(c) for c in color),
        opacity=opacity,
        wireframe=wireframe,
        flat_shading=False,
        cast_shadow=False,  # shadow passes double the cost of a software-WebGL frame
        receive_shadow=False,
        wxyz=wxyz(sq.pose[:3, :3]),
        position=np.asarray(sq.pose[:3, 3], dtype=np.float64),
    )


def cloud(
    server,
    points: np.ndarray,
    *,
    labels: np.ndarray | None,
    rgb: np.ndarray | None,
    color_by: str = "rgb",
    point_size: float = 0.003,
) -> None:
    """``points (N, 3)``; colours from ``labels (N,)`` (palette) or ``rgb (N, 3)`` uint8."""
    if color_by == "rgb" and rgb is not None:
        colors = np.asarray(rgb, dtype=np.uint8)
    elif labels is not None:
        colors = label_colors(labels)
    elif rgb is not None:
        colors = np.asarray(rgb, dtype=np.uint8)
    else:
        colors = np.full((points.shape[0], 3), 200, dtype=np.uint8)
    server.scene.add_point_cloud(
        "/cloud",
        np.asarray(points, dtype=np.float32),
        colors,
        point_size=point_size,
        point_shape="circle",
    )


def objects(server, scene_objects: Iterable, *, color_parts: bool = True) -> list[int]:
    """Each recognized object's parts under ``/objects/obj_<id>``; returns the ids drawn."""
    clear(server, "/objects")
    ids = []
    for obj in scene_objects:
        base = object_color(obj.id)
        for j, part in enumerate(obj.parts):
            color = shade(base, 1.0 - 0.25 * (j % 3)) if color_parts else base
            part_mesh(server, f"/objects/obj_{obj.id}/part_{j}", part, color)
        if obj.parts:
            top = max(float(p.pose[2, 3]) + float(max(p.size)) for p in obj.parts)
            x, y = obj.parts[0].pose[:2, 3]
            server.scene.add_label(
                f"/objects/obj_{obj.id}/label", f"#{obj.id}", position=(float(x), float(y), top)
            )
        ids.append(int(obj.id))
    return ids


def support_plane(
    server, normal: Sequence[float] | None, offset: float, center: np.ndarray | None
) -> None:
    """A thin translucent square on ``normal . x + offset = 0`` around ``center``'s projection."""
    clear(server, "/support")
    if normal is None:
        return
    n = np.asarray(normal, dtype=np.float64)
    n = n / max(float(np.linalg.norm(n)), 1e-12)
    c = np.zeros(3) if center is None else np.asarray(center, dtype=np.float64)
    c = c - (float(n @ c) + float(offset)) * n
    rot, _ = Rotation.align_vectors([n], [[0.0, 0.0, 1.0]])
    server.scene.add_box(
        "/support",
        color=(200, 200, 190),
        dimensions=(0.9, 0.9, 0.002),
        opacity=0.5,
        wxyz=wxyz(rot.as_matrix()),
        position=c - 0.001 * n,
    )


def shelf(server, spec) -> None:
    """The five boards of a :class:`sqmanip.search.shelf.ShelfSpec` as translucent boxes."""
    clear(server, "/shelf")
    for name, half, centre in spec.board_boxes():
        server.scene.add_box(
            f"/shelf/{name}",
            color=(160, 120, 80),
            dimensions=tuple(2 * h for h in half),
            opacity=0.25 if name != "shelf_bottom" else 0.6,
            position=centre,
        )


def gripper_segments(pose: np.ndarray, width: float, depth: float = 0.045) -> np.ndarray:
    """A parallel-jaw glyph in the gripper frame (approach z, closing y, origin between the
    pads): two fingers, the palm and the approach stem, as ``(4, 2, 3)`` world segments."""
    h = max(float(width), 0.01) / 2
    local = np.array(
        [
            [[0, -h, 0], [0, -h, -depth]],
            [[0, h, 0], [0, h, -depth]],
            [[0, -h, -depth], [0, h, -depth]],
            [[0, 0, -depth], [0, 0, -2 * depth]],
        ],
        dtype=np.float64,
    )
    return local @ pose[:3, :3].T + pose[:3, 3]


def grasps(server, ranked: Sequence[tuple[np.ndarray, float]], top_k: int) -> int:
    """The best ``top_k`` of ``ranked`` ``(pose 4 x 4, width)`` (best first) as one batch of
    line segments, green (best) to red; returns the number drawn."""
    clear(server, "/grasps")
    chosen = list(ranked)[: max(int(top_k), 0)]
    if not chosen:
        return 0
    segs = np.stack([gripper_segments(p, w) for p, w in chosen])  # (K, 4, 2, 3)
    t = np.linspace(0.0, 1.0, len(chosen))
    rank_rgb = np.stack([255 * t, 200 * (1 - t) + 30, 40 + 0 * t], axis=1).astype(np.uint8)
    colors = np.repeat(rank_rgb[:, None, None, :], 4 * 2, axis=1).reshape(-1, 2, 3)
    server.scene.add_line_segments(
        "/grasps", segs.reshape(-1, 2, 3).astype(np.float32), colors, thickness=0.004
    )
    return len(chosen)


def push_ghosts(
    server,
    shapes: dict[int, Superquadric],
    predicted: dict[str, list[float]],
    observed: dict[str, list[float]],
) -> None:
    """Predicted (blue, translucent) and observed (orange wireframe) poses after a push of the
    objects whose shapes are known; ``predicted``/``observed``: ``{id: [x, y, z, yaw]}``."""
    clear(server, "/push/predicted")
    clear(server, "/push/observed")
    for layer, poses, color, wire in (
        ("predicted", predicted, (60, 120, 255), False),
        ("observed", observed, (255, 150, 30), True),
    ):
        for key, (x, y, z, yaw) in poses.items():
            sq = shapes.get(int(key))
            if sq is None:
                continue
            posed = sq.with_pose(yaw_pose(sq.pose, x, y, z, yaw))
            part_mesh(server, f"/push/{layer}/obj_{key}", posed, color, opacity=0.35,
                      wireframe=wire)  # fmt: skip


def push_arrows(server, pushes: Sequence[Sequence[float]]) -> None:
    """Pushes ``(p, v)`` (6 values each, Ch. 4.3) as arrows from ``p`` to ``p + v``; the last
    (the current one) red, earlier ones grey."""
    clear(server, "/push/arrows")
    if not pushes:
        return
    a = np.asarray(pushes, dtype=np.float64).reshape(-1, 6)
    pts = np.stack([a[:, :3], a[:, :3] + a[:, 3:]], axis=1).astype(np.float32)
    colors = np.tile(np.array([[150, 150, 150]], dtype=np.uint8), (len(a), 1))
    colors[-1] = (230, 30, 30)
    server.scene.add_arrows(
        "/push/arrows", pts, colors, shaft_radius=0.004, head_radius=0.01, head_length=0.02
    )


def search_maps(
    server,
    grid_xy: np.ndarray,
    f: np.ndarray,
    fg: np.ndarray,
    resolution: float,
    floor_z: float,
    show: str = "fg",
) -> None:
    """Existence ``f`` (C.2) and ``f * g`` (C.3) over the target grid as coloured square tiles
    on the shelf floor; ``grid_xy (P, 2)``, ``f``, ``fg`` ``(P,)`` (max over orientations done
    by the caller); ``show`` picks the visible layer (f | fg | none)."""
    clear(server, "/search")
    for name, values, dz in (("f", f, 0.002), ("fg", fg, 0.003)):
        pts = np.column_stack([grid_xy, np.full(len(grid_xy), floor_z + dz)]).astype(np.float32)
        server.scene.add_point_cloud(
            f"/search/{name}",
            pts,
            colormap(values),
            point_size=float(resolution) * 0.95,
            point_shape="square",
            point_shading="flat",
            visible=show == name,
        )
