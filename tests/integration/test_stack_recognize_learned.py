"""End to end with the shipped networks: the launcher starts perception and the gateway on free
loopback ports; a synthetic tabletop scene goes through the SDK with method=network and
method=hybrid, which load ``models/dsqnet_cpu`` inside the perception process, and with
segmentation=network (``models/segnet_cpu``). Checks the wiring (one object per ground-truth
object, parts where the objects are), not the models' accuracy, which the model cards and
``benchmarks/recognition_learned.py`` report."""

from pathlib import Path

import numpy as np
import pytest
import sqmanip_client as sdk
from sqmanip.launch import running_stack
from sqmanip.perception.learned.serving import default_model_dir
from sqmanip.perception.synthetic import make_tabletop_scene

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def stack():
    with running_stack(services=("perception",)) as s:
        yield s


@pytest.mark.parametrize("method", ["network", "hybrid"])
def test_learned_methods_answer_through_the_sdk(stack, method: str) -> None:
    scene = make_tabletop_scene(2, seed=12)
    with sdk.Client(stack.gateway_url, timeout=120) as client:
        result = client.recognize(scene.points, viewpoint=scene.viewpoint, method=method)
    assert len(result.objects) == 2
    assert result.timings_ms["network"] > 0
    for obj in result.objects:
        seen = scene.points[obj.point_indices]
        lo, hi = seen.min(0) - 0.05, seen.max(0) + 0.05
        for part in obj.parts:
            sq = sdk.to_superquadric(part)
            assert np.all(sq.pose[:3, 3] > lo) and np.all(sq.pose[:3, 3] < hi)
            assert all(0 < s < 0.6 for s in sq.size)


def test_network_segmentation_answers_through_the_sdk(stack) -> None:
    scene = make_tabletop_scene(2, seed=12)
    with sdk.Client(stack.gateway_url, timeout=120) as client:
        result = client.recognize(scene.points, viewpoint=scene.viewpoint, segmentation="network")
    assert len(result.objects) == 2
    for obj in result.objects:
        ids = scene.object_ids[obj.point_indices]
        assert (ids == np.bincount(ids + 1).argmax() - 1).mean() > 0.95
        assert 1 <= len(obj.parts) <= 3


@pytest.mark.parametrize("name", ["sqnet_cpu", "dsqnet_cpu", "dsqnet_plus_cpu", "segnet_cpu"])
def test_shipped_model_dirs_resolve_to_the_repository(name: str) -> None:
    assert default_model_dir(name).parts[-2:] == ("models", name)
    for f in ("model.pt", "config.toml", "MODEL_CARD.md"):
        assert (Path(default_model_dir(name)) / f).is_file()
