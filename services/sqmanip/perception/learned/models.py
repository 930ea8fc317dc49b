"""DSQNet, SQNet, DSQNet+ and the DGCNN segmentation network (Ch. 3.3.1, 3.5.2, 3.6.2, A.2).

- :class:`PCANormalizer`: the point-cloud pre-processing of 3.3.1 (centre of mass, principal axes
  ``[v2, v1, v3]``, farthest pair of points at distance 1) with its exact inverse
  (:class:`NormalizedFrame`), so predictions made in the normalised frame map back to the world.
- :class:`DGCNNEncoder`: EdgeConv layers [72] on a dynamic k-NN graph, then a point-wise layer to
  a ``global_dim`` feature max-pooled over the points (permutation-invariant).
- :class:`SuperquadricNet`: encoder + one MLP head per output of Table 3.1. ``dsqnet`` has seven
  heads (pose, size, shape, taper, bend ``b'`` and direction); ``sqnet`` the four of a plain
  superquadric (B.2); ``dsqnet_plus`` takes 4-d points whose last channel marks the segment (3.6.2).
- :class:`SegNet`: DGCNN part segmentation, per-point logits over ``max_labels`` labels.

:func:`build_model` is the factory; unknown names raise an error that lists the valid ones.
"""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F
from torch import nn

from sqmanip.geometry.transforms import pose_from_pq, quat_normalize

from .config import MODEL_NAMES, ModelConfig, RecognitionNetConfig, SegNetConfig, model_config

__all__ = [
    "DGCNNEncoder",
    "NormalizedFrame",
    "PCANormalizer",
    "SQPrediction",
    "SegNet",
    "SuperquadricNet",
    "build_model",
    "count_parameters",
]


# --- pre-processing (3.3.1) ------------------------------------------------------------------------


@dataclasses.dataclass
class NormalizedFrame:
    """Similarity ``x_n = V^T (x - c) / s`` of 3.3.1 for a batch of clouds.

    ``center (B, 3)``, ``rotation (B, 3, 3)`` (columns ``[v2, v1, v3]``, right-handed) and
    ``scale (B,)`` (the largest distance between two input points). World coordinates are
    ``x = s V x_n + c``.
    """

    center: torch.Tensor
    rotation: torch.Tensor
    scale: torch.Tensor

    def apply(self, points: torch.Tensor) -> torch.Tensor:
        """World ``(B, N, 3)`` -> normalised ``(B, N, 3)``."""
        return (points - self.center[:, None]) @ self.rotation / self.scale[:, None, None]

    def invert(self, points: torch.Tensor) -> torch.Tensor:
        """Normalised ``(B, N, 3)`` -> world ``(B, N, 3)``."""
        return (
            points * self.scale[:, None, None] @ self.rotation.transpose(1, 2)
            + self.center[:, None]
        )

    def apply_vectors(self, v: torch.Tensor) -> torch.Tensor:
        """Rotate world directions ``(B, 3)`` into the normalised frame (no scaling)."""
        return (v.unsqueeze(1) @ self.rotation).squeeze(1)

    def pose_to_world(self, pose: torch.Tensor) -> torch.Tensor:
        """Object-to-normalised poses ``(B, 4, 4)`` -> object-to-world poses ``(B, 4, 4)``."""
        out = pose.clone()
        out[:, :3, :3] = self.rotation @ pose[:, :3, :3]
        out[:, :3, 3] = (self.rotation @ pose[:, :3, 3:4]).squeeze(-1) * self.scale[
            :, None
        ] + self.center
        return out

    def pose_to_normalized(self, pose: torch.Tensor) -> torch.Tensor:
        """Object-to-world poses ``(B, 4, 4)`` -> object-to-normalised poses ``(B, 4, 4)``."""
        out = pose.clone()
        Vt = self.rotation.transpose(1, 2)
        out[:, :3, :3] = Vt @ pose[:, :3, :3]
        out[:, :3, 3] = (Vt @ (pose[:, :3, 3] - self.center).unsqueeze(-1)).squeeze(
            -1
        ) / self.scale[:, None]
        return out

    def params_to_world(self, params: torch.Tensor) -> torch.Tensor:
        """Packed ``(B, 9)`` params in normalised units -> metres: lengths ``* s``, ``b / s``."""
        s = self.scale[:, None]
        out = params.clone()
        out[:, :3] = params[:, :3] * s
        out[:, 6] = params[:, 6] / self.scale
        out[:, 8] = params[:, 8] * self.scale
        return out

    def params_to_normalized(self, params: torch.Tensor) -> torch.Tensor:
        """Packed ``(B, 9)`` params in metres -> normalised units (inverse of params_to_world)."""
        s = self.scale[:, None]
        out = params.clone()
        out[:, :3] = params[:, :3] / s
        out[:, 6] = params[:, 6] * self.scale
        out[:, 8] = params[:, 8] / self.scale
        return out


