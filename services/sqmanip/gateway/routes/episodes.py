"""Episodes in the background: ``POST /mpc/episodes``, ``POST /search/episodes`` return an id;
``GET /mpc/episodes/{id}`` and ``GET /search/episodes/{id}`` follow progress and the result.

The gateway opens the service's ``RunEpisode`` stream, waits for its start (the service checks
that the simulator and the other services it needs are SERVING, so a missing dependency is a 503
here, not a silent failure later), then keeps consuming the stream in a background task. Events
live in memory only: at most :data:`MAX_EVENTS` per episode (oldest dropped) and
:data:`MAX_EPISODES` episodes (the oldest finished ones are forgotten first; when all are still
running a new one is 429). An unknown id is 404.
"""

from __future__ import annotations

import asyncio
import collections
import dataclasses
import logging
import time
import uuid
from collections.abc import Callable
from typing import Any

import grpc
from fastapi import APIRouter, Request

from sqmanip.rpc import convert

from ..deps import PlannerDep, SearchDep, SettingsDep
from ..errors import STATUS_BY_CODE, HTTPError
from ..schemas import (
    EpisodeErrorOut,
    EpisodeOut,
    EpisodeStartedOut,
    MPCEpisodeBody,
    SearchEpisodeBody,
)

log = logging.getLogger("sqmanip.gateway.episodes")

router = APIRouter()

MAX_EVENTS = 200
MAX_EPISODES = 32
START_TIMEOUT_S = 10.0
"""How long ``POST`` waits for the service to accept the episode (dependency health checks)."""
EPISODE_TIMEOUT_S = 3600.0


@dataclasses.dataclass
class Episode:
    id: str
    kind: str
    events: collections.deque = dataclasses.field(
        default_factory=lambda: collections.deque(maxlen=MAX_EVENTS)
    )
    n_events: int = 0
    status: str = "running"
    result: dict[str, Any] | None = None
    error: EpisodeErrorOut | None = None
    started: float = dataclasses.field(default_factory=time.monotonic)
    finished: float | None = None
    task: asyncio.Task | None = None

    def out(self) -> EpisodeOut:
        end = self.finished if self.finished is not None else time.monotonic()
        return EpisodeOut(
            id=self.id, kind=self.kind, status=self.status, events=list(self.events),
            n_events=self.n_events, result=self.result, error=self.error,
            elapsed_s=end - self.started,
        )  # fmt: skip


class EpisodeStore:
    """Bounded in-memory episodes of one gateway."""

    def __init__(self) -> None:
        self.episodes: collections.OrderedDict[str, Episode] = collections.OrderedDict()

    def new(self, kind: str) -> Episode:
        if len(self.episodes) >= MAX_EPISODES:
            done = [k for k, e in self.episodes.items() if e.status != "running"]
            if not done:
                raise HTTPError(429, f"{MAX_EPISODES} episodes are running; try again later")
            del self.episodes[done[0]]
        ep = Episode(uuid.uuid4().hex[:16], kind)
        self.episodes[ep.id] = ep
        return ep

    def get(self, kind: str, episode_id: str) -> Episode:
        ep = self.episodes.get(episode_id)
        if ep is None or ep.kind != kind:
            raise HTTPError(404, f"episode_id: no {kind} episode {episode_id!r}", "episode_id")
        return ep


def store_of(request: Request) -> EpisodeStore:
    store = getattr(request.app.state, "episodes", None)
    if store is None:
        store = request.app.state.episodes = EpisodeStore()
    return store


def _error(exc: grpc.aio.AioRpcError) -> EpisodeErrorOut:
    code = exc.code().name
    return EpisodeErrorOut(
        status=STATUS_BY_CODE.get(code, 500), code=code, detail=exc.details() or ""
    )


