"""Numerical helpers shared by every geometry function.

Convention:
- powers of possibly-negative numbers go through :func:`signed_pow`;
- shape exponents are clamped to ``[E_MIN, E_MAX]`` (Table 3.1);
- divisions near zero go through :func:`safe_div`.
"""

from __future__ import annotations

import torch

E_MIN = 0.2
E_MAX = 1.7
TINY = 1e-12


def tiny(dtype: torch.dtype) -> float:
    """Smallest magnitude treated as non-zero for ``dtype`` (keeps powers finite)."""
    return 1e-30 if dtype == torch.float64 else 1e-20


def signed_pow(x: torch.Tensor, e: torch.Tensor | float) -> torch.Tensor:
    """``sgn(x) |x|^e`` (the thesis' ``cos^e``), finite with a zero gradient at ``x = 0``."""
    mag = x.abs().clamp_min(tiny(x.dtype))
    return torch.sign(x) * mag.pow(e)


def abs_pow(x: torch.Tensor, e: torch.Tensor | float) -> torch.Tensor:
    """``|x|^e`` with the base clamped away from zero so gradients stay finite."""
    return x.abs().clamp_min(tiny(x.dtype)).pow(e)


def safe_div(num: torch.Tensor, den: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """``num / den`` with ``|den|`` kept >= ``eps`` (sign preserved, 0 treated as +)."""
    den = torch.where(den >= 0, den.clamp_min(eps), den.clamp_max(-eps))
    return num / den


def clamp_shape(e: torch.Tensor) -> torch.Tensor:
    """Clamp shape exponents to the documented range ``[E_MIN, E_MAX]``."""
    return e.clamp(E_MIN, E_MAX)


def finite_max(dtype: torch.dtype) -> float:
    return torch.finfo(dtype).max / 4


def as_tensor(x, dtype: torch.dtype | None = None, device=None) -> torch.Tensor:
    """Convert array-likes to a floating tensor (float32 unless ``x`` is already float64)."""
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(x)
    if dtype is None:
        dtype = t.dtype if t.dtype in (torch.float32, torch.float64) else torch.float32
    return t.to(dtype=dtype, device=device)
