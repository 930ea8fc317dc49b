"""The recognition pipeline: validate -> preprocess -> segment -> fit -> :class:`Scene`.

``Recognizer.recognize`` is synchronous and deterministic for ``options.seed``; the gRPC server
and tests call it in-process. ``timings_ms`` holds ``preprocess`` (crop, plane RANSAC and
removal, per-segment re-sampling), ``segment``, ``fit`` and ``total`` (including validation).
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import torch

from sqmanip.errors import UnimplementedError
from sqmanip.geometry import radial_distance

from .config import PerceptionSettings
from .fit import fit_segments
from .mvbb import mvbb_fit
from .preprocess import crop_mask, fit_plane_ransac, resample
from .segment import cluster_with_groups, segments_from_labels
from .types import RecognizedObject, RecognizeRequest, Scene
from .validate import validate_request

log = logging.getLogger(__name__)

MIN_FIT_POINTS = 10
"""Labelled segments with fewer points are not fitted (too few to define a superquadric)."""
MAX_TABLE_POINTS = 6000
"""Support-plane points kept (random subset) for the free-space term."""
CONFIDENCE_SCALE = 0.005
"""``confidence = exp(-rms radial distance / CONFIDENCE_SCALE)`` (m)."""


def _residual(points: np.ndarray, part) -> float:
    x = torch.as_tensor(points, dtype=torch.float64)
    T = torch.as_tensor(np.linalg.inv(part.pose), dtype=torch.float64)
    local = x @ T[:3, :3].T + T[:3, 3]
    d = radial_distance(local, torch.as_tensor(part.params(), dtype=torch.float64))
    return float((d**2).mean())


def _group_parts(
    points: np.ndarray,
    segments: list[np.ndarray],
    clusters: list[int],
    plane,
    contact: float,
) -> list[int]:
    """Object id per segment: a segment that does not reach the support plane is a part of the
    object it rests on (the largest segment cut from the same Euclidean cluster that does), so a
    bottle's neck or a mug's handle become parts of one object while touching objects, which
    both stand on the plane, stay apart. Without a plane every segment is its own object."""
    groups = list(range(len(segments)))
    if plane is None:
        return groups
    grounded = [float(plane.signed_distance(points[seg]).min()) <= contact for seg in segments]
    for i, cl in enumerate(clusters):  # segments are sorted largest first
        if grounded[i]:
            continue
        base = next((j for j, c in enumerate(clusters) if c == cl and grounded[j]), None)
        if base is not None:
            groups[i] = groups[base]
    return groups


def _members(groups: list[int]) -> list[list[int]]:
    """Segment indices per object, objects in order of their first (largest) segment."""
    out: dict[int, list[int]] = {}
    for i, g in enumerate(groups):
        out.setdefault(g, []).append(i)
    return list(out.values())


class Recognizer:
    """Training-free recognizer: RANSAC support plane, clustering and superquadric fitting."""

    def __init__(self, settings: PerceptionSettings | None = None) -> None:
        self.settings = settings or PerceptionSettings()

    def recognize(self, request: RecognizeRequest) -> Scene:
        t_start = time.perf_counter()
        s = self.settings
        valid = validate_request(request, s)
        opt = request.options
        if opt.method in ("network", "hybrid"):
            raise UnimplementedError(
                f"options.method={opt.method!r} needs a trained recognition network, which this "
                "build does not ship yet; use method='optimization' or 'mvbb'"
            )
        if opt.segmentation == "network" and valid.labels is None:
            raise UnimplementedError(
                "options.segmentation='network' needs a trained segmentation network, which this "
                "build does not ship yet; use 'clustering' or pass labels"
            )
        rng = np.random.default_rng(opt.seed)
        points = valid.points

        # --- preprocess: crop, support plane --------------------------------------------------
        t0 = time.perf_counter()
        cropped = np.flatnonzero(crop_mask(points, valid.workspace))
        pts = points[cropped].astype(np.float64)
        plane = None
        if opt.remove_support and len(pts) >= 3:
            plane = fit_plane_ransac(
                pts,
                rng,
                threshold=s.ransac_threshold,
                iterations=s.ransac_iterations,
                eval_points=s.ransac_eval_points,
                viewpoint=valid.viewpoint,
                min_fraction=s.plane_min_fraction,
            )
        table = None
        if plane is not None:
            above = plane.signed_distance(pts) > s.ransac_threshold
            keep = above & ~plane.inliers
            table = pts[plane.inliers]
            if len(table) > MAX_TABLE_POINTS:
                table = table[rng.choice(len(table), MAX_TABLE_POINTS, replace=False)]
            object_idx = cropped[keep]
        else:
            object_idx = cropped
        t_pre = time.perf_counter() - t0

        # --- segment -----------------------------------------------------------------------------
        t0 = time.perf_counter()
        obj_pts = points[object_idx].astype(np.float64)
        if valid.labels is not None:
            local_segments = segments_from_labels(valid.labels[object_idx], MIN_FIT_POINTS)
            groups = list(range(len(local_segments)))
        else:
            local_segments, clusters = cluster_with_groups(obj_pts, s, valid.viewpoint)
            groups = _group_parts(obj_pts, local_segments, clusters, plane, s.part_contact)
        segments = [object_idx[seg] for seg in local_segments]
        t_seg = time.perf_counter() - t0

        # --- resample (preprocessing, 3.5.3) and fit ---------------------------------------------
        t0 = time.perf_counter()
        n = opt.points_per_segment
        clouds = [
            resample(
                points[idx].astype(np.float64),
                n,
                rng,
                voxel=s.voxel_size,
                neighbors=s.upsample_neighbors,
            )
            for idx in segments
        ]
        t_pre += time.perf_counter() - t0

        t0 = time.perf_counter()
        if opt.method == "mvbb":
            parts = [mvbb_fit(points[idx], plane if opt.amodal else None) for idx in segments]
            residuals = [_residual(c, p) for c, p in zip(clouds, parts, strict=True)]
        else:
            fits = fit_segments(
                clouds,
                plane=plane,
                viewpoint=valid.viewpoint,
                table_points=table,
                settings=s,
                amodal=opt.amodal,
                deformable=opt.deformable,
                seed=opt.seed,
            )
            parts = [f.part for f in fits]
            residuals = [f.residual for f in fits]
        t_fit = time.perf_counter() - t0

        objects = []
        for i, members in enumerate(_members(groups)):
            idx = np.concatenate([segments[m] for m in members])
            counts = np.array([len(segments[m]) for m in members], dtype=np.float64)
            res = float(np.average([residuals[m] for m in members], weights=counts))
            color = None
            if valid.colors is not None:
                color = tuple(float(c) for c in valid.colors[idx].mean(0, dtype=np.float64))
            objects.append(
                RecognizedObject(
                    id=i,
                    parts=[parts[m] for m in members],
                    point_indices=idx.astype(np.int64),
                    mean_color=color,
                    residual=res,
                    confidence=float(math.exp(-math.sqrt(max(res, 0.0)) / CONFIDENCE_SCALE)),
                )
            )
        total = time.perf_counter() - t_start
        timings = {
            "preprocess": 1e3 * t_pre,
            "segment": 1e3 * t_seg,
            "fit": 1e3 * t_fit,
            "total": 1e3 * total,
        }
        log.info(
            "recognize method=%s points=%d objects=%d total_ms=%.1f",
            opt.method,
            len(points),
            len(objects),
            timings["total"],
        )
        return Scene(objects, plane.as_support() if plane is not None else None, timings)
