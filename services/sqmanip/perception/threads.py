"""Thread limits for the pipeline's compute libraries, applied per call and restored after.

The pipeline's arrays are small (a segment is 300 points, a rotation 3 x 3), so intra-op
threads never pay for their synchronisation. Worse, numpy's OpenBLAS keeps its idle threads
spinning for milliseconds after each call: a /recognize request used twice its wall time in
CPU, and the spinning thread took the second core from the gateway and the other services.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from threadpoolctl import ThreadpoolController

_blas: ThreadpoolController | None = None


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run with ``n`` torch intra-op threads (None or 0: leave torch's setting), restored after."""
    before = torch.get_num_threads()
    if n and n != before:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if torch.get_num_threads() != before:
            torch.set_num_threads(before)


@contextlib.contextmanager
def blas_threads(n: int | None) -> Iterator[None]:
    """Run with ``n`` BLAS threads (None or 0: leave the library's setting), restored after."""
    global _blas
    if not n:
        yield
        return
    if _blas is None:  # finding the loaded libraries takes a few ms: once per process
        _blas = ThreadpoolController()
    with _blas.limit(limits=n, user_api="blas"):
        yield
