"""Euclidean clustering, convexity split of touching objects, and label segments."""

from __future__ import annotations

import numpy as np
from sqmanip.perception.config import PerceptionSettings
from sqmanip.perception.segment import cluster, segments_from_labels

EYE = np.array([0.0, -0.5, 0.6])


def _visible_sphere(center, radius, rng, n=3000):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    pts = center + radius * v
    seen = ((EYE - pts) * v).sum(1) > 0
    return pts[seen] + rng.normal(scale=0.0005, size=(seen.sum(), 3))


def test_separated_objects_become_separate_clusters_and_clutter_is_dropped():
    rng = np.random.default_rng(0)
    a = _visible_sphere(np.array([0.0, 0.0, 0.05]), 0.05, rng)
    b = _visible_sphere(np.array([0.15, 0.0, 0.04]), 0.04, rng)
    speck = np.array([[0.4, 0.4, 0.4], [0.401, 0.4, 0.4]])
    pts = np.concatenate([a, b, speck])
    segs = cluster(pts, PerceptionSettings(), EYE)
    assert len(segs) == 2
    assert set(segs[0]) == set(range(len(a)))
    assert set(segs[1]) == set(range(len(a), len(a) + len(b)))


def test_touching_objects_are_split_at_the_concave_seam():
    rng = np.random.default_rng(1)
    a = _visible_sphere(np.array([0.0, 0.0, 0.05]), 0.05, rng, 6000)
    b = _visible_sphere(np.array([0.095, 0.0, 0.05]), 0.05, rng, 6000)
    # keep only the visible union (points of one sphere inside the other are hidden)
    a = a[np.linalg.norm(a - [0.095, 0, 0.05], axis=1) > 0.05]
    b = b[np.linalg.norm(b - [0.0, 0, 0.05], axis=1) > 0.05]
    pts = np.concatenate([a, b])
    merged = cluster(pts, PerceptionSettings(split_touching=False), EYE)
    assert len(merged) == 1
    segs = cluster(pts, PerceptionSettings(), EYE)
    assert len(segs) == 2
    truth = np.r_[np.zeros(len(a)), np.ones(len(b))]
    purity = [np.bincount(truth[s].astype(int)).max() / len(s) for s in segs]
    assert min(purity) > 0.95


def test_flush_boxes_of_different_colours_are_split_and_one_colour_stays_whole():
    """Two 6 cm boxes pushed together (one flat top, no concave seam) seen from above: one
    segment without colours, two with (a red and a blue box, shaded differently per face)."""
    rng = np.random.default_rng(2)
    top = np.column_stack([rng.uniform(-0.06, 0.06, 8000), rng.uniform(-0.03, 0.03, 8000)])
    top = np.column_stack([top, np.full(len(top), 0.06)])
    side = np.column_stack(
        [rng.uniform(-0.06, 0.06, 4000), np.full(4000, -0.03), rng.uniform(0.0, 0.06, 4000)]
    )
    pts = np.concatenate([top, side]) + rng.normal(scale=0.0005, size=(12000, 3))
    left = pts[:, 0] < 0
    shade = np.where(pts[:, 2] > 0.059, 1.0, 0.6)[:, None]  # lit top, darker side
    colors = shade * np.where(left[:, None], [0.8, 0.1, 0.1], [0.15, 0.3, 0.7])
    eye = np.array([0.0, -0.4, 0.6])
    assert len(cluster(pts, PerceptionSettings(), eye)) == 1
    segs = cluster(pts, PerceptionSettings(), eye, colors)
    assert len(segs) == 2
    purity = [np.bincount(left[s].astype(int)).max() / len(s) for s in segs]
    assert min(purity) > 0.97
    one_colour = np.full_like(colors, 0.5) * shade
    assert len(cluster(pts, PerceptionSettings(), eye, one_colour)) == 1


def test_segments_from_labels_ignores_background_and_tiny_labels():
    labels = np.array([-1, 0, 0, 2, 2, 2, -1, 5])
    segs = segments_from_labels(labels, min_points=2)
    assert [s.tolist() for s in segs] == [[1, 2], [3, 4, 5]]


def test_objects_of_different_colours_joined_by_a_few_edges_are_split():
    """A red and a blue can top 10 cm apart, joined by a sparse chain of points (a strip of side
    wall seen between them) whose colour changes halfway: no node has the two cut edges that
    make a seam node, so only cutting colour edges outright separates them (a red can once
    vanished into its blue neighbour this way in a grasping-clutter scene)."""
    rng = np.random.default_rng(3)

    def can_top(cx: float, n: int = 3000) -> np.ndarray:
        r = 0.034 * np.sqrt(rng.uniform(size=n))
        t = rng.uniform(0, 2 * np.pi, n)
        return np.column_stack([cx + r * np.cos(t), r * np.sin(t), np.full(n, 0.10)])

    # 0.037, 0.046, 0.055, 0.064: 9 mm apart (under the 12 mm clustering radius), red then blue
    chain = np.column_stack([0.037 + 0.009 * np.arange(4), np.zeros(4), np.full(4, 0.10)])
    pts = np.concatenate([can_top(0.0), chain, can_top(0.10)])
    red, blue = [0.7, 0.08, 0.08], [0.13, 0.26, 0.6]
    colors = np.array([red] * 3002 + [blue] * 3002)
    eye = np.array([0.05, 0.0, 0.7])
    assert len(cluster(pts, PerceptionSettings(split_touching=False), eye)) == 1
    segs = cluster(pts, PerceptionSettings(), eye, colors)
    assert len(segs) == 2
    is_red = np.arange(len(pts)) < 3002
    assert all(is_red[s].all() or not is_red[s].any() for s in segs)
