"""R-SQPD-Net inputs: objects recognized from each tuple's observed cloud (Ch. 4.6, Table 4.2).

The thesis' R-SQPD-Net chains a recognition network ``R`` (poses and superquadric shapes from
the observation) with SQPD-Net. Here ``R`` is the in-process perception pipeline
(:class:`sqmanip.perception.pipeline.Recognizer`, amodal optimisation fit, non-deformable
superquadrics since the pushing objects are boxes and cylinders), run on the observed cloud
stored with each tuple (:mod:`.generate`).

The stored cloud keeps object points only, so the visible table is re-created: every pixel of
the split's camera (``meta.camera``) that no observed object point covers (dilated by
``dilate`` pixels, since the cloud is sub-sampled) is back-projected onto the table plane
``z = 0``. This gives the recognizer its support plane and free-space evidence (3.4) as in the
live pipeline; labels come from the cloud (segmentation errors stay out, as in 3.5.1).

Metrics: the recognized frame of an object differs from its ground-truth frame (axis order,
symmetries), so poses cannot be compared directly. The network's prediction is turned into the
world-frame rigid motion ``W = T'_rec T_rec^{-1}`` of each recognized object and applied to the
ground-truth pose, ``T'_pred = W T_gt``; flows, pose errors and IoUs are then computed against
the ground truth exactly as for GT-SQPD-Net, so the error includes what wrong recognized shapes
and poses do to the predicted motion. Objects the recognizer misses (fewer than 10 observed
points) are left out of the network's scene and predicted not to move.

Recognition costs ~0.3-1 s per tuple, so results are cached per split in
``<cache_dir>/<split>.npz``, keyed by the split's manifest and the options.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .data import PushBatch, PushTensors
from .model import SQPDNet

__all__ = [
    "RECOGNIZE_OPTIONS",
    "load_or_recognize",
    "predict_recognized",
    "recognize_split",
    "recognize_tuple",
    "upright_frames",
    "visible_table_points",
]

log = logging.getLogger(__name__)

RECOGNIZE_OPTIONS: dict[str, Any] = {
    "method": "optimization",
    "segmentation": "labels",
    "amodal": True,
    "deformable": False,
    "remove_support": True,
    "seed": 0,
}
"""Recognizer options used for R-SQPD-Net (also part of the cache key)."""


def visible_table_points(
    cloud: np.ndarray, camera: Any, *, stride: int = 3, dilate: int = 3
) -> np.ndarray:
    """Table points ``(T, 3)`` on ``z = 0`` seen by ``camera`` around the object ``cloud (P, 3)``.

    A pixel (on a ``stride`` grid) is table if its ray meets ``z = 0`` in front of the camera and
    no object point projects within ``dilate`` pixels of it (the object hides the table there).
    """
    cloud = np.asarray(cloud, dtype=np.float64).reshape(-1, 3)
    pose = np.asarray(camera.pose, dtype=np.float64)
    R, t = pose[:3, :3], pose[:3, 3]
    h, w = int(camera.height), int(camera.width)
    covered = np.zeros((h, w), dtype=bool)
    if len(cloud):
        local = (cloud - t) @ R  # world -> camera (R^T (x - t))
        front = local[:, 2] > 1e-6
        local = local[front]
        u = np.round(camera.fx * local[:, 0] / local[:, 2] + camera.cx).astype(int)
        v = np.round(camera.fy * local[:, 1] / local[:, 2] + camera.cy).astype(int)
        for du in range(-dilate, dilate + 1):
            for dv in range(-dilate, dilate + 1):
                uu, vv = u + du, v + dv
                ok = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
                covered[vv[ok], uu[ok]] = True
    vs, us = np.mgrid[0:h:stride, 0:w:stride]
    free = ~covered[vs, us]
    us, vs = us[free].astype(np.float64), vs[free].astype(np.float64)
    rays = np.stack([(us - camera.cx) / camera.fx, (vs - camera.cy) / camera.fy,
                     np.ones_like(us)], -1) @ R.T  # fmt: skip
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -t[2] / rays[:, 2]
    hit = np.isfinite(s) & (s > 0)
    return t + s[hit, None] * rays[hit]


def recognize_tuple(
    recognizer: Any,
    cloud: np.ndarray,
    labels: np.ndarray,
    n_objects: int,
    camera: Any,
    options: dict[str, Any] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Recognize one tuple's objects from its cloud ``(P, 3)`` with labels ``(P,)`` (object index).

    Returns ``poses (n, 4, 4)``, ``params (n, 9)``, ``kinds (n,)`` and ``found (n,)`` bool, in
    the tuple's object order (the label of the majority of an object's points).
    """
    from sqmanip.perception.types import RecognizeOptions, RecognizeRequest

    opts = RecognizeOptions(**{**RECOGNIZE_OPTIONS, **(options or {})})
    cloud = np.asarray(cloud, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    table = visible_table_points(cloud, camera)
    points = np.concatenate([cloud, table]).astype(np.float32)
    all_labels = np.concatenate([labels, np.full(len(table), -1)]).astype(np.int32)
    viewpoint = np.asarray(camera.pose, dtype=np.float64)[:3, 3]
    scene = recognizer.recognize(
        RecognizeRequest(points, labels=all_labels, viewpoint=viewpoint, options=opts)
    )
    poses = np.tile(np.eye(4), (n_objects, 1, 1))
    params = np.zeros((n_objects, 9))
    kinds = np.zeros(n_objects, dtype=np.int64)
    found = np.zeros(n_objects, dtype=bool)
    for obj in scene.objects:
        lab = all_labels[obj.point_indices]
        lab = lab[(lab >= 0) & (lab < n_objects)]
        if lab.size == 0 or not obj.parts:
            continue
        i = int(np.bincount(lab).argmax())
        part = obj.parts[0]
        poses[i], params[i], kinds[i], found[i] = part.pose, part.params(), part.kind_index, True
    return poses, params, kinds, found


def recognize_split(
    data: PushTensors, camera: Any, *, progress: bool = True
) -> dict[str, np.ndarray]:
    """Recognize every tuple of ``data`` (needs clouds): arrays ``poses (S, M, 4, 4)``,
    ``params (S, M, 9)``, ``kinds (S, M)``, ``found (S, M)`` and ``seconds (S,)``."""
    import time

    from tqdm import tqdm

    from sqmanip.perception.pipeline import Recognizer

    if data.cloud is None or data.cloud_labels is None:
        raise ValueError("data has no observed clouds; load the split with with_cloud=True")
    b = data.batch
    s, m = b.mask.shape
    out = {
        "poses": np.tile(np.eye(4), (s, m, 1, 1)),
        "params": np.zeros((s, m, 9)),
        "kinds": np.zeros((s, m), dtype=np.int64),
        "found": np.zeros((s, m), dtype=bool),
        "seconds": np.zeros(s),
    }
    rec = Recognizer()
    for k in tqdm(range(s), desc="recognize", disable=not progress, unit="tuple"):
        keep = (data.cloud_labels[k] >= 0).numpy()
        n = int(b.mask[k].sum())
        t0 = time.perf_counter()
        p, q, kd, f = recognize_tuple(
            rec, data.cloud[k].numpy()[keep], data.cloud_labels[k].numpy()[keep], n, camera
        )
        out["seconds"][k] = time.perf_counter() - t0
        out["poses"][k, :n], out["params"][k, :n] = p, q
        out["kinds"][k, :n], out["found"][k, :n] = kd, f
    return out


def _cache_key(split_dir: Path) -> str:
    manifest = (split_dir / "manifest.json").read_text()
    blob = json.dumps({"manifest": manifest, "options": RECOGNIZE_OPTIONS}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def load_or_recognize(
    data: PushTensors, split_dir: str | Path, camera: Any, cache_dir: str | Path
) -> dict[str, np.ndarray]:
    """:func:`recognize_split` results, read from ``cache_dir/<split>.npz`` when its key (split
    manifest + options) matches, else computed and written there."""
    split_dir = Path(split_dir)
    path = Path(cache_dir) / f"{split_dir.name}.npz"
    key = _cache_key(split_dir)
    if path.is_file():
        with np.load(path) as z:
            if str(z["key"]) == key and z["poses"].shape[0] == len(data):
                return {k: z[k] for k in z.files if k != "key"}
        log.info("recognition cache %s is stale; recomputing", path)
    res = recognize_split(data, camera)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, key=np.array(key), **res)
    tmp.replace(path)
    return res


def upright_frames(poses: torch.Tensor, params: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Relabel each recognized superquadric's axes so its z axis is the most vertical one.

    ``poses (..., 4, 4)``, ``params (..., 9)`` (undeformed superellipsoids). The fitter returns
    box-like objects with any axis order (mostly x vertical), while SQPD-Net was trained on
    upright frames (z up), and the 4.6 shape alignment only moves z when ``e1`` and ``e2`` are
    within ``SQPDNetConfig.alignment_e_tol`` (0.3).
    The pushing objects stand upright, so the vertical axis becomes z (sign up, cyclic order,
    sizes follow their axes). When z moves, ``e1`` and ``e2`` swap: the footprint (the section
    across the new z) had exponent ``e1``; exact for ``e1 == e2``, the common box-like case.
    """
    from .model import _alignment_apply

    z_idx = poses[..., 2, :3].abs().argmax(-1)
    z_val = poses[..., 2, :3].gather(-1, z_idx.unsqueeze(-1)).squeeze(-1)
    z_sign = torch.where(z_val < 0, -1.0, 1.0).to(poses.dtype)
    ok = torch.ones_like(z_idx, dtype=torch.bool)
    new_poses, new_params, _ = _alignment_apply(
        poses, params, ok, z_idx, z_sign, (z_idx + 1) % 3, torch.ones_like(z_sign)
    )
    moved = (z_idx != 2).unsqueeze(-1)
    swapped = torch.cat([new_params[..., :3], new_params[..., 4:5], new_params[..., 3:4],
                         new_params[..., 5:]], -1)  # fmt: skip
    return new_poses, torch.where(moved, swapped, new_params)


@torch.no_grad()
def predict_recognized(
    model: SQPDNet,
    data: PushTensors,
    rec: dict[str, np.ndarray],
    batch_size: int = 256,
    *,
    upright: bool = True,
) -> torch.Tensor:
    """Predicted next ground-truth-frame poses ``(S, M, 4, 4)`` from recognized inputs.

    The model sees the recognized poses / shapes (missed objects masked out); each recognized
    object's predicted world motion ``T'_rec T_rec^{-1}`` is applied to its ground-truth pose
    (module docstring). Missed objects keep their pose. ``upright``: relabel the recognized
    axes first (:func:`upright_frames`); the motion is the same for either labelling.
    """
    b = data.batch
    dt = b.poses.dtype
    found = torch.as_tensor(rec["found"]) & b.mask
    rec_poses = torch.as_tensor(rec["poses"], dtype=dt)
    rec_params = torch.as_tensor(rec["params"], dtype=dt)
    if upright:
        rec_poses, rec_params = upright_frames(rec_poses, rec_params)
    batch = PushBatch(
        rec_poses,
        rec_params,
        torch.as_tensor(rec["kinds"], dtype=torch.long),
        found,
        b.action_p,
        b.action_v,
        b.next_poses,
    )
    model.eval()
    ref = next(model.parameters())
    parts = []
    for start in range(0, len(b.mask), batch_size):
        sub = PushBatch(*(x[start : start + batch_size] for x in (
            batch.poses, batch.params, batch.kinds, batch.mask, batch.action_p, batch.action_v,
            batch.next_poses)))  # fmt: skip
        parts.append(model.forward_batch(sub.to(ref.device, ref.dtype)).to("cpu", dt))
    rec_next = torch.cat(parts) if parts else rec_poses.clone()
    motion = rec_next @ torch.linalg.inv(rec_poses)
    pred = motion @ b.poses
    return torch.where(found[..., None, None], pred, b.poses)
