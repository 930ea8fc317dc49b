"""File formats a user already has: point clouds in (PLY, NPY, NPZ), meshes out (PLY, OBJ).

No service, no torch at import time: the ``sqmanip`` CLI and the gateway import these modules
directly (``sqmanip.io.ply``, ``sqmanip.io.clouds``, ``sqmanip.io.meshes``).
"""
