"""Hypothesis strategies over the thesis' parameter ranges (Table 3.1) for the geometry tests.

e in [0.2, 1.7], k in [-0.9, 0.9], b' = max(a1, a2) b in [0.01, 0.75], alpha in [-pi, pi],
sizes in [0.03, 0.53] m (the DSQNet size range).
"""

from __future__ import annotations

import math

import torch
from hypothesis import strategies as st

E = st.floats(0.2, 1.7)
K = st.floats(-0.9, 0.9)
B_PRIME = st.floats(0.01, 0.75)
ALPHA = st.floats(-math.pi, math.pi)
SIZE = st.floats(0.03, 0.53)


@st.composite
def deformed_params(draw, deformed: bool = True) -> torch.Tensor:
    """Packed ``(9,)`` float64 params ``a1 a2 a3 e1 e2 k b alpha a4`` within the thesis ranges."""
    a1, a2, a3 = draw(SIZE), draw(SIZE), draw(SIZE)
    e1, e2 = draw(E), draw(E)
    k, bp, alpha = (draw(K), draw(B_PRIME), draw(ALPHA)) if deformed else (0.0, 0.0, 0.0)
    b = bp / max(a1, a2)
    return torch.tensor([a1, a2, a3, e1, e2, k, b, alpha, 0.0], dtype=torch.float64)


def seeds() -> st.SearchStrategy[int]:
    return st.integers(0, 2**31 - 1)