async def _start(
    request: Request,
    kind: str,
    call: grpc.aio.UnaryStreamCall,
    decode: Callable[[Any], dict[str, Any]],
    result_key: str,
) -> EpisodeStartedOut:
    """Wait for the stream to start (or fail), then consume it in the background."""
    store = store_of(request)
    try:
        await asyncio.wait_for(call.initial_metadata(), START_TIMEOUT_S)
    except TimeoutError:
        call.cancel()
        raise HTTPError(504, f"{kind} service did not start the episode in time") from None
    if call.done():
        code = await call.code()
        if code != grpc.StatusCode.OK:
            details = await call.details()
            status = STATUS_BY_CODE.get(code.name, 500)
            if status == 503:
                details = f"{kind} episode cannot start: {details}"
            raise HTTPError(status, details or code.name)
    ep = store.new(kind)

    async def consume() -> None:
        try:
            async for msg in call:
                d = decode(msg)
                if "result" in d:
                    ep.result = d["result"]
                else:
                    ep.events.append(d)
                    ep.n_events += 1
            ep.status = "done" if ep.result is not None else "failed"
            if ep.result is None:
                ep.error = EpisodeErrorOut(status=500, code="INTERNAL",
                                           detail="stream ended without a result")  # fmt: skip
        except grpc.aio.AioRpcError as exc:
            ep.status, ep.error = "failed", _error(exc)
        except asyncio.CancelledError:
            ep.status = "failed"
            ep.error = EpisodeErrorOut(status=499, code="CANCELLED", detail="gateway stopping")
            raise
        finally:
            ep.finished = time.monotonic()

    ep.task = asyncio.get_running_loop().create_task(consume())
    return EpisodeStartedOut(id=ep.id, status=ep.status)


_RESPONSES = {
    400: {"description": "Bad request (names the field)"},
    429: {"description": "An episode is already running in the service, or too many here"},
    503: {"description": "The service or one of its dependencies (sim, ...) is unavailable"},
}


@router.post(
    "/mpc/episodes",
    response_model=EpisodeStartedOut,
    status_code=202,
    tags=["planning"],
    operation_id="planning-start-episode",
    summary="Start a closed-loop pushing episode in the simulator",
    responses=_RESPONSES,
)
async def start_mpc_episode(
    request: Request, body: MPCEpisodeBody, planner: PlannerDep, settings: SettingsDep
) -> EpisodeStartedOut:
    msg = convert.episode_request_to_proto(
        body.kind,
        body.index,
        body.seed,
        objects=body.objects,
        max_steps=body.max_steps,
        options=body.options.to_kwargs(),
    )
    call = planner.RunEpisode(msg, timeout=EPISODE_TIMEOUT_S)
    return await _start(request, "mpc", call, convert.episode_event_from_proto, "result")


@router.get(
    "/mpc/episodes/{episode_id}",
    response_model=EpisodeOut,
    tags=["planning"],
    operation_id="planning-get-episode",
    summary="Progress and result of a pushing episode",
    responses={404: {"description": "Unknown episode id"}},
)
async def get_mpc_episode(request: Request, episode_id: str) -> EpisodeOut:
    return store_of(request).get("mpc", episode_id).out()


@router.post(
    "/search/episodes",
    response_model=EpisodeStartedOut,
    status_code=202,
    tags=["search"],
    operation_id="search-start-episode",
    summary="Start a shelf-search episode in the simulator",
    responses=_RESPONSES,
)
async def start_search_episode(
    request: Request, body: SearchEpisodeBody, search: SearchDep, settings: SettingsDep
) -> EpisodeStartedOut:
    msg = convert.search_episode_request_to_proto(
        body.scenario, n_objects=body.n_objects, seed=body.seed, method=body.method,
        shapes=body.shapes, actions=body.actions, dynamics_model=body.dynamics_model,
        max_steps=body.max_steps, num_sequences=body.num_sequences, plan_seed=body.plan_seed,
    )  # fmt: skip
    call = search.RunEpisode(msg, timeout=EPISODE_TIMEOUT_S)
    return await _start(request, "search", call, convert.search_event_from_proto, "result")


@router.get(
    "/search/episodes/{episode_id}",
    response_model=EpisodeOut,
    tags=["search"],
    operation_id="search-get-episode",
    summary="Progress and result of a shelf-search episode",
    responses={404: {"description": "Unknown episode id"}},
)
async def get_search_episode(request: Request, episode_id: str) -> EpisodeOut:
    return store_of(request).get("search", episode_id).out()
