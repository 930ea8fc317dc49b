"""PLY point uploads: the parser lives in :mod:`sqmanip.io.ply` (shared with the ``sqmanip`` CLI);
re-exported here for the gateway's routes and existing imports."""

from sqmanip.io.ply import MAX_HEADER_BYTES, PlyCloud, parse_ply, to_ply

__all__ = ["MAX_HEADER_BYTES", "PlyCloud", "parse_ply", "to_ply"]
