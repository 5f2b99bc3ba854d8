"""Liveness (the process answers) and readiness (Redis answers and a worker runs orchestration;
the queues nobody consumes are listed)."""

from __future__ import annotations

import shutil
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from api.deps import ServicesDep, solver_queues
from api.errors import full_storage
from api.schemas import Health

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health)
def healthz():
    return Health(status="ok")


#: Free bytes below which the data directory's disk counts as full.
MIN_FREE_BYTES = 2**20


def disk_state(folder: Path) -> str:
    """ "ok", or "full: ..." when the disk of ``folder`` (or of its nearest existing parent)
    has less than :data:`MIN_FREE_BYTES` free."""
    existing = next((p for p in [folder, *folder.parents] if p.exists()), None)
    if existing is None:
        return "ok"
    free = shutil.disk_usage(existing).free
    if free < MIN_FREE_BYTES:
        return f"full: the disk of the data directory {existing} has {free} bytes free"
    return "ok"


@router.get("/readyz", response_model=Health, responses={503: {"model": Health}})
def readyz(svc: ServicesDep):
    """503 while Redis is unreachable, storage is full (``storage`` names what: the data
    directory's disk or Redis refusing writes) or no worker consumes the control queue (jobs
    could not start); otherwise 200, listing solver queues without a worker (`inspect
    active_queues`, cached a few seconds)."""
    storage = disk_state(svc.settings.data_dir)
    try:
        svc.store.ping()
    except Exception as error:
        if (full := full_storage(error)) is None:
            body = Health(
                status="unavailable", redis=f"unreachable: {type(error).__name__}", storage=storage
            )
        else:  # Redis answers, but refuses writes (PING too) it cannot persist
            reason = str(full).split(".")[0][:200]
            body = Health(
                status="unavailable",
                redis="ok, refusing writes",
                storage=f"full: Redis cannot persist writes ({reason}); free disk space where "
                "Redis keeps its files",
            )
        return JSONResponse(body.model_dump(), status_code=503)
    if storage != "ok":
        body = Health(status="unavailable", redis="ok", storage=storage)
        return JSONResponse(body.model_dump(), status_code=503)
    consumers = svc.queues.consumers()
    if consumers is None:  # the workers could not be asked
        return Health(status="ok", redis="ok", storage=storage)
    control = svc.settings.control_queue
    idle = [queue for queue in [control, *solver_queues()] if not consumers.get(queue)]
    if control in idle:
        body = Health(
            status="unavailable", redis="ok", storage=storage, queues_without_consumer=idle
        )
        return JSONResponse(body.model_dump(), status_code=503)
    return Health(status="ok", redis="ok", storage=storage, queues_without_consumer=idle)
