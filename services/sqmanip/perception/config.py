"""Settings of the perception service (pydantic-settings, env prefix ``SQMANIP_PERCEPTION_``).

Every tuning knob of preprocessing (3.5.3, B.2), segmentation and fitting lives here with a
default that works for a tabletop seen from about 1 m; e.g. ``SQMANIP_PERCEPTION_MAX_POINTS=500000``.
Lengths are metres.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict


class PerceptionSettings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="SQMANIP_PERCEPTION_", extra="ignore")

    # --- validation ---------------------------------------------------------------------------
    max_points: int = Field(2_000_000, ge=500_000)
    """Largest accepted cloud (points); larger requests are rejected with a ValidationError."""

    # --- preprocessing (3.5.3, B.2) ---------------------------------------------------------------
    points_per_segment: int = Field(300, ge=16, le=4096)
    """Default number of points each segment is re-sampled to (3.5.3: 300)."""
    voxel_size: float = Field(0.004, gt=0)
    """Voxel edge for down-sampling before clustering and per segment (m)."""
    ransac_iterations: int = Field(128, ge=1)
    """Plane hypotheses drawn by RANSAC (B.2)."""
    ransac_threshold: float = Field(0.005, gt=0)
    """Inlier distance to the support plane (m): 5 sigma of the 1 mm noise of A.1."""
    ransac_eval_points: int = Field(3000, ge=100)
    """Hypotheses are scored on a random subset of this many points, then refit on all."""
    plane_min_fraction: float = Field(0.05, ge=0, le=1)
    """A plane is reported only if at least this fraction of the (cropped) points support it."""
    upsample_neighbors: int = Field(8, ge=3)
    """Neighbours used to estimate the tangent plane for up-sampling (3.5.3)."""

    # --- segmentation ---------------------------------------------------------------------------
    cluster_voxel: float = Field(0.006, gt=0)
    """Voxel edge of the down-sampled copy that clustering runs on (m)."""
    cluster_radius: float = Field(0.012, gt=0)
    """Euclidean clustering radius (m): voxel representatives closer than this are connected."""
    min_cluster_points: int = Field(40, ge=1)
    """Clusters with fewer original points are dropped as clutter."""
    fragment_points: int = Field(200, ge=0)
    """With colours, a segment with fewer points than this joins the nearest larger segment of its
    colour (within 5 cm) instead of becoming an object: a strip of a box seen through a gap
    between its neighbours (0: never)."""
    split_touching: bool = True
    """Cut concave edges (local convexity of normals) to split objects that touch."""
    concavity_tolerance: float = Field(0.12, ge=0)
    """An edge is concave if ``(n_i - n_j) . (x_i - x_j) / |x_i - x_j| < -tolerance``."""
    color_tolerance: float = Field(0.06, gt=0)
    """``segmentation='color'``: neighbours whose chromaticity ``(r, g, b) / (r + g + b)``
    differs by more than this are cut apart like a concave edge, and segments of different
    colours are never parts of one object (touching objects of different colours). A mode of
    its own because a real object's printed label would split it; for uniformly coloured
    objects, such as the simulator's. Chromaticity ignores shading: within one simulated object it varies by
    ~0.002, between the clutter objects of the MPC benchmark by 0.02-0.75."""
    normal_neighbors: int = Field(10, ge=3)
    part_contact: float = Field(0.01, ge=0)
    """A segment whose lowest point is farther than this above the support plane (m) does not
    stand on it: it becomes a part of the object it rests on (a bottle's neck, a mug's handle)."""

    # --- fitting --------------------------------------------------------------------------------
    fit_iterations: int = Field(40, ge=1)
    """Adam steps of the first stage, over every initial orientation (on a point subset)."""
    select_points: int = Field(64, ge=8)
    """Observed points per problem in the first stage."""
    select_free_points: int = Field(64, ge=0)
    """Free-space samples per problem in the first stage."""
    refine_iterations: int = Field(20, ge=0)
    """Adam steps of the second stage, for the best initialisations only, on all points."""
    refine_points: int = Field(4096, ge=8)
    """Observed points per problem in the second stage (all of them when at least
    ``points_per_segment``)."""
    refine_free_points: int = Field(4096, ge=0)
    """Free-space samples per problem in the second stage."""
    pca_inits: bool = False
    """Also start from the 3-D principal axes for segments resting on the plane (always used
    for segments not in contact or without a plane)."""
    refine_keep: int = Field(1, ge=1)
    """Initialisations per segment carried into the second stage."""
    initial_shape: tuple[float, float] = (0.6, 0.6)
    """Starting ``(e1, e2)`` of every initialisation."""
    learning_rate: float = Field(0.08, gt=0)
    refine_learning_rate: float = Field(0.04, gt=0)
    lr_decay: float = Field(0.5, ge=0, le=1)
    """The second stage's learning rate follows a cosine from its start down to
    ``(1 - lr_decay)`` of it (the first stage, which only ranks initialisations, keeps its
    rate)."""
    huber_delta: float = Field(0.003, gt=0)
    """Robust (pseudo-Huber) scale of the radial distance (m)."""
    free_space_weight: float = Field(1.0, ge=0)
    free_space_offsets: tuple[float, ...] = (0.006, 0.015, 0.03, 0.06)
    """Distances (m) before each observed point, along its camera ray, that must be empty."""
    free_space_rays: int = Field(32, ge=0)
    """Object rays (and as many table rays) sampled per segment for the free-space term."""
    support_weight: float = Field(1.0, ge=0)
    support_contact: float = Field(0.03, gt=0)
    """A segment whose lowest point is within this height of the plane rests on it (m)."""
    taper_weight: float = Field(1e-5, ge=0)
    """Regulariser ``w k^2`` keeping tapering near 0 unless the data need it."""
    size_bounds: tuple[float, float] = (0.004, 0.6)
    """Half-extent bounds (m) of fitted parts (Table 3.1 uses [0.03, 0.53] for its data)."""
    # --- learned recognition (method = network | hybrid, segmentation = network) -------------
    network_model_dir: Path | None = None
    """DSQNet / SQNet / DSQNet+ checkpoint directory (``config.toml`` + ``model.pt``); None:
    ``models/dsqnet_cpu`` under the working directory, else under the repository."""
    segmentation_model_dir: Path | None = None
    """DGCNN segmentation checkpoint directory; None: ``models/segnet_cpu`` (not shipped)."""
    hybrid_iterations: int = Field(60, ge=0)
    """Adam steps refining the network's prediction (``method='hybrid'``)."""
    hybrid_learning_rate: float = Field(0.05, gt=0)
    hybrid_hidden_weight: float = Field(0.5, ge=0)
    """Hidden-side pseudo-points of the network's surface per observed point (the pull toward
    the network where the view says nothing)."""
    hybrid_seen_radius: float = Field(0.01, gt=0)
    """Network surface points farther than this from every observed point are hidden (m)."""
    torch_threads: int | None = 1
    """Torch threads of the networks and the hybrid refinement (restored afterwards; None:
    leave torch's setting): their tensors are small, so intra-op threads only add
    synchronisation, which on a loaded 2-core machine costs more than the arithmetic."""
    blas_threads: int | None = 1
    """BLAS threads while recognizing (None: leave numpy's setting). 1 stops OpenBLAS from
    spinning idle threads on a second core after each call (see ``perception.threads``)."""
