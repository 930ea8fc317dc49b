"""method = network | hybrid and segmentation = network in the Recognizer, with tiny
checkpoints made in the test (independent of the shipped model's training quality).

The "constant" networks have zero output weights, so their prediction is known exactly: a part
centred at the centroid of the segment's (resampled) cloud with half sizes
``0.03 + 0.5 * 0.5 = 0.28`` times the cloud's diameter (Table 3.1 bounds, sigmoid(0) = 0.5),
bending at its lower bound - which checks that the PCA normalisation is undone on the way back
to the world frame."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sqmanip.errors import PreconditionError
from sqmanip.geometry import Superquadric
from sqmanip.perception.config import PerceptionSettings
from sqmanip.perception.learned import serving
from sqmanip.perception.learned.config import TrainConfig, model_config
from sqmanip.perception.learned.hybrid import hidden_side_points, refine_parts
from sqmanip.perception.learned.infer import NetworkRecognizer
from sqmanip.perception.learned.models import build_model
from sqmanip.perception.learned.train import save_model_dir
from sqmanip.perception.pipeline import Recognizer
from sqmanip.perception.synthetic import make_tabletop_scene
from sqmanip.perception.types import RecognizeOptions, RecognizeRequest

TINY = dict(k=4, edge_widths=(8, 8), global_dim=16, head_widths=(16,))


def make_checkpoint(path, name: str = "dsqnet", constant: bool = True):
    torch.manual_seed(0)
    cfg = model_config(name, **TINY)
    model = build_model(name, cfg)
    if constant:
        with torch.no_grad():
            last = [m for m in model.modules() if isinstance(m, torch.nn.Linear | torch.nn.Conv1d)]
            if name == "segnet":  # every point gets label 0
                last[-1].weight.zero_()
                last[-1].bias.copy_(torch.tensor([5.0] + [0.0] * (cfg.max_labels - 1)))
            else:
                for head in model.heads.values():
                    head[-1].weight.zero_()
                    head[-1].bias.zero_()
                model.heads["quaternion"][-1].bias.copy_(torch.tensor([0.0, 0.0, 0.0, 1.0]))
                model.heads["bend"][-1].bias.fill_(-20.0)  # b' at its lower bound 0.01
    save_model_dir(path, model, cfg, TrainConfig(), {"note": "unit-test checkpoint"})
    return path


@pytest.fixture(autouse=True)
def _fresh_cache():
    serving.clear_cache()
    yield
    serving.clear_cache()


@pytest.fixture(scope="module")
def scene():
    return make_tabletop_scene(2, seed=12, n_points=12_000)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    return make_checkpoint(tmp_path_factory.mktemp("dsqnet_const"))


def _request(scene, **opts):
    return RecognizeRequest(
        scene.points, viewpoint=scene.viewpoint, options=RecognizeOptions(**opts)
    )


def test_network_method_predicts_one_part_per_segment_in_the_world_frame(scene, ckpt):
    rec = Recognizer(PerceptionSettings(network_model_dir=ckpt))
    threads = torch.get_num_threads()
    out = rec.recognize(_request(scene, method="network"))
    assert torch.get_num_threads() == threads  # the service's thread setting is restored
    reference = Recognizer().recognize(_request(scene, method="mvbb"))
    assert len(out.objects) == len(reference.objects) == 2
    assert {"network", "fit", "total"} <= set(out.timings_ms)
    for obj in out.objects:
        pts = scene.points[obj.point_indices].astype(np.float64)
        (part,) = obj.parts
        centre = part.pose[:3, 3]
        assert np.linalg.norm(centre - pts.mean(0)) < 0.01  # the normalised origin, mapped back
        diam = np.linalg.norm(pts.max(0) - pts.min(0))
        assert np.allclose(part.size, part.size[0])  # all three equal
        assert 0.2 * diam < part.size[0] < 0.36 * diam
        assert np.allclose(part.shape, (0.95, 0.95), atol=1e-5)  # 0.2 + 1.5 * 0.5
        assert np.allclose(part.pose[:3, :3] @ part.pose[:3, :3].T, np.eye(3), atol=1e-5)
        assert obj.residual > 0 and np.isfinite(obj.residual)
    again = rec.recognize(_request(scene, method="network"))
    for a, b in zip(out.objects, again.objects, strict=True):
        assert np.allclose(a.parts[0].params(), b.parts[0].params())


def test_checkpoint_is_loaded_once_per_process(scene, ckpt, monkeypatch):
    calls = []
    original = NetworkRecognizer.load.__func__

    def counting(cls, *args, **kwargs):
        calls.append(args)
        return original(cls, *args, **kwargs)

    monkeypatch.setattr(NetworkRecognizer, "load", classmethod(counting))
    rec = Recognizer(PerceptionSettings(network_model_dir=ckpt))
    rec.recognize(_request(scene, method="network"))
    Recognizer(PerceptionSettings(network_model_dir=ckpt)).recognize(
        _request(scene, method="network")
    )
    assert len(calls) == 1
    assert serving.get_recognizer(ckpt) is serving.get_recognizer(str(ckpt))


def test_missing_checkpoint_is_a_precondition_error_naming_the_path(scene, tmp_path):
    missing = tmp_path / "no_model_here"
    for opts in (dict(method="network"), dict(method="hybrid"), dict(segmentation="network")):
        rec = Recognizer(
            PerceptionSettings(network_model_dir=missing, segmentation_model_dir=missing)
        )
        with pytest.raises(PreconditionError, match="no_model_here"):
            rec.recognize(_request(scene, **opts))


def test_a_segnet_checkpoint_is_refused_as_a_recognition_network(scene, tmp_path):
    seg = make_checkpoint(tmp_path / "seg", "segnet")
    with pytest.raises(PreconditionError, match="segnet"):
        Recognizer(PerceptionSettings(network_model_dir=seg)).recognize(
            _request(scene, method="network")
        )


def test_hybrid_fits_the_seen_side_better_than_the_network_alone(scene, ckpt):
    s = PerceptionSettings(network_model_dir=ckpt)
    net = Recognizer(s).recognize(_request(scene, method="network"))
    hyb = Recognizer(s).recognize(_request(scene, method="hybrid"))
    assert len(hyb.objects) == len(net.objects)
    update = {"hybrid_hidden_weight": 0.0, "hybrid_iterations": 200}
    seen_only = Recognizer(s.model_copy(update=update)).recognize(_request(scene, method="hybrid"))
    for a, b, c in zip(net.objects, hyb.objects, seen_only.objects, strict=True):
        assert np.array_equal(a.point_indices, b.point_indices)
        # the constant network's sphere is far off: the refinement fits the observed points
        # better, and without the pull toward the network's hidden side much better
        assert b.residual < 0.8 * a.residual, (a.residual, b.residual)
        assert c.residual < 0.2 * a.residual, (a.residual, c.residual)
        assert b.confidence >= a.confidence


def test_hidden_side_points_lie_where_the_view_says_nothing():
    ball = Superquadric((0.05, 0.05, 0.05), (1.0, 1.0))
    rng = np.random.default_rng(0)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    seen = 0.05 * d[d[:, 0] > 0.2]  # the +x cap was observed
    hidden = hidden_side_points(ball, seen, radius=0.01)
    assert len(hidden) > 100
    assert hidden[:, 0].max() < 0.2 * 0.05  # nothing on the observed cap
    assert np.allclose(np.linalg.norm(hidden, axis=1), 0.05, atol=1e-3)


def test_hybrid_keeps_a_bent_network_part_that_the_unbent_fitter_cannot_match():
    from sqmanip.geometry.sampling import sample_surface

    bent = Superquadric((0.015, 0.015, 0.08), (0.3, 1.0), bend=8.0)  # b' = 0.12: a clear arc
    pts, _ = sample_surface(bent.params()[None], 600, generator=0)
    pts = np.asarray(pts[0], dtype=np.float64)
    eye = np.array([0.5, 0.0, 0.0])
    seen = pts[pts[:, 0] > np.median(pts[:, 0])][:300]  # the half facing the camera
    (res,) = refine_parts([seen], [bent], viewpoint=eye, settings=PerceptionSettings())
    assert res.part is bent
    with pytest.raises(ValueError, match="same length"):
        refine_parts([seen], [bent, bent])


def test_network_segmentation_splits_objects_into_network_parts(scene, tmp_path):
    seg = make_checkpoint(tmp_path / "seg", "segnet")
    s = PerceptionSettings(segmentation_model_dir=seg)
    out = Recognizer(s).recognize(_request(scene, method="mvbb", segmentation="network"))
    assert len(out.objects) == 2  # two Euclidean clusters, one part each (label 0 everywhere)
    for obj in out.objects:
        assert len(obj.parts) == 1
        ids = scene.object_ids[obj.point_indices]
        assert (ids == np.bincount(ids + 1).argmax() - 1).mean() > 0.95
