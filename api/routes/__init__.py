"""Routers, one per resource, under one ``/v1`` router (:func:`v1`); a route module imports no
other (what several share is in :mod:`api.responses`)."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from api.auth import current_user
from api.routes import batches, estimate, jobs, solvers, usage, users, views

#: Where :func:`v1`'s routes are.
V1 = "/v1"


def v1_parts() -> list[tuple[APIRouter, bool]]:
    """The routers under ``/v1``, each with whether :func:`v1` checks the API key for it (the
    users' routes check theirs); ``api.middleware.RequestGuard`` reads their policies too."""
    return [
        (jobs.router, True),
        (batches.router, True),
        (estimate.router, True),
        (views.router, True),
        (views.thumbnails, True),
        (solvers.router, True),
        (usage.router, True),
        (users.router, False),
        (users.me_router, False),
    ]


def v1() -> APIRouter:
    """Every ``/v1`` route. All need an API key (the users' routes check theirs, an admin's for
    most); ``/healthz``, ``/readyz``, ``/metrics``, ``/docs`` and the web page are outside it."""
    authenticated = [Depends(current_user)]
    router = APIRouter(prefix=V1)
    for part, checked in v1_parts():
        router.include_router(part, dependencies=authenticated if checked else [])
    return router
