"""FastAPI dependencies: settings and one gRPC stub per backend, as ``Annotated`` aliases.

Channels are created in the app's lifespan (inside its event loop) and kept in
``app.state.channels``; tests override these with ``app.dependency_overrides`` or by passing
settings that point at their own servers.
"""

from __future__ import annotations

from typing import Annotated

import grpc
from fastapi import Depends, Request

from sqmanip.v1 import (
    dynamics_pb2_grpc,
    grasp_pb2_grpc,
    perception_pb2_grpc,
    planner_pb2_grpc,
    search_pb2_grpc,
    sim_pb2_grpc,
)

from .config import GatewaySettings
from .errors import HTTPError


async def get_settings(request: Request) -> GatewaySettings:
    return request.app.state.settings


def channel_for(request: Request, service: str) -> grpc.aio.Channel:
    channels: dict[str, grpc.aio.Channel] = request.app.state.channels
    if service not in channels:
        raise HTTPError(503, f"{service} service is not configured in this gateway")
    request.state.backend = service
    return channels[service]


async def get_perception(request: Request) -> perception_pb2_grpc.PerceptionStub:
    return perception_pb2_grpc.PerceptionStub(channel_for(request, "perception"))


async def get_sim(request: Request) -> sim_pb2_grpc.SimulatorStub:
    return sim_pb2_grpc.SimulatorStub(channel_for(request, "sim"))


async def get_grasp(request: Request) -> grasp_pb2_grpc.GraspPlannerStub:
    return grasp_pb2_grpc.GraspPlannerStub(channel_for(request, "grasp"))


async def get_dynamics(request: Request) -> dynamics_pb2_grpc.DynamicsStub:
    return dynamics_pb2_grpc.DynamicsStub(channel_for(request, "dynamics"))


async def get_planner(request: Request) -> planner_pb2_grpc.PlannerStub:
    return planner_pb2_grpc.PlannerStub(channel_for(request, "mpc"))


async def get_search(request: Request) -> search_pb2_grpc.SearchStub:
    return search_pb2_grpc.SearchStub(channel_for(request, "search"))


SettingsDep = Annotated[GatewaySettings, Depends(get_settings)]
PerceptionDep = Annotated[perception_pb2_grpc.PerceptionStub, Depends(get_perception)]
SimDep = Annotated[sim_pb2_grpc.SimulatorStub, Depends(get_sim)]
GraspDep = Annotated[grasp_pb2_grpc.GraspPlannerStub, Depends(get_grasp)]
DynamicsDep = Annotated[dynamics_pb2_grpc.DynamicsStub, Depends(get_dynamics)]
PlannerDep = Annotated[planner_pb2_grpc.PlannerStub, Depends(get_planner)]
SearchDep = Annotated[search_pb2_grpc.SearchStub, Depends(get_search)]
