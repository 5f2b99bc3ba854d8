"""Liveness (the process answers) and readiness (Redis answers and a worker runs orchestration;
the queues nobody consumes are listed)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from api.deps import ServicesDep
from api.schemas import Health
from shared.solvers.registry import queue_names

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health)
def healthz():
    return Health(status="ok")


@router.get("/readyz", response_model=Health, responses={503: {"model": Health}})
def readyz(svc: ServicesDep):
    """503 while Redis is unreachable or no worker consumes the control queue (jobs could not
    start); otherwise 200, listing solver queues without a worker (`inspect active_queues`,
    cached a few seconds)."""
    try:
        svc.store.ping()
    except Exception as error:
        body = Health(status="unavailable", redis=f"unreachable: {type(error).__name__}")
        return JSONResponse(body.model_dump(), status_code=503)
    consumers = svc.queues.consumers()
    if consumers is None:  # the workers could not be asked
        return Health(status="ok", redis="ok")
    control = svc.settings.control_queue
    idle = [queue for queue in [control, *queue_names()] if not consumers.get(queue)]
    if control in idle:
        body = Health(status="unavailable", redis="ok", queues_without_consumer=idle)
        return JSONResponse(body.model_dump(), status_code=503)
    return Health(status="ok", redis="ok", queues_without_consumer=idle)
