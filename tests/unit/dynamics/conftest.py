"""Run the dynamics tests on one torch thread: these small nets are slower with two threads
on a shared 2-core machine (thread contention), and results do not depend on it."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def _one_torch_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
