"""Gateway routers, one module per backend (plus health)."""

from fastapi import APIRouter

from . import grasps, health, predict, recognize, sim

api_router = APIRouter()
api_router.include_router(health.router)
api_router.include_router(recognize.router)
api_router.include_router(sim.router)
api_router.include_router(grasps.router)
api_router.include_router(predict.router)
