"""The API router: every resource router under ``/api``."""

from __future__ import annotations

from fastapi import APIRouter

from server.api.routes import analytics, batch, jobs, results, sessions, utils, viewer
from server.api.routes import annotations as annotation_routes

api_router = APIRouter()
api_router.include_router(utils.router)
api_router.include_router(sessions.router)
api_router.include_router(jobs.router)
api_router.include_router(annotation_routes.router)
api_router.include_router(results.router)
api_router.include_router(analytics.router)
api_router.include_router(batch.router)
api_router.include_router(viewer.router)
