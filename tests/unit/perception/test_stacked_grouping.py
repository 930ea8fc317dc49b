"""Parts grouping across an overhang's gap (pipeline._group_parts): a bottle's shoulder hides a
band of its body from a camera above, so body and shoulder+neck come out as two Euclidean
clusters; they are still one object, while two objects side by side stay apart."""

import numpy as np
from sqmanip.perception.pipeline import _group_parts


class LevelPlane:
    """z = 0, up."""

    def signed_distance(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x)[:, 2]


def ring(center_xy, radius, z0, z1, n=200, seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(z0, z1, n)
    return np.stack([center_xy[0] + radius * np.cos(t), center_xy[1] + radius * np.sin(t), z], -1)


def test_shoulder_and_neck_above_a_gap_join_the_body_below():
    body = ring((0.5, 0.0), 0.03, 0.012, 0.09, seed=1)  # lowest band lost to plane removal
    shoulder = ring((0.5, 0.0), 0.035, 0.108, 0.14, seed=2)
    neck = ring((0.5, 0.0), 0.013, 0.145, 0.18, seed=3)
    pts = np.concatenate([shoulder, body, neck])
    segs = [np.arange(0, 200), np.arange(200, 400), np.arange(400, 600)]
    clusters = [0, 1, 0]  # the gap at z 0.09-0.108 splits the Euclidean cluster
    groups = _group_parts(pts, segs, clusters, LevelPlane(), contact=0.01)
    assert len(set(groups)) == 1


def test_objects_side_by_side_and_far_floating_segments_stay_apart():
    a = ring((0.5, 0.0), 0.03, 0.0, 0.09, seed=1)
    b = ring((0.6, 0.1), 0.03, 0.0, 0.09, seed=2)
    high = ring((0.5, 0.0), 0.02, 0.2, 0.25, seed=3)  # 11 cm above a: not a part of it
    pts = np.concatenate([a, b, high])
    segs = [np.arange(0, 200), np.arange(200, 400), np.arange(400, 600)]
    groups = _group_parts(pts, segs, [0, 1, 2], LevelPlane(), contact=0.01)
    assert len(set(groups)) == 3


def test_a_small_fragment_joins_the_nearby_segment_of_its_colour_only():
    """A strip of a red box seen through a gap (60 points, 3 cm away) joins the red box; a blue
    strip, or one 10 cm away, stays its own segment."""
    from sqmanip.perception.pipeline import _absorb_fragments

    rng = np.random.default_rng(0)
    box = rng.uniform([0.0, 0.0, 0.0], [0.1, 0.05, 0.03], (2000, 3))
    near = rng.uniform([0.13, 0.0, 0.0], [0.14, 0.05, 0.01], (60, 3))
    far = rng.uniform([0.20, 0.0, 0.0], [0.21, 0.05, 0.01], (60, 3))
    pts = np.concatenate([box, near, far])
    segs = [np.arange(2000), np.arange(2000, 2060), np.arange(2060, 2120)]
    red, blue = [0.8, 0.1, 0.1], [0.1, 0.2, 0.8]
    colours = np.array([red] * 2120)
    merged, clusters = _absorb_fragments(pts, segs, [0, 1, 2], colours, 0.06, 200)
    assert [len(s) for s in merged] == [2060, 60] and clusters == [0, 2]
    colours[2000:2060] = blue
    kept, _ = _absorb_fragments(pts, segs, [0, 1, 2], colours, 0.06, 200)
    assert [len(s) for s in kept] == [2000, 60, 60]
    unchanged, _ = _absorb_fragments(pts, segs, [0, 1, 2], None, 0.06, 200)
    assert unchanged is segs
