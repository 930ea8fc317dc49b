"""Shared fixtures for the geometry tests: dtypes and one tolerance table (kornia style)."""

from __future__ import annotations

import pytest
import torch

# (rtol, atol) per dtype for comparing results of the same math done two ways. Tests that
# compare against finite differences or chain many powers scale these explicitly.
DTYPE_TOLERANCES: dict[torch.dtype, tuple[float, float]] = {
    torch.float32: (1e-4, 1e-5),
    torch.float64: (1e-9, 1e-10),
}


def tolerances(dtype: torch.dtype, scale: float = 1.0) -> dict[str, float]:
    """``rtol``/``atol`` keyword arguments for ``torch.testing.assert_close`` at ``dtype``."""
    rtol, atol = DTYPE_TOLERANCES[dtype]
    return {"rtol": rtol * scale, "atol": atol * scale}


@pytest.fixture(params=[torch.float32, torch.float64], ids=["float32", "float64"])
def dtype(request: pytest.FixtureRequest) -> torch.dtype:
    return request.param


@pytest.fixture()
def tol():
    """The :func:`tolerances` helper, as a fixture (test modules are not importable packages)."""
    return tolerances