class PCANormalizer(nn.Module):
    """Point-cloud standardisation of 3.3.1, batched: ``(B, N, 3)`` -> ``(B, N, 3)`` + frame.

    Convention:
    - eigenvalues ``l1 < l2 < l3`` of the covariance, axes ``V = [v2, v1, v3]``;
    - eigenvector signs are fixed so the third moment of the points along ``v2`` and ``v3`` is
      >= 0 (the thesis leaves them to the eigen-solver); ``v1`` is then ``v3 x v2`` (det V = +1);
    - with ``mask (B, N)`` the frame comes from the masked points only (DSQNet+ segments) and is
      applied to all points; ``scale`` is clamped to ``>= eps``.
    """

    def __init__(self, eps: float = 1e-6) -> None:
        super().__init__()
        self.eps = eps

    @torch.no_grad()
    def frame(self, points: torch.Tensor, mask: torch.Tensor | None = None) -> NormalizedFrame:
        if points.ndim != 3 or points.shape[-1] != 3:
            raise ValueError(f"points must have shape (B, N, 3), got {tuple(points.shape)}")
        x = points.double()
        if mask is None:
            w = torch.ones(x.shape[:2], dtype=x.dtype, device=x.device)
        else:
            if mask.shape != points.shape[:2]:
                raise ValueError(
                    f"mask must have shape {tuple(points.shape[:2])}, got {tuple(mask.shape)}"
                )
            w = mask.to(x.dtype)
        cnt = w.sum(1).clamp_min(1.0)
        c = (x * w[..., None]).sum(1) / cnt[:, None]
        d = (x - c[:, None]) * w[..., None]
        cov = d.transpose(1, 2) @ d / cnt[:, None, None]
        _, vec = torch.linalg.eigh(cov)  # ascending: v1, v2, v3
        v2, v3 = vec[..., 1], vec[..., 2]

        def orient(v):
            m3 = ((d @ v.unsqueeze(-1)).squeeze(-1) ** 3 * w).sum(1)
            return torch.where(m3 < 0, -1.0, 1.0).to(x.dtype)[:, None] * v

        v2, v3 = orient(v2), orient(v3)
        v1 = torch.linalg.cross(v3, v2)
        V = torch.stack([v2, v1, v3], -1)
        pts = torch.where(w[..., None] > 0, x, c[:, None])  # unmasked points do not count
        diam = torch.cdist(pts, pts).flatten(1).amax(1).clamp_min(self.eps)
        dt = points.dtype
        return NormalizedFrame(c.to(dt), V.to(dt), diam.to(dt))

    def forward(
        self, points: torch.Tensor, mask: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, NormalizedFrame]:
        """Normalised points ``(B, N, 3)`` and the frame that undoes them."""
        fr = self.frame(points, mask)
        return fr.apply(points), fr


# --- DGCNN ---------------------------------------------------------------------------------------


def knn(x: torch.Tensor, k: int) -> torch.Tensor:
    """Indices ``(B, N, k)`` of the ``k`` nearest neighbours (self included) of ``x (B, C, N)``."""
    sq = (x * x).sum(1)  # (B, N)
    neg_d2 = 2 * x.transpose(1, 2) @ x - sq[:, :, None] - sq[:, None, :]  # (B, N, N)
    return neg_d2.topk(k=k, dim=-1).indices


def graph_features(x: torch.Tensor, k: int) -> torch.Tensor:
    """EdgeConv inputs ``(x_j - x_i, x_i)`` over the k-NN graph: ``(B, C, N) -> (B, 2C, N, k)``."""
    b, c, n = x.shape
    idx = knn(x, k)  # (B, N, k)
    xt = x.transpose(1, 2).reshape(b * n, c)
    base = torch.arange(b, device=x.device).view(b, 1, 1) * n
    nb = xt[(idx + base).reshape(-1)].view(b, n, k, c)  # (B, N, k, C)
    xt = xt.view(b, n, c)
    centre = xt.unsqueeze(2).expand(b, n, k, c)
    return torch.cat([nb - centre, centre], -1).permute(0, 3, 1, 2).contiguous()


