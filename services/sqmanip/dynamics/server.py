"""gRPC Dynamics server: objects + K pushes -> next poses under every push, in one call.

``python -m sqmanip.dynamics.server [--host H] [--port P]``. ``Predict`` decodes the objects
(one superquadric each, at its current pose) and the packed ``K x 6`` actions, and answers
``K x N x 4 x 4`` next poses from the model the request names:

- ``"sqpdnet"`` (default): the SQPD-Net checkpoint in ``SQMANIP_DYNAMICS_MODEL_DIR`` (default
  ``models/sqpdnet`` under the working directory or the repository), a training output directory
  with ``config.json`` and ``model.pt`` (``sqmanip.dynamics.train``). All K actions go through
  :meth:`SQPDNet.predict` in one batched pass (MPC scores its 100 candidates with one call).
  Without a checkpoint the call fails with FAILED_PRECONDITION saying where it looked and how to
  train one. The weights are loaded with ``torch.load(..., weights_only=True)`` and reloaded
  when ``model.pt`` changes on disk.
- ``"physics"``: the PyBullet re-simulation baseline of 4.7.4
  (:class:`sqmanip.dynamics.physics.PhysicsDynamics`, all pushes of a call in one PyBullet
  world): 100 pushes of 4 objects take 8-20 s on this 2-core machine (10 pushes 1-3 s), so at
  most ``SQMANIP_DYNAMICS_PHYSICS_MAX_ACTIONS`` (100, the MPC's K) per call. Its PyBullet
  clients live on one dedicated thread (they must never be shared across threads). Pushes the
  robot cannot execute keep the poses and are flagged in ``failed``.
- any other name: a checkpoint directory of that name next to the SQPD-Net one (e.g.
  ``models/sqpdnet_baseline`` for the 4.7.1 baseline); unknown names are NOT_FOUND.

Torch threads (``SQMANIP_DYNAMICS_TORCH_THREADS``, default 1). Measured with
``python -m sqmanip.dynamics.server --bench-threads`` (p50 of a 100-action x 4-object SQPD-Net
prediction, CPU preset, on this 2-core machine while other jobs kept it busy, load average ~12):
1 thread 14.3 ms alone and 31.4 ms with a second process predicting on the other core; 2 threads
222.7 ms alone and 159.0 ms contended. With more runnable threads than cores, torch's intra-op
workers wait on each other (spin, then sleep) at every one of the many small matrix products,
so two threads are an order of magnitude *slower* than one. In the stack every service shares
the same cores, so one thread per service process is the default; throughput scales with
processes (the services are stateless), not with threads. Re-measure on a dedicated machine
before raising it.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import dataclasses
import logging
import re
import sys
import threading
import time
from pathlib import Path
from typing import Any

import grpc
import numpy as np
import torch
from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from sqmanip.errors import (
    NotFoundError,
    PreconditionError,
    ResourceExhaustedError,
    ValidationError,
)
from sqmanip.rpc import convert
from sqmanip.rpc.server import configure_logging, run_service, service_parser
from sqmanip.settings import StackSettings, get_settings
from sqmanip.v1 import dynamics_pb2, dynamics_pb2_grpc

from .config import SQPDNetConfig
from .model import SQPDNet, make_model

log = logging.getLogger("sqmanip.dynamics.server")

REPO = Path(__file__).resolve().parents[3]
DEFAULT_MODEL_SUBDIR = Path("models") / "sqpdnet"
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$")


def default_model_dir() -> Path:
    """``models/sqpdnet`` under the working directory if it exists, else under the repository."""
    local = Path.cwd() / DEFAULT_MODEL_SUBDIR
    return local if local.is_dir() else REPO / DEFAULT_MODEL_SUBDIR


class DynamicsServiceSettings(BaseSettings):
    """Settings of the dynamics service (env prefix ``SQMANIP_DYNAMICS_``)."""

    model_config = SettingsConfigDict(env_prefix="SQMANIP_DYNAMICS_", extra="ignore")

    model_dir: Path | None = None
    """SQPD-Net checkpoint directory (config.json + model.pt); None = :func:`default_model_dir`."""
    torch_threads: int = Field(1, ge=1)
    """``torch.set_num_threads`` of the service process (1: see the module docstring)."""
    max_actions: int = Field(100_000, ge=1)
    """Most actions per learned-model call (memory grows linearly with K N)."""
    physics_max_actions: int = Field(100, ge=1)
    """Most actions per ``physics`` call (100 pushes of 4 objects: 8-20 s, within the 30 s
    request deadline)."""
    max_queue: int = Field(16, ge=0)
    """Requests that may wait per model thread; more are answered RESOURCE_EXHAUSTED."""

    def resolved_model_dir(self) -> Path:
        return Path(self.model_dir) if self.model_dir is not None else default_model_dir()


def checkpoint_files(directory: Path) -> tuple[Path, Path]:
    return directory / "config.json", directory / "model.pt"


def load_checkpoint(directory: str | Path) -> SQPDNet:
    """An SQPD-Net (or baseline) from a training output directory, on the CPU, in eval mode.

    ``torch.load(weights_only=True)``: a checkpoint is data, never code. Raises
    :class:`PreconditionError` when a file is missing or does not fit the config.
    """
    directory = Path(directory)
    cfg_path, weights = checkpoint_files(directory)
    if not cfg_path.is_file() or not weights.is_file():
        raise PreconditionError(
            f"model: no SQPD-Net checkpoint at {directory} (expected config.json and model.pt); "
            f"train one with `sqmanip train sqpdnet --out {directory}` "
            f"(python -m sqmanip.dynamics.train sqpdnet --synthetic 2000 --out {directory}) "
            "or set SQMANIP_DYNAMICS_MODEL_DIR"
        )
    try:
        config = dataclasses.replace(SQPDNetConfig.load(cfg_path), device="cpu")
        model = make_model(config)
        state = torch.load(weights, map_location="cpu", weights_only=True)
        model.load_state_dict(state)
    except Exception as exc:  # noqa: BLE001 - any unreadable checkpoint is the same precondition
        raise PreconditionError(
            f"model: cannot load the checkpoint at {directory}: {exc}"
        ) from None
    return model.eval()


class ModelRegistry:
    """Checkpoints by name, loaded on first use and reloaded when ``model.pt`` changes."""

    def __init__(self, model_dir: Path) -> None:
        self.model_dir = Path(model_dir)
        self._cache: dict[str, tuple[float, SQPDNet]] = {}
        self._lock = threading.Lock()

    def directory(self, name: str) -> Path:
        if name == "sqpdnet":
            return self.model_dir
        if not _NAME.match(name):
            raise ValidationError(
                f"model: expected 'sqpdnet', 'physics' or a checkpoint name of letters, digits, "
                f"'_', '-', '.', got {name!r}"
            )
        path = self.model_dir.parent / name
        if not checkpoint_files(path)[1].is_file():
            raise NotFoundError(
                f"model: no checkpoint named {name!r} in {self.model_dir.parent}; available: "
                f"{self.available()}"
            )
        return path

    def available(self) -> list[str]:
        names = ["physics"]
        if checkpoint_files(self.model_dir)[1].is_file():
            names.insert(0, "sqpdnet")
        root = self.model_dir.parent
        if root.is_dir():
            for d in sorted(root.iterdir()):
                if d != self.model_dir and _NAME.match(d.name) and (d / "model.pt").is_file():
                    names.append(d.name)
        return names

    def get(self, name: str) -> SQPDNet:
        path = self.directory(name)
        weights = checkpoint_files(path)[1]
        mtime = weights.stat().st_mtime if weights.is_file() else -1.0
        with self._lock:
            hit = self._cache.get(name)
            if hit is not None and hit[0] == mtime:
                return hit[1]
            model = load_checkpoint(path)
            self._cache[name] = (mtime, model)
            log.info("loaded %s from %s", name, path)
            return model


class _Lane:
    """One worker thread with a bounded number of waiting calls."""

    def __init__(self, name: str, max_queue: int) -> None:
        self.pool = concurrent.futures.ThreadPoolExecutor(1, name)
        self.name = name
        self.max_pending = 1 + max_queue
        self.pending = 0

    async def run(self, fn, *args: Any):
        if self.pending >= self.max_pending:
            raise ResourceExhaustedError(
                f"dynamics busy: {self.pending} {self.name} requests in progress"
            )
        self.pending += 1
        try:
            return await asyncio.get_running_loop().run_in_executor(self.pool, fn, *args)
        finally:
            self.pending -= 1


class DynamicsServicer(dynamics_pb2_grpc.DynamicsServicer):
    """``Predict``: proto -> (poses, params, actions, kinds), the model on its thread -> proto.

    ``physics_factory`` builds the physics baseline (default
    :class:`~sqmanip.dynamics.physics.PhysicsDynamics`); it is called on the physics thread,
    where its PyBullet client lives from then on.
    """

    def __init__(
        self,
        settings: DynamicsServiceSettings | None = None,
        *,
        physics_factory=None,
    ) -> None:
        self.settings = settings or DynamicsServiceSettings()
        self.registry = ModelRegistry(self.settings.resolved_model_dir())
        self._physics_factory = physics_factory
        self._physics = None
        self._learned = _Lane("sqpdnet", self.settings.max_queue)
        self._physics_lane = _Lane("physics", self.settings.max_queue)

    def _predict_learned(self, name: str, args: convert.PredictArgs) -> np.ndarray:
        model = self.registry.get(name)
        if args.scene_poses is not None:
            return model.predict_batch(
                args.scene_poses, args.params, args.actions, args.kinds
            ).numpy()
        out = model.predict(args.poses, args.params, args.actions, args.kinds)
        return out.numpy()

    def _predict_physics(self, args: convert.PredictArgs) -> tuple[np.ndarray, np.ndarray]:
        if self._physics is None:
            factory = self._physics_factory
            if factory is None:
                from .physics import PhysicsDynamics

                factory = PhysicsDynamics
            self._physics = factory()
        if args.scene_poses is not None:
            out = self._physics.predict_batch(
                args.scene_poses, args.params, args.actions, args.kinds
            )
        else:
            out = self._physics.predict(args.poses, args.params, args.actions, args.kinds)
        failed = np.asarray(getattr(self._physics, "last_failed", np.zeros(len(args.actions))))
        return np.asarray(out), failed

    async def Predict(self, request, context: grpc.aio.ServicerContext):  # noqa: N802
        args = convert.predict_request_from_proto(request)
        k = args.actions.shape[0]
        t0 = time.perf_counter()
        failed = None
        if args.model == "physics":
            limit = self.settings.physics_max_actions
            if k > limit:
                raise ValidationError(
                    f"actions: the physics model takes at most {limit} actions per call "
                    f"(about 1 s each), got {k}"
                )
            poses, failed = await self._physics_lane.run(self._predict_physics, args)
        else:
            if k > self.settings.max_actions:
                raise ValidationError(
                    f"actions: at most {self.settings.max_actions} actions per call, got {k}"
                )
            self.registry.directory(args.model)  # name errors before queueing
            poses = await self._learned.run(self._predict_learned, args.model, args)
        latency = 1e3 * (time.perf_counter() - t0)
        return convert.predict_response_to_proto(
            poses, model=args.model, failed=failed, latency_ms=latency
        )

    def close(self) -> None:
        if self._physics is not None and hasattr(self._physics, "close"):
            try:
                self._physics_lane.pool.submit(self._physics.close).result(10)
            except Exception:  # noqa: BLE001 - shutting down anyway
                log.exception("closing the physics simulator failed")
        for lane in (self._learned, self._physics_lane):
            lane.pool.shutdown(wait=False, cancel_futures=True)


def registrar(servicer: DynamicsServicer):
    """``Register`` callback for :func:`sqmanip.rpc.server.start_server`."""

    def register(server: grpc.aio.Server) -> list[str]:
        dynamics_pb2_grpc.add_DynamicsServicer_to_server(servicer, server)
        return [dynamics_pb2.DESCRIPTOR.services_by_name["Dynamics"].full_name]

    return register


def bench_threads(repeats: int = 200) -> dict[str, float]:
    """p50 latency (ms) of a 100-action x 4-object prediction (CPU preset, random weights) at
    1 and 2 torch threads, alone and with a second process doing the same on the other core."""
    import multiprocessing as mp

    from .config import cpu_config

    def run(threads: int, n: int) -> float:
        torch.set_num_threads(threads)
        torch.manual_seed(0)
        model = make_model(cpu_config()).eval()
        rng = np.random.default_rng(0)
        poses = np.tile(np.eye(4), (4, 1, 1))
        poses[:, :2, 3] = rng.uniform(-0.2, 0.2, (4, 2))
        params = np.tile([0.03, 0.03, 0.03, 0.2, 0.2, 0, 0, 0, 0], (4, 1))
        actions = rng.normal(size=(100, 6)).astype(np.float32)
        for _ in range(10):
            model.predict(poses, params, actions)
        times = []
        for _ in range(n):
            t = time.perf_counter()
            model.predict(poses, params, actions)
            times.append(time.perf_counter() - t)
        return 1e3 * float(np.median(times))

    out: dict[str, float] = {}
    for threads in (1, 2):
        out[f"alone_{threads}"] = run(threads, repeats)
        ctx = mp.get_context("fork")
        busy = ctx.Process(target=run, args=(threads, 10 * repeats), daemon=True)
        busy.start()
        time.sleep(1.0)
        out[f"contended_{threads}"] = run(threads, repeats)
        busy.terminate()
        busy.join()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("dynamics", "sqmanip.dynamics.server", __doc__)
    parser.add_argument("--bench-threads", action="store_true",
                        help="measure 1 vs 2 torch threads alone and contended, then exit")  # fmt: skip
    args = parser.parse_args(argv)
    if args.bench_threads:
        for key, ms in bench_threads().items():
            print(f"{key:<14} p50 {ms:7.2f} ms")
        return 0
    configure_logging(args.log_level)
    settings: StackSettings = get_settings()
    service = DynamicsServiceSettings()
    torch.set_num_threads(service.torch_threads)
    servicer = DynamicsServicer(service)
    model_dir = servicer.registry.model_dir
    if checkpoint_files(model_dir)[1].is_file():
        try:
            servicer.registry.get("sqpdnet")  # load now: report a broken checkpoint at start-up
        except PreconditionError as exc:
            log.error("%s", exc)
    else:
        log.warning("no SQPD-Net checkpoint at %s: model 'sqpdnet' answers FAILED_PRECONDITION",
                    model_dir)  # fmt: skip
    log.info("dynamics: model_dir=%s torch_threads=%d", model_dir, service.torch_threads)
    return run_service(
        servicer, registrar(servicer), settings, name="dynamics", host=args.host, port=args.port
    )


if __name__ == "__main__":
    sys.exit(main())
