"""From a simulator observation to the planner's objects ``[(parts, task id)]`` (Ch. 4.6.3).

Two sources of object shapes, the rows of Table 4.6:

- :class:`PerceptionObjects` ("R-SQPD-Net", "PyBullet w/ Recog."): render the wrist camera at
  the home pose (0.72 m above the workspace, looking down), crop the cloud to the space above
  the table (and up to 15 cm past its far and side edges, where a pushed object overhangs), and run
  the training-free recognizer (:class:`~sqmanip.perception.pipeline.Recognizer`: RANSAC table,
  clustering, superquadric fitting with amodal completion). Object identities are *not* taken from
  the simulator's segmentation; they come from :class:`ObjectTracker`;
- :class:`GroundTruthObjects` ("PyBullet w/ GT"): the simulator's own superquadrics (boxes and
  cylinders as ``e = 0.2`` / ``(0.2, 1.0)`` shapes) with their true ids.

:class:`ObjectTracker` associates recognized objects with task ids across steps by nearest centre:
each step, recognized centres are matched one-to-one to the tracked objects' *expected* centres
(Hungarian assignment on planar distance, pairs farther apart than ``gate`` are not matched). The
expected centres start at the scenario's initial object positions (a task names "the object
standing at ...") and after each push become the planner's *predicted* positions of the tracked
objects (so a pushed object is looked for where the model said it would go, not where it was).
When exactly one tracked object is unmatched and exactly one recognized object is left over, they
are paired by elimination up to three gates apart (a push carried the object farther than the
model said). Tracked objects that are not recognized keep their last expectation; recognized
objects left unmatched get fresh ids from 1000 up and are tracked from then on. Recognized and true centres
differ by the recognition error (an upright box seen from above is fitted around its visible
part), which the 10 cm default gate absorbs.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence

import numpy as np

from sqmanip.geometry import Superquadric
from sqmanip.perception.types import RecognizeOptions, RecognizeRequest, Workspace
from sqmanip.sim.camera import Intrinsics

from .config import TableSpec

__all__ = [
    "GroundTruthObjects",
    "ObjectTracker",
    "PerceptionObjects",
    "Recognition",
    "object_centre",
]

OVERVIEW = Intrinsics(fx=380.0, fy=380.0)
"""The planner's observation: 640 x 576 with a wider lens than the default (fx 504), so that
from the home pose (0.72 m up) it sees 0.61 m either side of the workspace centre in y, past the
table's side edges (0.40 m), where a box pushed over the edge overhangs."""

FIRST_NEW_ID = 1000
"""Ids given to recognized objects that match no tracked object."""
ELIMINATION_GATES = 3.0
"""A single unseen tracked object takes the single unmatched recognized object up to this many
gates away (a push moved it farther than the model predicted)."""


def object_centre(parts: Sequence[Superquadric]) -> np.ndarray:
    """``(3,)`` mean of the parts' origins (the object's state is its first part's pose)."""
    return np.mean([np.asarray(p.pose)[:3, 3] for p in parts], axis=0)


@dataclasses.dataclass(frozen=True)
class Recognition:
    """Objects seen in one observation, before association (ids are the source's own)."""

    objects: list[tuple[list[Superquadric], int]]
    n_points: int
    timings_ms: dict[str, float]
    source: str


class GroundTruthObjects:
    """The simulator's true shapes and ids ("w/ GT"); objects below the table top are dropped."""

    name = "gt"
    uses_tracker = False

    def __init__(self, min_z: float = -0.02) -> None:
        self.min_z = float(min_z)

    def __call__(self, sim) -> Recognition:
        t0 = time.perf_counter()
        objs = []
        for o in sim.get_state().objects:
            if o.superquadric is None or o.position[2] < self.min_z:
                continue
            objs.append(([o.superquadric], int(o.id)))
        return Recognition(objs, 0, {"observe": 0.0, "recognize": _ms(t0)}, self.name)