class _NeighbourStats(torch.autograd.Function):
    """Per row of ``p (M, C)``: max, min, sum and sum of squares over the rows ``idx (M, k)``.

    The ``(M, k, C)`` neighbour tensor is never built: each of the ``k`` neighbour columns is
    gathered, folded into the four running results and dropped (forward), and gathered again to
    scatter its share of the gradient (backward; a tie for the max or min passes the gradient to
    every tied neighbour, which only exact duplicates can cause).
    """

    @staticmethod
    def forward(ctx, p: torch.Tensor, idx: torch.Tensor):
        v = p[idx[:, 0]]
        mx, mn, s1, s2 = v.clone(), v.clone(), v.clone(), v * v
        for j in range(1, idx.shape[1]):
            v = p[idx[:, j]]
            torch.maximum(mx, v, out=mx)
            torch.minimum(mn, v, out=mn)
            s1 += v
            s2.addcmul_(v, v)
        ctx.save_for_backward(p, idx, mx, mn)
        return mx, mn, s1, s2

    @staticmethod
    def backward(ctx, g_mx, g_mn, g_s1, g_s2):
        p, idx, mx, mn = ctx.saved_tensors
        g = torch.zeros_like(p)
        g2 = 2 * g_s2
        for j in range(idx.shape[1]):
            rows = idx[:, j]
            v = p[rows]
            c = g_s1 + g2 * v
            c += g_mx * (v == mx)
            c += g_mn * (v == mn)
            g.index_add_(0, rows, c)
        return g, None


class EdgeConv(nn.Module):
    """``max_j h([x_j - x_i, x_i])`` over the dynamic k-NN graph of the layer's input [72],
    ``h`` = 1x1 convolution (no bias), batch norm, leaky ReLU."""

    def __init__(self, c_in: int, c_out: int, k: int, slope: float) -> None:
        super().__init__()
        self.k = k
        self.mlp = nn.Sequential(
            nn.Conv2d(2 * c_in, c_out, 1, bias=False), nn.BatchNorm2d(c_out), nn.LeakyReLU(slope)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, C_in, N) -> (B, C_out, N)``, the same numbers as ``mlp(graph_features(x))``
        max-pooled over the neighbours, computed without the ``(B, N, k, C)`` edge tensor:

        - the convolution is linear and bias-free, so the edge feature is
          ``e_ij = W [x_j - x_i, x_i] = p_j + q_i`` with ``p = W_a x``, ``q = (W_b - W_a) x``
          computed per point;
        - batch norm is a per-channel affine map and leaky ReLU is increasing, so the max over
          ``j`` of ``lrelu(bn(e_ij))`` is ``lrelu(bn(q_i + max_j p_j))`` where the channel's
          scale ``gamma / sigma`` is >= 0 and the same with ``min_j p_j`` where it is < 0;
        - the batch statistics over all edges follow from ``sum_j p_j`` and ``sum_j p_j^2``.

        About 2x faster per training step on a CPU than building the edge tensor (a unit test
        checks values, gradients and running statistics against that form)."""
        b, c, n = x.shape
        k = min(self.k, n)
        conv, bn, act = self.mlp
        w = conv.weight.view(conv.out_channels, 2 * c)
        w_nb, w_c = w[:, :c], w[:, c:]
        xt = x.transpose(1, 2)  # (B, N, C_in)
        p = (xt @ w_nb.T).reshape(b * n, -1)
        q = (xt @ (w_c - w_nb).T).reshape(b * n, -1)
        base = torch.arange(b, device=x.device).view(b, 1, 1) * n
        idx = (knn(x, k) + base).reshape(b * n, k)
        mx, mn, s1, s2 = _NeighbourStats.apply(p, idx)
        if bn.training or not bn.track_running_stats:
            cnt = b * n * k
            s1d, qd = s1.double(), q.double()
            mean = (s1d.sum(0) + k * qd.sum(0)) / cnt
            ex2 = (s2.double().sum(0) + 2 * (qd * s1d).sum(0) + k * (qd * qd).sum(0)) / cnt
            var = (ex2 - mean * mean).clamp_min(0)
            if bn.training and bn.track_running_stats:
                with torch.no_grad():
                    m = bn.momentum
                    bn.running_mean.mul_(1 - m).add_(m * mean.to(p.dtype))
                    bn.running_var.mul_(1 - m).add_(m * var.to(p.dtype) * cnt / max(cnt - 1, 1))
                    bn.num_batches_tracked += 1
            mean, var = mean.to(p.dtype), var.to(p.dtype)
        else:
            mean, var = bn.running_mean, bn.running_var
        scale = bn.weight / torch.sqrt(var + bn.eps)
        edge = torch.where(scale >= 0, mx, mn) + q
        y = F.leaky_relu((edge - mean) * scale + bn.bias, act.negative_slope)
        return y.view(b, n, -1).transpose(1, 2)


class DGCNNEncoder(nn.Module):
    """EdgeConv stack + point-wise layer to ``global_dim`` + max pooling (3.3.1, Fig. 3.3)."""

    def __init__(
        self, in_dim: int, k: int, widths: tuple[int, ...], global_dim: int, slope: float
    ) -> None:
        super().__init__()
        layers, c = [], in_dim
        for w in widths:
            layers.append(EdgeConv(c, w, k, slope))
            c = w
        self.edges = nn.ModuleList(layers)
        self.local_dim = sum(widths)
        self.point = nn.Sequential(
            nn.Conv1d(self.local_dim, global_dim, 1, bias=False),
            nn.BatchNorm1d(global_dim),
            nn.LeakyReLU(slope),
        )

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``x (B, N, C)`` -> global feature ``(B, global_dim)``, local features ``(B, L, N)``."""
        h = x.transpose(1, 2)
        feats = []
        for layer in self.edges:
            h = layer(h)
            feats.append(h)
        local = torch.cat(feats, 1)  # (B, L, N)
        return self.point(local).amax(-1), local


