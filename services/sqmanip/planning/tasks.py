"""Pushing tasks of Ch. 4.4.2 and 4.7.3: what the MPC's terminal cost ``q(s_{T+1})`` measures.

Each task is a frozen dataclass that checks its own numbers on construction and, through
:func:`validate_task`, its object ids and goals against a scene (unknown id, goal off the table:
:class:`~sqmanip.errors.ValidationError` naming the field). Object ids are the recognizer's
``RecognizedObject.id`` values (ints).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from typing import ClassVar

import numpy as np

from sqmanip.errors import ValidationError

from .config import TableSpec

__all__ = [
    "GraspingTask",
    "InteractiveMovingTask",
    "MovingTask",
    "SingulationTask",
    "Task",
    "validate_task",
]


def _pose(name: str, value) -> np.ndarray:
    T = np.asarray(value, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValidationError(f"{name} must be a (4, 4) pose, got shape {T.shape}")
    if not np.isfinite(T).all():
        raise ValidationError(f"{name} must be finite")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
        raise ValidationError(f"{name} must have a rotation block (orthonormal, det +1)")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValidationError(f"{name} must have last row (0, 0, 0, 1), got {T[3].tolist()}")
    return T


def _position(name: str, value) -> np.ndarray:
    t = np.asarray(value, dtype=np.float64)
    if t.shape != (3,):
        raise ValidationError(f"{name} must be a (3,) position, got shape {t.shape}")
    if not np.isfinite(t).all():
        raise ValidationError(f"{name} must be finite")
    return t


def _object_id(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ValidationError(f"{name} must be an integer object id, got {value!r}")
    return int(value)


@dataclasses.dataclass(frozen=True)
class MovingTask:
    """Move objects to goal poses: ``q = sum_i ||t_i - t_d,i||^2 + beta d_SO(3)(I, R_d,i^-1 R_i)``
    (4.4.6), summed over the objects that have a goal. 4.6.3 uses ``beta = 0``."""

    goals: Mapping[int, np.ndarray]
    """Object id -> goal pose ``T_d,i`` (4, 4), world frame."""
    beta: float = 0.0
    name: ClassVar[str] = "moving"
    default_horizon: ClassVar[int] = 1

    def __post_init__(self) -> None:
        if not isinstance(self.goals, Mapping) or len(self.goals) == 0:
            raise ValidationError("task.goals must map at least one object id to a goal pose")
        goals = {
            _object_id("task.goals key", k): _pose(f"task.goals[{k}]", v)
            for k, v in self.goals.items()
        }
        object.__setattr__(self, "goals", goals)
        if not (math.isfinite(self.beta) and self.beta >= 0):
            raise ValidationError(f"task.beta must be finite and >= 0, got {self.beta!r}")

    @classmethod
    def to_positions(
        cls, positions: Mapping[int, Iterable[float]], beta: float = 0.0
    ) -> MovingTask:
        """Goals given as positions (identity orientation; use ``beta = 0`` to ignore it)."""
        goals = {}
        for k, p in positions.items():
            T = np.eye(4)
            T[:3, 3] = _position(f"task.goals[{k}]", list(p))
            goals[k] = T
        return cls(goals, beta)


@dataclasses.dataclass(frozen=True)
class SingulationTask:
    """Separate every pair of objects by more than ``tau``:
    ``q = -min_{i>j} min(||t_i - t_j|| - tau, 0)`` (4.4.7); ``tau = 0.20`` m in 4.6.3."""

    tau: float = 0.20
    name: ClassVar[str] = "singulation"
    default_horizon: ClassVar[int] = 1

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tau) and self.tau > 0):
            raise ValidationError(f"task.tau must be finite and > 0, got {self.tau!r}")


@dataclasses.dataclass(frozen=True)
class GraspingTask:
    """Make ``target_id`` graspable: ``q = 0`` if a collision-free, kinematically feasible
    rule-based grasp exists in the predicted state, else 1 (B.5.13). Horizon 3 (B.4)."""

    target_id: int
    name: ClassVar[str] = "grasping"
    default_horizon: ClassVar[int] = 3

    def __post_init__(self) -> None:
        object.__setattr__(self, "target_id", _object_id("task.target_id", self.target_id))


@dataclasses.dataclass(frozen=True)
class InteractiveMovingTask:
    """Move ``target_id`` to ``goal`` by pushing *other* objects: ``q = ||t - t_d||^2`` (4.7.9).

    The target itself may not be pushed: the MPC drops every push aimed at it (4.7.3)."""

    target_id: int
    goal: np.ndarray
    """Goal position ``t_d`` (3,), world frame (4.7.3 uses ``(0.3, 0.0, t_0,z)``)."""
    name: ClassVar[str] = "interactive_moving"
    default_horizon: ClassVar[int] = 1

    def __post_init__(self) -> None:
        object.__setattr__(self, "target_id", _object_id("task.target_id", self.target_id))
        object.__setattr__(self, "goal", _position("task.goal", self.goal))


Task = MovingTask | SingulationTask | GraspingTask | InteractiveMovingTask


def validate_task(task: Task, object_ids: Iterable[int], table: TableSpec) -> None:
    """Check ``task`` against a scene: ids must exist, goals must lie over the table.

    Raises :class:`~sqmanip.errors.ValidationError` naming the field (``task.goals[<id>]``,
    ``task.target_id``, ``task.goal``); interactive moving needs another object to push.
    """
    ids = [int(i) for i in object_ids]
    known = set(ids)
    if isinstance(task, MovingTask):
        for k, T in task.goals.items():
            if k not in known:
                raise ValidationError(
                    f"task.goals: unknown object id {k} (scene has {sorted(known)})"
                )
            if not table.contains_xy(T[:2, 3]):
                raise ValidationError(
                    f"task.goals[{k}]: goal position ({T[0, 3]:.3f}, {T[1, 3]:.3f}) is off the "
                    f"table (x in [{table.lo[0]:.3f}, {table.hi[0]:.3f}], "
                    f"y in [{table.lo[1]:.3f}, {table.hi[1]:.3f}])"
                )
    elif isinstance(task, GraspingTask | InteractiveMovingTask):
        if task.target_id not in known:
            raise ValidationError(
                f"task.target_id: unknown object id {task.target_id} (scene has {sorted(known)})"
            )
        if isinstance(task, InteractiveMovingTask):
            g = task.goal
            if not table.contains_xy(g[:2]):
                raise ValidationError(
                    f"task.goal: position ({g[0]:.3f}, {g[1]:.3f}) is off the table "
                    f"(x in [{table.lo[0]:.3f}, {table.hi[0]:.3f}], "
                    f"y in [{table.lo[1]:.3f}, {table.hi[1]:.3f}])"
                )
            if len(known) < 2:
                raise ValidationError(
                    "task.target_id: interactive moving needs at least one other object to push"
                )
    elif isinstance(task, SingulationTask):
        pass
    else:
        raise ValidationError(f"task must be one of {Task}, got {type(task).__name__}")
