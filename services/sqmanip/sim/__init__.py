"""PyBullet Franka Panda simulator: tabletop and shelf scenes, cameras, push/grasp/pick-and-place.

Domain API (in-process; the gRPC servicer wraps it): :class:`Simulator`, the scene specs
:class:`SceneSpec` / :class:`ObjectSpec`, and the result types in :mod:`.actions`.

The names below are loaded on first access (PEP 562): importing a light sub-module
(``sqmanip.sim.actions``, ``.camera``, ``.config``; the proto converters, the CLI) must not load
PyBullet (which prints a banner) and pinocchio in every process.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "ActionResult": "actions", "ObjectState": "actions", "Observation": "actions",
    "SimState": "actions",
    "Intrinsics": "camera",
    "GRIPPER_MAX_WIDTH": "config", "LABEL_BACKGROUND": "config", "LABEL_ROBOT": "config",
    "LABEL_STATIC": "config", "WORKSPACE_CENTER": "config", "WORKSPACE_SIZE": "config",
    "ShelfGeometry": "config", "SimConfig": "config",
    "PandaKinematics": "kinematics",
    "ObjectSpec": "scene", "SceneSpec": "scene",
    "Simulator": "simulator", "workspace_bounds": "simulator",
}  # fmt: skip

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


if TYPE_CHECKING:
    from .actions import ActionResult, ObjectState, Observation, SimState
    from .camera import Intrinsics
    from .config import (
        GRIPPER_MAX_WIDTH,
        LABEL_BACKGROUND,
        LABEL_ROBOT,
        LABEL_STATIC,
        WORKSPACE_CENTER,
        WORKSPACE_SIZE,
        ShelfGeometry,
        SimConfig,
    )
    from .kinematics import PandaKinematics
    from .scene import ObjectSpec, SceneSpec
    from .simulator import Simulator, workspace_bounds
