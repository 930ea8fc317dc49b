"""Minimal PLY point-cloud reader and writer: ``ascii`` and ``binary_little_endian``, one
``vertex`` element with ``x y z`` and optional ``red green blue`` (other properties are skipped;
with ``allow_mesh=True`` later elements, e.g. a mesh's face lists, are ignored: the vertices are
the cloud).

Shared by the gateway (PLY uploads) and the ``sqmanip`` CLI (``sqmanip recognize cloud.ply``).

Parsed with numpy only (no pickle, no eval). Colors: integer types are scaled by their maximum
(uchar / 255), float colors are taken as [0, 1]. Any malformed input raises
:class:`sqmanip.errors.ValidationError` naming what is wrong.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from sqmanip.errors import ValidationError

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
MAX_HEADER_BYTES = 16 * 1024


@dataclasses.dataclass(frozen=True)
class PlyCloud:
    points: np.ndarray
    """(N, 3) float32."""
    colors: np.ndarray | None
    """(N, 3) float32 in [0, 1], or None."""


def _header(data: bytes) -> tuple[list[str], int]:
    if not data.startswith(b"ply"):
        raise ValidationError("ply: file must start with 'ply'")
    end = data.find(b"end_header", 0, MAX_HEADER_BYTES)
    if end < 0:
        raise ValidationError(f"ply: no 'end_header' in the first {MAX_HEADER_BYTES} bytes")
    nl = data.find(b"\n", end)
    body_start = len(data) if nl < 0 else nl + 1
    try:
        text = data[:end].decode("ascii")
    except UnicodeDecodeError:
        raise ValidationError("ply: header must be ASCII") from None
    return [ln.strip() for ln in text.splitlines() if ln.strip()], body_start


def parse_ply(data: bytes, max_points: int | None = None, *, allow_mesh: bool = False) -> PlyCloud:
    """Parse a PLY file's bytes into points and optional colors.

    ``allow_mesh``: accept list properties in elements after ``vertex`` (a mesh's faces) and
    ignore them; the gateway's uploads reject them (a cloud is expected there).
    """
    lines, body_start = _header(data)
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for ln in lines[1:]:
        parts = ln.split()
        if parts[0] in ("comment", "obj_info"):
            continue
        if parts[0] == "format":
            if len(parts) < 2 or parts[1] not in ("ascii", "binary_little_endian"):
                got = parts[1] if len(parts) > 1 else ""
                raise ValidationError(
                    f"ply: format must be ascii or binary_little_endian, got {got!r}"
                )
            fmt = parts[1]
        elif parts[0] == "element":
            if len(parts) != 3 or not parts[2].isdigit():
                raise ValidationError(f"ply: bad element line {ln!r}")
            elements.append((parts[1], int(parts[2]), []))
        elif parts[0] == "property":
            if not elements:
                raise ValidationError("ply: property before any element")
            if len(parts) >= 2 and parts[1] == "list":
                if allow_mesh and len(elements) > 1:
                    continue  # e.g. a mesh's face lists: only the vertex element is read
                raise ValidationError(
                    f"ply: list properties are not supported in element {elements[-1][0]!r}"
                )
            if len(parts) != 3 or parts[1] not in _TYPES:
                raise ValidationError(f"ply: bad property line {ln!r}")
            elements[-1][2].append((parts[2], parts[1]))
        else:
            raise ValidationError(f"ply: unexpected header line {ln!r}")
    if fmt is None:
        raise ValidationError("ply: missing 'format' line")
    if not elements or elements[0][0] != "vertex":
        raise ValidationError("ply: the first element must be 'vertex'")
    _, n, props = elements[0]
    names = [p[0] for p in props]
    for axis in ("x", "y", "z"):
        if axis not in names:
            raise ValidationError(f"ply: vertex element has no '{axis}' property")
    if max_points is not None and n > max_points:
        raise ValidationError(f"points: expected at most {max_points} points, got {n}")
    dtype = np.dtype([(name, "<" + _TYPES[t]) for name, t in props])
    body = data[body_start:]
    if fmt == "binary_little_endian":
        need = n * dtype.itemsize
        if len(body) < need:
            raise ValidationError(
                f"ply: {n} vertices need {need} bytes of binary data, got {len(body)}"
            )
        table = np.frombuffer(body, dtype=dtype, count=n)
    else:
        rows = [r for r in body.split(b"\n", n)[:n] if r.strip()] if n else []
        if len(rows) < n:
            raise ValidationError(f"ply: expected {n} vertex lines, got {len(rows)}")
        try:
            values = np.array([r.split() for r in rows], dtype=np.float64)
        except ValueError:
            raise ValidationError(f"ply: each vertex line must hold {len(props)} numbers") from None
        if values.shape != (n, len(props)):
            raise ValidationError(
                f"ply: each vertex line must hold {len(props)} numbers, got shape {values.shape}"
            )
        table = np.zeros(n, dtype=dtype)
        for i, name in enumerate(names):
            table[name] = values[:, i]
    points = np.stack([table["x"], table["y"], table["z"]], axis=1).astype(np.float32)
    colors = None
    if all(c in names for c in ("red", "green", "blue")):
        cols = np.stack([table["red"], table["green"], table["blue"]], axis=1)
        if np.issubdtype(cols.dtype, np.integer):
            colors = (cols.astype(np.float32) / np.iinfo(cols.dtype).max).astype(np.float32)
        else:
            colors = cols.astype(np.float32)
    return PlyCloud(points, colors)


def to_ply(points: np.ndarray, colors: np.ndarray | None = None, *, binary: bool = True) -> bytes:
    """Write ``points (N, 3)`` (and ``colors (N, 3)`` in [0, 1]) as PLY (for tests and tools)."""
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    n = len(pts)
    props = ["property float x", "property float y", "property float z"]
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        props += ["property uchar red", "property uchar green", "property uchar blue"]
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    fmt = "binary_little_endian" if binary else "ascii"
    header = "\n".join(["ply", f"format {fmt} 1.0", f"element vertex {n}", *props, "end_header"])
    table = np.zeros(n, dtype=np.dtype(fields))
    table["x"], table["y"], table["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if colors is not None:
        rgb = np.rint(np.clip(np.asarray(colors, dtype=np.float64), 0, 1) * 255).astype(np.uint8)
        table["red"], table["green"], table["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    if binary:
        return header.encode() + b"\n" + table.tobytes()
    rows = [" ".join(repr(v.item()) for v in row) for row in table]
    return (header + "\n" + "\n".join(rows) + "\n").encode()