def _mlp(c_in: int, widths: tuple[int, ...], c_out: int, slope: float) -> nn.Sequential:
    layers: list[nn.Module] = []
    for w in widths:
        layers += [nn.Linear(c_in, w), nn.LeakyReLU(slope)]
        c_in = w
    layers.append(nn.Linear(c_in, c_out))
    return nn.Sequential(*layers)


# --- superquadric networks -------------------------------------------------------------------------


@dataclasses.dataclass
class SQPrediction:
    """Network output for ``B`` clouds, in the normalised frame of :class:`PCANormalizer`.

    All fields are ``(B, ...)`` tensors and satisfy the bounds of Table 3.1.
    """

    position: torch.Tensor
    """``p (B, 3)``, object origin."""
    quaternion: torch.Tensor
    """``q (B, 4)``, unit, (x, y, z, w)."""
    size: torch.Tensor
    """``a (B, 3)`` in ``size_bounds``."""
    shape: torch.Tensor
    """``e (B, 2)`` in ``shape_bounds``."""
    taper: torch.Tensor
    """``k (B,)`` in ``taper_bounds`` (0 for SQNet)."""
    bend: torch.Tensor
    """``b = b' / max(a1, a2) (B,)``, ``b'`` in ``bend_bounds`` (0 for SQNet)."""
    bend_direction: torch.Tensor
    """``(cos alpha, sin alpha) (B, 2)``, unit."""

    def params(self) -> torch.Tensor:
        """Packed ``(B, 9)`` params (``a1 a2 a3 e1 e2 k b alpha a4``) for the geometry core."""
        alpha = torch.atan2(self.bend_direction[:, 1], self.bend_direction[:, 0])
        zero = torch.zeros_like(self.taper)
        cols = [self.size, self.shape, self.taper[:, None], self.bend[:, None], alpha[:, None]]
        return torch.cat(cols + [zero[:, None]], -1)

    def pose(self) -> torch.Tensor:
        """Object-to-normalised-frame poses ``(B, 4, 4)``."""
        return pose_from_pq(self.position, self.quaternion)


def _bounded(x: torch.Tensor, bounds: tuple[float, float]) -> torch.Tensor:
    lo, hi = bounds
    return lo + (hi - lo) * torch.sigmoid(x)


