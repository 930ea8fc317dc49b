"""Physics baseline of Ch. 4.7.4: re-simulate the (recognized) superquadrics in PyBullet.

"Pybullet (w/ Recog.)" / "(w/ GT)" of Table 4.6: instead of a learned model, the objects are
spawned in the simulator as superquadric meshes (:mod:`sqmanip.sim.scene`: one convex hull per
convex superellipsoid, slabs of hulls otherwise) at their poses, the simulated Panda executes the
push exactly as in data generation, and the resting poses are read back.

:class:`PhysicsDynamics.predict` has the signature of :meth:`SQPDNet.predict` and returns
``(K, N, 4, 4)``. It is batched over actions only by looping: every action resets the scene
and runs a full push, so the cost is about 1 s of wall time per action on one core (PyBullet
steps at 240 Hz through the ~9 s of simulated robot motion of a push, plus IK), i.e. ~100 s
for MPC's 100 candidates versus ~5 ms for SQPD-Net. Pushes the robot cannot execute (IK or
collision refusal) leave the poses unchanged and are flagged in :attr:`last_failed`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from sqmanip.geometry.superquadric import N_PARAMS
from sqmanip.geometry.transforms import matrix_to_quat

__all__ = ["PhysicsDynamics"]

_SQ_KINDS = ("superellipsoid", "superparaboloid", "supertoroid")


class PhysicsDynamics:
    """A dynamics model that re-simulates each push in PyBullet (4.7.4).

    ``simulator``: a ``sqmanip.sim.Simulator`` to use (one is created, and owned, if None).
    ``mass`` / ``friction`` are given to every spawned object (the data generator's defaults).
    """

    def __init__(self, simulator=None, *, mass: float = 0.2, friction: float = 0.6) -> None:
        if simulator is None:
            from sqmanip.sim import Simulator

            simulator = Simulator()
            self._owned = True
        else:
            self._owned = False
        self.sim = simulator
        self.mass = float(mass)
        self.friction = float(friction)
        self.last_failed = np.zeros(0, dtype=bool)
        """``(K,)``: the actions of the last :meth:`predict` that the robot could not execute."""

    def close(self) -> None:
        if self._owned:
            self.sim.close()

    def __enter__(self) -> PhysicsDynamics:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def scene_spec(self, poses: np.ndarray, params: np.ndarray, kinds: np.ndarray):
        """The tabletop ``SceneSpec`` with one superquadric object per row."""
        from sqmanip.sim import ObjectSpec, SceneSpec

        q = matrix_to_quat(torch.as_tensor(poses[:, :3, :3])).numpy()
        objects = tuple(
            ObjectSpec(
                "superquadric",
                position=tuple(poses[i, :3, 3]),
                orientation=tuple(q[i]),
                params=tuple(params[i]),
                sq_kind=_SQ_KINDS[int(kinds[i])],
                mass=self.mass,
                friction=self.friction,
                upright=False,
                name=f"object_{i}",
            )
            for i in range(poses.shape[0])
        )
        return SceneSpec("tabletop", objects, 0)

    def predict(
        self,
        poses: torch.Tensor | np.ndarray,
        params: torch.Tensor | np.ndarray,
        actions: torch.Tensor | np.ndarray,
        kinds: torch.Tensor | np.ndarray | Sequence[int] | None = None,
    ) -> torch.Tensor:
        """Next poses ``(K, N, 4, 4)`` (float64) of ``N`` objects under each of ``K`` pushes.

        ``poses (N, 4, 4)``, ``params (N, 9)``, ``actions (K, 6)`` rows ``(p, v)`` in the world
        frame, ``kinds (N,)`` (default superellipsoids). One simulator reset and push per action.
        """
        from sqmanip.errors import PreconditionError, ValidationError

        poses_np = np.asarray(torch.as_tensor(poses, dtype=torch.float64).cpu())
        params_np = np.asarray(torch.as_tensor(params, dtype=torch.float64).cpu())
        acts = np.asarray(torch.as_tensor(actions, dtype=torch.float64).cpu())
        if poses_np.ndim != 3 or poses_np.shape[1:] != (4, 4):
            raise ValueError(f"poses must have shape (N, 4, 4), got {poses_np.shape}")
        n = poses_np.shape[0]
        if params_np.shape != (n, N_PARAMS):
            raise ValueError(f"params must have shape ({n}, {N_PARAMS}), got {params_np.shape}")
        if acts.ndim != 2 or acts.shape[1] != 6:
            raise ValueError(f"actions must have shape (K, 6), got {acts.shape}")
        kinds_np = np.zeros(n, dtype=np.int64) if kinds is None else np.asarray(kinds, np.int64)
        if kinds_np.shape != (n,):
            raise ValueError(f"kinds must have shape ({n},), got {kinds_np.shape}")
        if np.any((kinds_np < 0) | (kinds_np > 2)):
            raise ValueError(f"kinds must be 0, 1 or 2, got {kinds_np.tolist()}")
        k = acts.shape[0]
        out = np.broadcast_to(poses_np, (k, n, 4, 4)).copy()
        self.last_failed = np.zeros(k, dtype=bool)
        if n == 0:
            return torch.as_tensor(out)
        spec = self.scene_spec(poses_np, params_np, kinds_np)
        for j in range(k):
            self.sim.reset(spec)
            try:
                result = self.sim.push(acts[j, :3], acts[j, 3:])
            except (PreconditionError, ValidationError):
                self.last_failed[j] = True
                continue
            out[j] = np.stack([o.pose for o in result.after.objects])
        return torch.as_tensor(out)
