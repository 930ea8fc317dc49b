"""Domain types of grasp planning: the gripper, a grasp, the environment and the plan options.

Frames and units follow ARCHITECTURE.md: metres, radians, world z up. A grasp pose maps the
*gripper frame* to the world: origin at the tool centre point (TCP, midway between the finger pads),
``z`` the approach direction (from the palm towards the object), ``y`` the closing axis (the fingers
move along ``+-y``), ``x = y x z``. This is the Franka hand's own convention.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
import torch

from sqmanip.errors import ValidationError
from sqmanip.geometry import Superquadric

Score = Literal["top_down", "uncertainty"]
Method = Literal["antipodal", "rule_based"]


def _positive(name: str, value: float, *, allow_zero: bool = False) -> None:
    ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise ValidationError(f"{name} must be finite and {bound}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class GripperSpec:
    """A parallel-jaw gripper as boxes in the gripper frame (defaults: the Franka Emika hand).

    Along ``z`` (approach) the fingertips end ``tip_offset`` past the TCP, the fingers reach back
    ``finger_length`` from their tips to the palm, and the palm (hand body) spans ``palm_size[2]``
    above that, ending at the flange ``flange_offset = finger_length - tip_offset + palm_size[2]``
    behind the TCP (0.1034 m on the Panda). ``wrist_radius`` / ``wrist_length`` approximate links
    7 and 6 above the flange by one cylinder along the approach axis (C.3 checks "the gripper and
    Franka's links 7 and 6"); link 6's true lateral offset depends on joint 7 and is not modelled.
    """

    max_opening: float = 0.08
    """Largest distance between the finger pads (m); the Franka hand opens to 8 cm."""
    finger_length: float = 0.054
    """Finger extent along the approach axis, tip to palm (m)."""
    finger_width: float = 0.02
    """Finger extent along the gripper ``x`` axis (m)."""
    finger_thickness: float = 0.012
    """Finger extent along the closing axis ``y``, behind each pad (m)."""
    tip_offset: float = 0.0094
    """How far the fingertips reach past the TCP along ``z`` (m)."""
    palm_size: tuple[float, float, float] = (0.063, 0.204, 0.0586)
    """Hand body extents along gripper ``x, y, z`` (m)."""
    wrist_radius: float = 0.045
    """Radius of the cylinder standing in for links 7 and 6 (m)."""
    wrist_length: float = 0.2
    """Length of that cylinder above the flange (m)."""

    def __post_init__(self) -> None:
        for name in ("max_opening", "finger_length", "finger_width", "finger_thickness"):
            _positive(name, float(getattr(self, name)))
        _positive("tip_offset", float(self.tip_offset), allow_zero=True)
        if len(self.palm_size) != 3:
            raise ValidationError(f"palm_size must be 3 lengths, got {self.palm_size!r}")
        for v in self.palm_size:
            _positive("palm_size", float(v))
        _positive("wrist_radius", float(self.wrist_radius))
        _positive("wrist_length", float(self.wrist_length), allow_zero=True)
        if self.tip_offset >= self.finger_length:
            raise ValidationError(
                f"tip_offset must be < finger_length ({self.finger_length}), got {self.tip_offset}"
            )
        if self.palm_size[1] < self.max_opening + 2 * self.finger_thickness:
            raise ValidationError(
                f"palm_size[1] must hold both open fingers (>= "
                f"{self.max_opening + 2 * self.finger_thickness:.4f} m), got {self.palm_size[1]}"
            )

    @property
    def palm_bottom(self) -> float:
        """``z`` of the palm's finger side in the gripper frame (negative: behind the TCP)."""
        return -(self.finger_length - self.tip_offset)

    @property
    def flange_offset(self) -> float:
        """Distance from the TCP back to the flange along ``-z`` (m)."""
        return -self.palm_bottom + self.palm_size[2]


@dataclasses.dataclass(frozen=True)
class Grasp:
    """One ranked grasp (ARCHITECTURE.md vocabulary)."""

    pose: np.ndarray
    """Gripper-to-world transform (4, 4); approach = ``pose[:3, 2]``, closing axis ``pose[:3, 1]``."""
    width: float
    """Distance between the two contacts (m); open wider than this before closing."""
    score: float
    """Higher is better: ``-z^T z_t`` (3.4.2), minus ``beta u`` when uncertainty-aware (3.6.3)."""
    contacts: np.ndarray | None = None
    """(2, 3) world-frame antipodal contact points, or None when not known."""
    uncertainty: float | None = None
    """Mean shape-uncertainty score ``u`` in [0, 1] of the contacts (3.6.3), when computed."""

    @property
    def approach(self) -> np.ndarray:
        """Unit approach vector (gripper ``z`` axis) in the world frame, (3,)."""
        return self.pose[:3, 2].copy()

    @property
    def position(self) -> np.ndarray:
        return self.pose[:3, 3].copy()


def _as_parts(name: str, value) -> tuple[Superquadric, ...]:
    parts = tuple(value)
    for p in parts:
        if not isinstance(p, Superquadric):
            raise ValidationError(f"{name} must hold Superquadric values, got {type(p).__name__}")
    return parts


@dataclasses.dataclass(frozen=True)
class Environment:
    """What surrounds the target besides the other recognized objects.

    The support plane is ``normal . x + offset = 0`` with ``normal`` the unit "up" vector
    ``z_t`` pointing into free space (the convention of ``perception.types.SupportPlane``).
    ``boxes`` are fixed obstacles modelled as superquadrics (e.g. the five boxes of a shelf,
    C.3, with ``e1 = e2 ~ 0.2``); ``objects`` are further obstacles, one tuple of parts each.
    """

    support_normal: tuple[float, float, float] | None = (0.0, 0.0, 1.0)
    """Unit up vector of the support plane, or None when there is no plane to avoid."""
    support_offset: float = 0.0
    boxes: tuple[Superquadric, ...] = ()
    objects: tuple[tuple[Superquadric, ...], ...] = ()
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """``z_t`` for the score when there is no support plane (defaults to world up)."""

    def __post_init__(self) -> None:
        if self.support_normal is not None:
            n = np.asarray(self.support_normal, dtype=np.float64)
            if n.shape != (3,) or not np.isfinite(n).all() or np.linalg.norm(n) < 1e-9:
                raise ValidationError(
                    f"support_normal must be a finite non-zero (3,) vector, got {self.support_normal!r}"
                )
            n = n / np.linalg.norm(n)
            object.__setattr__(self, "support_normal", tuple(float(v) for v in n))
        if not math.isfinite(float(self.support_offset)):
            raise ValidationError(f"support_offset must be finite, got {self.support_offset!r}")
        u = np.asarray(self.up, dtype=np.float64)
        if u.shape != (3,) or not np.isfinite(u).all() or np.linalg.norm(u) < 1e-9:
            raise ValidationError(f"up must be a finite non-zero (3,) vector, got {self.up!r}")
        object.__setattr__(self, "up", tuple(float(v) for v in u / np.linalg.norm(u)))
        object.__setattr__(self, "boxes", _as_parts("boxes", self.boxes))
        object.__setattr__(self, "objects", tuple(_as_parts("objects[i]", o) for o in self.objects))

    @property
    def z_t(self) -> np.ndarray:
        """The "table normal" of the score ``c = -z^T z_t`` (3.4.2), (3,)."""
        src = self.support_normal if self.support_normal is not None else self.up
        return np.asarray(src, dtype=np.float64)

    @classmethod
    def table(cls, height: float = 0.0, **kwargs) -> Environment:
        """A horizontal support plane at ``z = height``."""
        return cls(support_normal=(0.0, 0.0, 1.0), support_offset=-float(height), **kwargs)


@dataclasses.dataclass(frozen=True)
class RuleOptions:
    """The rule-based candidate generator of B.5 / C.3 (see :mod:`.rule_based`).

    B.5 (tabletop MPC): top-down and four side directions, 6 poses each (at most 30), antipodal
    width <= 7 cm. C.3 (shelf search): side grasps only, width <= 7.5 cm, pitched ``20 deg`` down
    towards the shelf floor; :meth:`shelf` returns that preset.
    """

    top_down: bool = True
    side: bool = True
    per_direction: int = 6
    max_candidates: int = 30
    max_width: float = 0.07
    """Reject pairs of contacts farther apart than this (m); the hand opens to 8 cm."""
    spread: float = 0.8
    """Grasp positions span ``+- spread`` times the half extent along their free axis."""
    grasp_depth: float = 0.03
    """How far past the object's near face (top, or side) the TCP goes (m), capped at the centre."""
    tilt: float = 0.0
    """Side grasps pitched down by this angle about their closing axis (rad; C.3 uses 20 deg)."""
    facing: tuple[float, float, float] | None = None
    """Keep only side grasps whose horizontal approach is within ``facing_angle`` of this."""
    facing_angle: float = math.pi / 4
    round_threshold: float = 0.6
    """``e2`` above which a cross-section counts as round (top-down grasps rotate about it)."""
    antipodal_threshold: float = 0.9
    """Contacts must pass the relaxed (3.4.7) ``n1 . n2 < -threshold`` (B.5: "the two gripper
    fingers should be on the antipodal points"); drops e.g. off-centre chords of round sections."""

    def __post_init__(self) -> None:
        for name in ("per_direction", "max_candidates"):
            v = getattr(self, name)
            if not isinstance(v, int | np.integer) or v < 1:
                raise ValidationError(f"{name} must be an integer >= 1, got {v!r}")
        _positive("max_width", float(self.max_width))
        _positive("spread", float(self.spread), allow_zero=True)
        _positive("grasp_depth", float(self.grasp_depth), allow_zero=True)
        if not (math.isfinite(self.tilt) and abs(self.tilt) < math.pi / 2):
            raise ValidationError(f"tilt must be in (-pi/2, pi/2), got {self.tilt!r}")
        if self.facing is not None:
            f = np.asarray(self.facing, dtype=np.float64)
            if f.shape != (3,) or not np.isfinite(f).all():
                raise ValidationError(f"facing must be a finite (3,) vector, got {self.facing!r}")
        if not (0.0 <= self.antipodal_threshold <= 1.0):
            raise ValidationError(
                f"antipodal_threshold must be in [0, 1], got {self.antipodal_threshold!r}"
            )
        if not (0.0 < self.facing_angle <= math.pi):
            raise ValidationError(f"facing_angle must be in (0, pi], got {self.facing_angle!r}")

    @classmethod
    def shelf(cls, facing: tuple[float, float, float] | None = None) -> RuleOptions:
        """C.3: side grasps only, width <= 7.5 cm, tilted 20 deg."""
        return cls(top_down=False, max_width=0.075, tilt=math.radians(20.0), facing=facing)


@dataclasses.dataclass(frozen=True)
class Candidates:
    """Grasp candidates before feasibility checks (world frame, ``K`` of them)."""

    poses: torch.Tensor
    """(K, 4, 4) gripper-to-world."""
    widths: torch.Tensor
    """(K,) contact distance (m)."""
    contacts: torch.Tensor
    """(K, 2, 3) contact points."""

    def __len__(self) -> int:
        return self.poses.shape[0]

    @classmethod
    def empty(cls, dtype: torch.dtype = torch.float64) -> Candidates:
        return cls(
            torch.zeros(0, 4, 4, dtype=dtype),
            torch.zeros(0, dtype=dtype),
            torch.zeros(0, 2, 3, dtype=dtype),
        )


@dataclasses.dataclass(frozen=True)
class PlanOptions:
    """Options of :meth:`GraspPlanner.plan` (defaults from 3.4, 3.6.3, B.5)."""

    n_samples: int = 256
    """Surface samples ``x1`` over the target's parts (Algorithm 1, ``n_s``)."""
    n_approach: int = 12
    """Approach directions per antipodal pair, evenly spaced about the closing axis (30 deg)."""
    antipodal_threshold: float = 0.9
    """Relaxed (3.4.7): accept ``n(x1) . n(x*) < -threshold |n(x1)| |n(x*)|``."""
    beta: float = 5.0
    """Weight of the uncertainty score ``u`` in ``c = -z^T z_t - beta u`` (3.6.3)."""
    max_results: int | None = 20
    """Keep at most this many feasible grasps (None: all)."""
    seed: int = 0
    score: Score = "top_down"
    """``"uncertainty"`` needs ``observed_points``; ``"top_down"`` ignores them."""
    method: Method = "antipodal"
    """Candidate generator: Algorithm 1 (``"antipodal"``) or the rule-based one of B.5 / C.3."""
    gripper_points: int = 512
    """Points sampled on the open gripper for collision checks (``n_gr``, B.5)."""
    include_wrist: bool = False
    """Also check links 7 and 6 (the wrist cylinder) for collisions (C.3)."""
    approach_distance: float = 0.0
    """Sweep the gripper this far back along ``-z`` (pre-grasp approach path, 0.3 m in C.3)."""
    support_clearance: float = 0.002
    """Gripper points closer than this to the support plane count as touching it (m)."""
    min_width: float = 0.002
    """Pairs closer than this (m) are degenerate (a sliver, not a grasp) and dropped."""
    open_margin: float = 0.02
    """The hand is opened to ``min(width + open_margin, max_opening)`` to execute a grasp
    (:meth:`opening`), and the collision check holds the fingers exactly that wide."""
    opening_clearance: float = 0.0
    """Pairs wider than ``max_opening - opening_clearance`` are dropped (m). Off by default: in
    the closed-loop benchmark recognized widths err on the wide side (a 6 cm box side fitted
    7.8 cm wide) and a clearance drops exactly those grasps, which the simulator executes fine."""
    collision_margin: float = 0.003
    """Every gripper box is inflated by this much for the collision checks (m): recognition
    error of a few mm must not turn a planned clearance into contact."""
    check_target: bool = True
    """Also reject grasps whose open gripper penetrates the target itself (palm, finger backs)."""
    chunk_size: int = 256
    """Candidates checked per batch; checking stops once ``max_results`` feasible ones are found."""
    rule: RuleOptions = dataclasses.field(default_factory=RuleOptions)
    """Options of the rule-based generator (``method="rule_based"``)."""

    def __post_init__(self) -> None:
        for name in ("n_samples", "n_approach", "gripper_points", "chunk_size"):
            v = getattr(self, name)
            if not isinstance(v, int | np.integer) or v < 1:
                raise ValidationError(f"{name} must be an integer >= 1, got {v!r}")
        if self.n_samples > 20000:
            raise ValidationError(f"n_samples must be <= 20000, got {self.n_samples}")
        if self.n_approach > 360:
            raise ValidationError(f"n_approach must be <= 360, got {self.n_approach}")
        if not (0.0 <= self.antipodal_threshold <= 1.0):
            raise ValidationError(
                f"antipodal_threshold must be in [0, 1], got {self.antipodal_threshold!r}"
            )
        _positive("beta", float(self.beta), allow_zero=True)
        if self.max_results is not None and (
            not isinstance(self.max_results, int | np.integer) or self.max_results < 1
        ):
            raise ValidationError(f"max_results must be None or >= 1, got {self.max_results!r}")
        if self.score not in ("top_down", "uncertainty"):
            raise ValidationError(f"score must be 'top_down' or 'uncertainty', got {self.score!r}")
        if self.method not in ("antipodal", "rule_based"):
            raise ValidationError(
                f"method must be 'antipodal' or 'rule_based', got {self.method!r}"
            )
        _positive("approach_distance", float(self.approach_distance), allow_zero=True)
        if not math.isfinite(self.support_clearance):
            raise ValidationError(
                f"support_clearance must be finite, got {self.support_clearance!r}"
            )
        _positive("min_width", float(self.min_width), allow_zero=True)
        for name in ("open_margin", "opening_clearance", "collision_margin"):
            _positive(name, float(getattr(self, name)), allow_zero=True)

    def opening(self, width: float | torch.Tensor, max_opening: float) -> float | torch.Tensor:
        """Finger opening (m) to execute a grasp of contact distance ``width``."""
        if torch.is_tensor(width):
            return torch.clamp(width + self.open_margin, max=max_opening)
        return float(min(float(width) + self.open_margin, max_opening))


def parts_tuple(name: str, parts: Sequence[Superquadric]) -> tuple[Superquadric, ...]:
    """Validate a list of parts (used by the planner for ``target`` and ``obstacles[i]``)."""
    if isinstance(parts, Superquadric):
        raise ValidationError(f"{name} must be a list of Superquadric parts, got one Superquadric")
    return _as_parts(name, parts)