class SuperquadricNet(nn.Module):
    """DSQNet (3.3.1), SQNet (3.5.2) or DSQNet+ (3.6.2), by ``config.name``.

    ``forward(x (B, N, in_dim))`` takes *normalised* points (:class:`PCANormalizer`; DSQNet+ adds
    the 0/1 segment channel) and returns an :class:`SQPrediction` in that frame.
    """

    HEADS_DEFORMABLE = {
        "position": 3,
        "quaternion": 4,
        "size": 3,
        "shape": 2,
        "taper": 1,
        "bend": 1,
        "bend_direction": 2,
    }
    HEADS_PLAIN = ("position", "quaternion", "size", "shape")

    def __init__(self, config: RecognitionNetConfig) -> None:
        super().__init__()
        self.config = config
        c = config
        self.encoder = DGCNNEncoder(c.in_dim, c.k, c.edge_widths, c.global_dim, c.leaky_slope)
        names = (
            list(self.HEADS_DEFORMABLE) if c.deformable else list(self.HEADS_PLAIN)
        )  # seven or four heads
        self.heads = nn.ModuleDict(
            {
                n: _mlp(c.global_dim, c.head_widths, self.HEADS_DEFORMABLE[n], c.leaky_slope)
                for n in names
            }
        )

    def forward(self, x: torch.Tensor) -> SQPrediction:
        c = self.config
        if x.ndim != 3 or x.shape[-1] != c.in_dim:
            raise ValueError(f"x must have shape (B, N, {c.in_dim}), got {tuple(x.shape)}")
        if x.shape[1] <= 1:
            raise ValueError(f"x must hold at least 2 points per cloud, got {x.shape[1]}")
        g, _ = self.encoder(x)
        out = {n: h(g) for n, h in self.heads.items()}
        size = _bounded(out["size"], c.size_bounds)
        quat = quat_normalize(out["quaternion"])
        if c.deformable:
            taper = _bounded(out["taper"], c.taper_bounds).squeeze(-1)
            b_prime = _bounded(out["bend"], c.bend_bounds).squeeze(-1)
            bend = b_prime / size[:, :2].amax(-1)
            d = out["bend_direction"]
            d = F.normalize(d + torch.tensor([1e-6, 0.0], dtype=d.dtype, device=d.device), dim=-1)
        else:
            taper = torch.zeros_like(size[:, 0])
            bend = torch.zeros_like(size[:, 0])
            d = torch.zeros_like(size[:, :2])
            d[:, 0] = 1.0
        return SQPrediction(
            position=out["position"],
            quaternion=quat,
            size=size,
            shape=_bounded(out["shape"], c.shape_bounds),
            taper=taper,
            bend=bend,
            bend_direction=d,
        )


class SegNet(nn.Module):
    """DGCNN part segmentation [72] (A.2): ``x (B, N, 3)`` normalised -> logits ``(B, N, K)``."""

    def __init__(self, config: SegNetConfig) -> None:
        super().__init__()
        self.config = config
        c = config
        self.encoder = DGCNNEncoder(c.in_dim, c.k, c.edge_widths, c.global_dim, c.leaky_slope)
        layers: list[nn.Module] = []
        c_in = c.global_dim + self.encoder.local_dim
        for w in c.head_widths:
            layers += [nn.Conv1d(c_in, w, 1, bias=False), nn.BatchNorm1d(w), nn.LeakyReLU(0.2)]
            if c.dropout > 0:
                layers.append(nn.Dropout(c.dropout))
            c_in = w
        layers.append(nn.Conv1d(c_in, c.max_labels, 1))
        self.head = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        c = self.config
        if x.ndim != 3 or x.shape[-1] != c.in_dim:
            raise ValueError(f"x must have shape (B, N, {c.in_dim}), got {tuple(x.shape)}")
        g, local = self.encoder(x)  # (B, G), (B, L, N)
        h = torch.cat([g.unsqueeze(-1).expand(-1, -1, local.shape[-1]), local], 1)
        return self.head(h).transpose(1, 2)  # (B, N, K)


def build_model(name: str, config: ModelConfig | None = None, **overrides) -> nn.Module:
    """Network ``name`` (``dsqnet`` | ``sqnet`` | ``dsqnet_plus`` | ``segnet``).

    ``config`` (or the full-size defaults plus ``overrides``) sets the widths. Unknown names raise
    ``ValueError`` listing the available models.
    """
    if name not in MODEL_NAMES:
        raise ValueError(f"Unknown model name {name!r}. Available models: {list(MODEL_NAMES)}")
    if config is None:
        config = model_config(name, **overrides)
    elif overrides:
        config = dataclasses.replace(config, **overrides)
    if config.name != name:
        raise ValueError(f"config is for {config.name!r}, but model {name!r} was requested")
    if isinstance(config, SegNetConfig):
        return SegNet(config)
    return SuperquadricNet(config)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
