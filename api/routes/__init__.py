"""Routers, one per resource, under one ``/v1`` router (:func:`v1`); a route module imports no
other (what several share is in :mod:`api.responses`)."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from api.auth import current_user
from api.routes import estimate, jobs, solvers, usage, users, views


def v1() -> APIRouter:
    """Every ``/v1`` route. All need an API key (the users' routes check theirs, an admin's for
    most); ``/healthz``, ``/readyz``, ``/metrics``, ``/docs`` and the web page are outside it."""
    authenticated = [Depends(current_user)]
    router = APIRouter(prefix="/v1")
    router.include_router(jobs.router, dependencies=authenticated)
    router.include_router(estimate.router, dependencies=authenticated)
    router.include_router(views.router, dependencies=authenticated)
    router.include_router(views.thumbnails, dependencies=authenticated)
    router.include_router(solvers.router, dependencies=authenticated)
    router.include_router(usage.router, dependencies=authenticated)
    router.include_router(users.router)
    router.include_router(users.me_router)
    return router
