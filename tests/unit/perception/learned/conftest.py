"""Shared fixtures for the learned-recognition tests: one torch thread, a tiny generated dataset
(2 shapes x 2 views of a few types, small ground-truth clouds) built once per session."""

from __future__ import annotations

import pytest
import torch
from sqmanip.perception.learned.datasets import GenerationSpec, generate


@pytest.fixture(autouse=True)
def _one_torch_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def tiny_data(tmp_path_factory):
    """Primitive dataset (B, TT) and object dataset (mug, CY): 2 shapes x 2 views each."""
    out = tmp_path_factory.mktemp("recognition_data")
    torch.set_num_threads(1)
    for ds, types in (("primitive", ("B", "TT")), ("object", ("mug", "CY"))):
        spec = GenerationSpec(
            out=str(out), datasets=(ds,), types=types, shapes=2, n_views=2, n_gt=128, resolution=64
        )
        generate(spec, workers=1, progress=False)
    return out
