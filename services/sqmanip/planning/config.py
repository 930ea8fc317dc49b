"""Configuration of the pushing MPC (Ch. 4.4.2, Appendices B.4, B.5): table, sampler, costs.

Defaults follow the thesis: 100 action sequences (B.4), horizon 1 for moving, singulation and
interactive moving and 3 for grasping (B.4, 4.7.3), ``n_gr = 512`` gripper points and at most 30
rule-based grasp candidates of width <= 7 cm (B.5), the 0.512 x 0.512 x 0.192 m workspace of
4.5. The table is the simulator's (``sqmanip.sim.config``: 0.80 x 0.80 x 0.05 m, top face at
``z = 0``, centred 0.10 m beyond the workspace centre at ``(0.55, 0)``); the numbers are repeated here rather
than imported so that planning does not import PyBullet through ``sqmanip.sim``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from sqmanip.errors import ValidationError
from sqmanip.grasping.config import PANDA_HAND
from sqmanip.grasping.types import GripperSpec, RuleOptions


def _finite_positive(name: str, value: float, *, allow_zero: bool = False) -> None:
    ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        raise ValidationError(
            f"{name} must be finite and {'>= 0' if allow_zero else '> 0'}, got {value!r}"
        )


@dataclasses.dataclass(frozen=True)
class TableSpec:
    """The table as an axis-aligned box: top face at ``height``, ``thickness`` below it.

    B.5 adds the table to the obstacles as one more implicit surface ("the box-shaped table can
    also be represented by superquadric equation"); an axis-aligned box has an exact and cheaper
    inside test, so it is used directly. A *finite* table matters: a flat object pushed over the
    edge becomes graspable from the side (4.6.3, "grasping large").
    """

    center: tuple[float, float] = (0.55, 0.0)
    """Table centre in the world x-y plane (m)."""
    size: tuple[float, float] = (0.80, 0.80)
    """Table extent along world x and y (m)."""
    height: float = 0.0
    """World z of the table top (m)."""
    thickness: float = 0.05

    def __post_init__(self) -> None:
        if len(self.center) != 2 or not all(math.isfinite(float(c)) for c in self.center):
            raise ValidationError(f"table.center must be 2 finite numbers, got {self.center!r}")
        if len(self.size) != 2:
            raise ValidationError(f"table.size must be 2 lengths, got {self.size!r}")
        for s in self.size:
            _finite_positive("table.size", float(s))
        if not math.isfinite(self.height):
            raise ValidationError(f"table.height must be finite, got {self.height!r}")
        _finite_positive("table.thickness", float(self.thickness))

    @property
    def lo(self) -> np.ndarray:
        """``(2,)`` lower x-y corner."""
        return np.asarray(self.center, dtype=np.float64) - 0.5 * np.asarray(self.size)

    @property
    def hi(self) -> np.ndarray:
        """``(2,)`` upper x-y corner."""
        return np.asarray(self.center, dtype=np.float64) + 0.5 * np.asarray(self.size)

    def contains_xy(self, xy: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Whether points ``(..., 2)`` lie over the table shrunk by ``margin``: ``(...)`` bool."""
        xy = np.asarray(xy, dtype=np.float64)
        return ((xy >= self.lo + margin) & (xy <= self.hi - margin)).all(-1)


@dataclasses.dataclass(frozen=True)
class SamplerSpec:
    """Arguments of the 4.5 action sampler (``sqmanip.dynamics.sampler.push_candidates``).

    Per object: 8 push directions relative to its heading, towards its centre; 5 heights dividing
    the workspace height (kept below the object's top); 4 start points on the push line; at most
    160 candidates per object. Defaults are the sampler's own (the data SQPD-Net is trained on),
    except ``min_travel``: the MPC drops pushes that would touch their object for less than
    3 cm (``sqmanip.dynamics.sampler``). Such pushes occur along a long box's diagonal, and the
    model overpredicts them.
    """

    directions: int = 8
    heights: int = 5
    start_offsets: tuple[float, ...] = (0.0, 0.01, 0.02, 0.03)
    push_length: float = 0.10
    tip_radius: float = 0.01
    clearance: float = 0.005
    workspace_height: float = 0.192
    """Height the ``heights`` levels divide, above the table top (m), 4.5."""
    min_travel: float | None = 0.03
    """Least tip travel (m) after it meets the object on the pushing line; None: keep all."""

    def __post_init__(self) -> None:
        for name in ("directions", "heights"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValidationError(f"sampler.{name} must be an integer >= 1, got {v!r}")
        _finite_positive("sampler.workspace_height", self.workspace_height)
        _finite_positive("sampler.push_length", self.push_length)
        _finite_positive("sampler.tip_radius", self.tip_radius, allow_zero=True)
        _finite_positive("sampler.clearance", self.clearance, allow_zero=True)
        if self.min_travel is not None:
            _finite_positive("sampler.min_travel", self.min_travel, allow_zero=True)
        if len(self.start_offsets) == 0:
            raise ValidationError("sampler.start_offsets must hold at least one distance")
        for o in self.start_offsets:
            _finite_positive("sampler.start_offsets", float(o), allow_zero=True)

    def candidate_kwargs(self) -> dict:
        return {
            "directions": self.directions,
            "heights": self.heights,
            "start_offsets": tuple(self.start_offsets),
            "push_length": self.push_length,
            "tip_radius": self.tip_radius,
            "clearance": self.clearance,
            "workspace_height": self.workspace_height,
            "min_travel": self.min_travel,
        }


@dataclasses.dataclass(frozen=True)
class GraspCostSpec:
    """The grasping cost of B.5.13: candidates, gripper points and what counts as a collision."""

    rule: RuleOptions = dataclasses.field(default_factory=RuleOptions)
    """Rule-based candidates (B.5): top-down + 4 side directions, 6 each, width <= 7 cm, <= 30."""
    edge_grasps: bool = True
    """Also add side grasps whose fingers close across the object's *vertical* axis (a flat object
    held by its rim). They collide with the table unless the object overhangs the table edge, which
    is how the MPC learns to push a large flat box to the edge (4.6.3, Fig. 4.16 last row)."""
    edge_turns_deg: tuple[float, ...] = (0.0, -20.0, 20.0)
    """Each edge grasp also turned by these angles about the vertical through its TCP
    (:func:`~sqmanip.planning.costs.edge_grasp_candidates`): with ``(0,)`` alone, a large box
    overhanging a side edge at a yaw of about -15 degrees on one side (+15 on the other) is not
    graspable before its centre is within 2 cm of the edge."""
    max_candidates: int = 30
    """Cap on the rule-based candidates (B.5: "maximum 30 grasp poses")."""
    max_edge_candidates: int = 72
    """Cap on the edge candidates (4 directions x 6 positions x 3 turns)."""
    gripper_points: int = 512
    """``n_gr`` points on the open gripper (B.5)."""
    table_clearance: float = 0.002
    """Gripper points closer than this above the table top count as touching it (m)."""
    check_target: bool = True
    """Reject candidates whose open gripper penetrates the target itself."""
    approach_distance: float = 0.10
    """The hand at the pre-grasp pose, this far back along the approach axis, must clear the table
    and the robot mount too: ``Simulator.grasp`` refuses a pre-grasp configuration in collision, and
    an edge grasp held low at the table's near side backs its hand into the pedestal."""
    mount: TableSpec | None = dataclasses.field(
        default_factory=lambda: TableSpec(
            center=(0.0, 0.0), size=(0.24, 0.24), height=0.10, thickness=0.10
        )
    )
    """The box the robot stands on (the simulator's pedestal under ``ROBOT_BASE``); None: no mount."""

    def __post_init__(self) -> None:
        if not math.isfinite(self.approach_distance) or self.approach_distance < 0:
            raise ValidationError(
                f"grasp.approach_distance must be finite and >= 0, got {self.approach_distance!r}"
            )
        for name in ("max_candidates", "max_edge_candidates"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValidationError(f"grasp.{name} must be an integer >= 1, got {v!r}")
        if not self.edge_turns_deg or not all(
            math.isfinite(float(a)) and abs(float(a)) < 90.0 for a in self.edge_turns_deg
        ):
            raise ValidationError(
                "grasp.edge_turns_deg must hold at least one finite angle in (-90, 90), got "
                f"{self.edge_turns_deg!r}"
            )
        if not isinstance(self.gripper_points, int) or not 16 <= self.gripper_points <= 100_000:
            raise ValidationError(
                f"grasp.gripper_points must be in [16, 100000], got {self.gripper_points!r}"
            )
        if not math.isfinite(self.table_clearance):
            raise ValidationError(
                f"grasp.table_clearance must be finite, got {self.table_clearance!r}"
            )


@dataclasses.dataclass(frozen=True)
class MPCConfig:
    """Sampling-based MPC (B.4) settings; every field is validated on construction."""

    n_sequences: int = 100
    """``K`` action sequences sampled per step (B.4)."""
    score_every_single_push: tuple[str, ...] = ("moving",)
    """Tasks whose horizon-1 steps score every admissible candidate instead of ``K`` draws:
    there are at most 160 per object and one batched dynamics call scores them all in about
    10 ms. It helps moving (its cost sums every object's distance): 37/40 -> 39/40 over
    scenario seeds 0 and 1; it hurts singulation (its cost is the closest pair only, flat over
    most pushes, so the best-predicted of all pushes is mostly the model's error): 36/40 ->
    32/40. Interactive moving: 3/10 either way. The physics baseline re-simulates every push,
    so the planner service and ``benchmarks.mpc`` give it ``()`` (K draws) (ours)."""
    horizon: int | None = None
    """Actions per sequence; None takes the task's default (1, or 3 for grasping, B.4)."""
    table: TableSpec = dataclasses.field(default_factory=TableSpec)
    workspace_margin: float = 0.0
    """Workspace constraint (4.6.3): a sequence is rejected when it is predicted to carry an
    object centre closer than this to the table edge (or past it), m."""
    sampler: SamplerSpec = dataclasses.field(default_factory=SamplerSpec)
    """The 4.5 sampler's settings; its workspace is the table top (x-y) and ``workspace_height``
    above it, so pushes may reach the table edge (where "grasping large" needs the object)."""
    gripper: GripperSpec = PANDA_HAND
    """The hand: pushes use it closed (Fig. 4.6), grasps open (B.5)."""
    reject_start_collisions: bool = True
    """Drop pushes whose closed gripper at the start pose hits the table or an object (B.5.12)."""
    pusher_points: int = 256
    """Points on the closed gripper for the start-pose check."""
    pusher_clearance: float = 0.002
    """Pusher points closer than this above the table top count as touching it (m)."""
    grasp: GraspCostSpec = dataclasses.field(default_factory=GraspCostSpec)

    def __post_init__(self) -> None:
        if not isinstance(self.n_sequences, int) or self.n_sequences < 1:
            raise ValidationError(f"n_sequences must be an integer >= 1, got {self.n_sequences!r}")
        if self.n_sequences > 100_000:
            raise ValidationError(f"n_sequences must be <= 100000, got {self.n_sequences}")
        tasks = ("moving", "singulation", "grasping", "interactive_moving")
        unknown = set(self.score_every_single_push) - set(tasks)
        if isinstance(self.score_every_single_push, str) or unknown:
            raise ValidationError(
                f"score_every_single_push must be a tuple of task names {tasks}, "
                f"got {self.score_every_single_push!r}"
            )
        if self.horizon is not None and (
            not isinstance(self.horizon, int) or not 1 <= self.horizon <= 10
        ):
            raise ValidationError(
                f"horizon must be None or an integer in [1, 10], got {self.horizon!r}"
            )
        _finite_positive("workspace_margin", float(self.workspace_margin), allow_zero=True)
        if not isinstance(self.pusher_points, int) or not 16 <= self.pusher_points <= 100_000:
            raise ValidationError(
                f"pusher_points must be in [16, 100000], got {self.pusher_points!r}"
            )
        if not math.isfinite(self.pusher_clearance):
            raise ValidationError(f"pusher_clearance must be finite, got {self.pusher_clearance!r}")
