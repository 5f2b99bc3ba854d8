"""GET /metrics: the service's Prometheus metrics (defined in :mod:`workers.telemetry`).

It needs an admin's key (per-user QPU seconds are in it): Prometheus sends it with
``authorization: {credentials: KEY}`` in the scrape config.
"""

from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import Response
from prometheus_client import CONTENT_TYPE_LATEST

from api.auth import admin_user
from api.deps import ServicesDep, solver_queues
from workers.telemetry import exposition

router = APIRouter(tags=["metrics"])


@router.get(
    "/metrics",
    response_class=Response,
    dependencies=[Depends(admin_user)],
    responses={200: {"content": {CONTENT_TYPE_LATEST: {}}}, 403: {"description": "Not an admin"}},
)
def metrics(svc: ServicesDep) -> Response:
    """Jobs by state, bundles solved and task times per solver, queue depths, QPU seconds per
    user and watchdog re-sends, in Prometheus' text format."""
    queues = [svc.settings.control_queue, *solver_queues()]
    body = exposition(svc.settings, svc.store.redis, queues)
    return Response(body, media_type=CONTENT_TYPE_LATEST)
