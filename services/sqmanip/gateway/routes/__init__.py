"""Gateway routers, one module per backend (plus health)."""

from fastapi import APIRouter

from . import episodes, grasps, health, plan, predict, recognize, sim

api_router = APIRouter()
api_router.include_router(health.router)
api_router.include_router(recognize.router)
api_router.include_router(sim.router)
api_router.include_router(grasps.router)
api_router.include_router(predict.router)
api_router.include_router(plan.router)
api_router.include_router(episodes.router)