class PerceptionObjects:
    """Observe with the simulator's camera and recognize with the perception pipeline.

    ``recognizer`` has ``recognize(RecognizeRequest) -> Scene`` (default: a new in-process
    ``Recognizer``). ``options`` default to plain (non-deformable) superquadrics: the objects of
    4.6.3 are boxes and cylinders, and skipping taper/bend halves the fit time on this CPU.
    """

    name = "recognition"
    uses_tracker = True

    def __init__(
        self,
        recognizer=None,
        *,
        table: TableSpec,
        camera: str = "wrist",
        intrinsics: Intrinsics = OVERVIEW,
        options: RecognizeOptions | None = None,
        crop_height: float = 0.25,
        crop_overhang: float = 0.15,
    ) -> None:
        if recognizer is None:
            from sqmanip.perception.pipeline import Recognizer

            recognizer = Recognizer()
        self.recognizer = recognizer
        self.camera = camera
        self.intrinsics = intrinsics
        # the simulator's objects are uniformly coloured: colour separates touching ones
        self.options = options or RecognizeOptions(deformable=False, segmentation="color")
        # past the table's edges too (not the robot's side: its pedestal stands there): a box
        # pushed over the edge keeps its overhanging part, the part an edge grasp holds
        lo = table.lo - np.array([0.0, crop_overhang])
        hi = table.hi + crop_overhang
        self.workspace = Workspace(
            (float(lo[0]), float(lo[1]), table.height - 0.02),
            (float(hi[0]), float(hi[1]), table.height + crop_height),
        )

    def __call__(self, sim) -> Recognition:
        t0 = time.perf_counter()
        obs = sim.observe(self.camera, intrinsics=self.intrinsics)
        t_obs = _ms(t0)
        t0 = time.perf_counter()
        req = RecognizeRequest(
            points=np.asarray(obs.points, dtype=np.float32),
            colors=obs.point_colors(),
            viewpoint=np.asarray(obs.camera_pose[:3, 3], dtype=np.float64),
            workspace=self.workspace,
            options=self.options,
        )
        scene = self.recognizer.recognize(req)
        objs = [(list(o.parts), int(o.id)) for o in scene.objects if len(o.parts) > 0]
        return Recognition(
            objs, int(obs.points.shape[0]), {"observe": t_obs, "recognize": _ms(t0)}, self.name
        )


def _ms(t0: float) -> float:
    return 1e3 * (time.perf_counter() - t0)


class ObjectTracker:
    """Nearest-centre association of recognized objects to task ids (module docstring)."""

    def __init__(self, initial: dict[int, np.ndarray], gate: float = 0.10) -> None:
        if not (np.isfinite(gate) and gate > 0):
            raise ValueError(f"gate must be finite and > 0, got {gate!r}")
        self.expected: dict[int, np.ndarray] = {
            int(k): np.asarray(v, dtype=np.float64).reshape(3) for k, v in initial.items()
        }
        self.gate = float(gate)
        self._next_id = max([FIRST_NEW_ID, *[k + 1 for k in self.expected]])

    def associate(
        self, objects: Sequence[tuple[Sequence[Superquadric], int]]
    ) -> tuple[list[tuple[list[Superquadric], int]], list[int]]:
        """Relabel ``objects`` with task ids; returns them and the tracked ids not seen."""
        from scipy.optimize import linear_sum_assignment

        ids = list(self.expected)
        centres = np.array([object_centre(p) for p, _ in objects]).reshape(-1, 3)
        out: list[tuple[list[Superquadric], int]] = []
        assigned: dict[int, int] = {}
        if ids and len(objects):
            exp = np.stack([self.expected[k] for k in ids])
            d = np.linalg.norm(centres[:, None, :2] - exp[None, :, :2], axis=-1)
            rows, cols = linear_sum_assignment(d)
            for r, c in zip(rows, cols, strict=True):
                if d[r, c] <= self.gate:
                    assigned[int(r)] = ids[int(c)]
            # by elimination: one tracked object unseen and one recognized object unmatched are
            # the same object, moved farther than predicted (up to ELIMINATION_GATES gates)
            lost = [c for c in range(len(ids)) if ids[c] not in assigned.values()]
            new = [r for r in range(len(objects)) if r not in assigned]
            if len(lost) == 1 and len(new) == 1:
                r, c = new[0], lost[0]
                if d[r, c] <= ELIMINATION_GATES * self.gate:
                    assigned[r] = ids[c]
        for r, (parts, _) in enumerate(objects):
            oid = assigned.get(r)
            if oid is None:
                oid = self._next_id
                self._next_id += 1
            self.expected[oid] = centres[r]
            out.append((list(parts), oid))
        seen = {oid for _, oid in out}
        return out, [k for k in ids if k not in seen]

    def expect(self, positions: dict[int, np.ndarray]) -> None:
        """Set the expected centres (the planner's predicted next positions) of tracked ids."""
        for k, v in positions.items():
            if int(k) in self.expected:
                self.expected[int(k)] = np.asarray(v, dtype=np.float64).reshape(3)
