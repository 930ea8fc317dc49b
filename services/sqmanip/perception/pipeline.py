"""The recognition pipeline: validate -> preprocess -> segment -> fit -> :class:`Scene`.

``Recognizer.recognize`` is synchronous and deterministic for ``options.seed``; the gRPC server
and tests call it in-process. ``timings_ms`` holds ``preprocess`` (crop, plane RANSAC and
removal, per-segment re-sampling), ``segment``, ``fit`` and ``total`` (including validation);
``method='network' | 'hybrid'`` add ``network`` (the network's share of ``fit``). Learned
networks (:mod:`.learned.serving`) are imported and loaded only when a request asks for them.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import torch
from scipy.spatial import cKDTree

from sqmanip.geometry import radial_distance

from .config import PerceptionSettings
from .fit import fit_segments
from .mvbb import mvbb_fit
from .preprocess import crop_mask, fit_plane_ransac, resample
from .segment import chromaticity, cluster, cluster_with_groups, segments_from_labels
from .threads import blas_threads
from .types import RecognizedObject, RecognizeRequest, Scene
from .validate import validate_request

log = logging.getLogger(__name__)

MIN_FIT_POINTS = 10
"""Labelled segments with fewer points are not fitted (too few to define a superquadric)."""
MAX_TABLE_POINTS = 6000
"""Support-plane points, and points below the plane, kept (random subsets) for the free-space
term."""
CONFIDENCE_SCALE = 0.005
"""``confidence = exp(-rms radial distance / CONFIDENCE_SCALE)`` (m)."""


def _at_most(points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return points[rng.choice(len(points), n, replace=False)] if len(points) > n else points


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
    colors: np.ndarray | None = None,
    color_tolerance: float = 0.0,
) -> list[int]:
    """Object id per segment: a segment that does not reach the support plane is a part of the
    object it rests on (the largest segment cut from the same Euclidean cluster that does), so a
    bottle's neck or a mug's handle become parts of one object while touching objects, which
    both stand on the plane, stay apart. With ``colors (N, 3)``, only segments of one colour
    join (a can whose lower half a neighbour hides is not the neighbour's part). Without a
    plane every segment is its own object."""
    groups = list(range(len(segments)))
    if plane is None:
        return groups
    same = _same_colour(colors, segments, color_tolerance)
    heights = [plane.signed_distance(points[seg]) for seg in segments]
    grounded = [float(h.min()) <= contact for h in heights]
    anchored = list(grounded)
    for i, cl in enumerate(clusters):  # segments are sorted largest first
        if grounded[i]:
            continue
        base = next(
            (j for j, c in enumerate(clusters) if c == cl and grounded[j] and same[i, j]), None
        )
        if base is None:
            base = _stacked_base(points, segments, heights, contact, i)
            base = base if base is not None and same[i, base] else None
        if base is not None:
            groups[i] = groups[base]
            anchored[i] = True
    # a floating segment of the same cluster as one anchored above (a neck on a shoulder that
    # joined the body across the overhang's gap) joins that object too
    changed = True
    while changed:
        changed = False
        for i, cl in enumerate(clusters):
            if anchored[i]:
                continue
            j = next(
                (j for j, c in enumerate(clusters) if c == cl and anchored[j] and same[i, j]), None
            )
            if j is not None:
                groups[i], anchored[i], changed = groups[j], True, True
    return groups


def _same_colour(
    colors: np.ndarray | None, segments: list[np.ndarray], tolerance: float
) -> np.ndarray:
    """``(S, S)`` bool: segments whose mean chromaticity (bright points) differ by at most
    ``tolerance``; all True without colours."""
    n = len(segments)
    if colors is None or n == 0:
        return np.ones((n, n), dtype=bool)
    chroma, bright = chromaticity(colors)
    mean = np.array(
        [
            chroma[seg][bright[seg]].mean(0) if bright[seg].any() else np.full(3, np.nan)
            for seg in segments
        ]
    )
    d = np.linalg.norm(mean[:, None] - mean[None], axis=-1)
    return ~(d > tolerance)  # NaN (a dark segment) compares as the same colour


FRAGMENT_GAP = 0.05
"""Largest distance (m) from a small same-coloured segment to the segment it is a fragment of."""


def _absorb_fragments(
    points: np.ndarray,
    segments: list[np.ndarray],
    clusters: list[int],
    colors: np.ndarray | None,
    tolerance: float,
    fragment_points: int,
) -> tuple[list[np.ndarray], list[int]]:
    """With colours, a segment of fewer than ``fragment_points`` points (a strip of a box's side
    seen through a gap between its neighbours) is merged into the nearest larger segment of its
    colour within ``FRAGMENT_GAP`` instead of becoming an object of its own."""
    if colors is None or fragment_points <= 0:
        return segments, clusters
    same = _same_colour(colors, segments, tolerance)
    big = [j for j, seg in enumerate(segments) if len(seg) >= fragment_points]
    merged = {j: [segments[j]] for j in range(len(segments))}
    for i, seg in enumerate(segments):
        if len(seg) >= fragment_points:
            continue
        gaps = {
            j: float(cKDTree(points[segments[j]]).query(points[seg])[0].min())
            for j in big
            if same[i, j]
        }
        if gaps and min(gaps.values()) <= FRAGMENT_GAP:
            merged[min(gaps, key=gaps.get)].append(seg)
            del merged[i]
    keep = sorted(merged)
    return [np.concatenate(merged[j]) for j in keep], [clusters[j] for j in keep]


STACK_GAP = 0.03
"""Largest vertical gap (m) in the cloud between a floating segment and the grounded segment right
below it for both to count as one object (an overhang, e.g. a bottle's shoulder, hides a band of
the body under it from a camera above and splits the Euclidean cluster there)."""


def _stacked_base(
    points: np.ndarray,
    segments: list[np.ndarray],
    heights: list[np.ndarray],
    contact: float,
    i: int,
) -> int | None:
    """The segment (largest first) directly under floating segment ``i``: it starts near the
    plane (within ``3 contact``: plane removal and self-occlusion eat an object's lowest band),
    its top lies at most ``STACK_GAP`` below segment ``i``'s bottom, and the centroid of either
    lies inside the other's horizontal bounding box (world x, y; the support plane is near level)."""
    lo_i = float(heights[i].min())
    xy_i = points[segments[i], :2]
    for j, seg in enumerate(segments):
        if j == i or float(heights[j].min()) > 3 * contact:
            continue
        gap = lo_i - float(heights[j].max())
        if gap > STACK_GAP or lo_i <= float(heights[j].min()):
            continue
        xy_j = points[seg, :2]
        inside_j = np.all((xy_i.mean(0) >= xy_j.min(0)) & (xy_i.mean(0) <= xy_j.max(0)))
        inside_i = np.all((xy_j.mean(0) >= xy_i.min(0)) & (xy_j.mean(0) <= xy_i.max(0)))
        if inside_j or inside_i:
            return j
    return None


def _members(groups: list[int]) -> list[list[int]]:
    """Segment indices per object, objects in order of their first (largest) segment."""
    out: dict[int, list[int]] = {}
    for i, g in enumerate(groups):
        out.setdefault(g, []).append(i)
    return list(out.values())


class Recognizer:
    """RANSAC support plane, segmentation (clustering, labels or the segmentation network) and
    per-segment shapes (optimisation fitting, MVBB, the recognition network, or the network
    refined by the fitter: ``method='hybrid'``). Networks load lazily, once per process."""

    def __init__(self, settings: PerceptionSettings | None = None) -> None:
        self.settings = settings or PerceptionSettings()

    def _network_segments(
        self, obj_pts: np.ndarray, viewpoint: np.ndarray | None, seed: int
    ) -> tuple[list[np.ndarray], list[int]]:
        """Euclidean clusters are objects; the segmentation network (A.2) splits each into
        parts. Returns index arrays into ``obj_pts`` (largest object first) and the object id
        of each."""
        from .learned import serving

        s = self.settings
        objects = cluster(obj_pts, s.model_copy(update={"split_touching": False}), viewpoint)
        segments: list[np.ndarray] = []
        groups: list[int] = []
        for gi, idx in enumerate(objects):
            parts = serving.segment_object(
                obj_pts[idx],
                model_dir=s.segmentation_model_dir,
                threads=s.torch_threads,
                seed=seed,
                min_points=MIN_FIT_POINTS,
            )
            segments += [idx[p] for p in parts]
            groups += [gi] * len(parts)
        return segments, groups

    def recognize(self, request: RecognizeRequest) -> Scene:
        with blas_threads(self.settings.blas_threads):
            return self._recognize(request)

    def _recognize(self, request: RecognizeRequest) -> Scene:
        t_start = time.perf_counter()
        s = self.settings
        valid = validate_request(request, s)
        opt = request.options
        learned = None
        if opt.method in ("network", "hybrid") or (
            opt.segmentation == "network" and valid.labels is None
        ):
            from .learned import serving as learned  # torch networks: loaded on first use

            # fail fast (PreconditionError naming the path) before any work is done
            if opt.method in ("network", "hybrid"):
                learned.get_recognizer(s.network_model_dir)
            if opt.segmentation == "network" and valid.labels is None:
                learned.get_segmenter(s.segmentation_model_dir)
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
            # seen-through evidence for the amodal fit: the support plane, and anything seen
            # below it anywhere in the frame (the floor past a table's edge)
            seen = points[:: max(1, len(points) // (8 * MAX_TABLE_POINTS))]  # enough, cheaply
            below = seen[plane.signed_distance(seen) < -s.ransac_threshold]
            table = np.concatenate(
                [_at_most(pts[plane.inliers], MAX_TABLE_POINTS, rng),
                 _at_most(below.astype(np.float64), MAX_TABLE_POINTS, rng)]
            )  # fmt: skip
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
        elif opt.segmentation == "network":
            local_segments, groups = self._network_segments(obj_pts, valid.viewpoint, opt.seed)
        else:
            obj_colors = valid.colors[object_idx] if opt.segmentation == "color" else None
            local_segments, clusters = cluster_with_groups(obj_pts, s, valid.viewpoint, obj_colors)
            local_segments, clusters = _absorb_fragments(
                obj_pts, local_segments, clusters, obj_colors, s.color_tolerance, s.fragment_points
            )
            groups = _group_parts(
                obj_pts,
                local_segments,
                clusters,
                plane,
                s.part_contact,
                obj_colors,
                s.color_tolerance,
            )
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
        t_net = 0.0
        if opt.method == "mvbb":
            parts = [mvbb_fit(points[idx], plane if opt.amodal else None) for idx in segments]
            residuals = [_residual(c, p) for c, p in zip(clouds, parts, strict=True)]
        elif opt.method in ("network", "hybrid"):
            parts = learned.predict_parts(
                clouds, model_dir=s.network_model_dir, threads=s.torch_threads, seed=opt.seed
            )
            t_net = time.perf_counter() - t0
            if opt.method == "hybrid":
                from .learned.hybrid import refine_parts

                fits = refine_parts(
                    clouds,
                    parts,
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
            else:
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
            **({"network": 1e3 * t_net} if opt.method in ("network", "hybrid") else {}),
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
