"""The FastAPI application: ``uvicorn api.app:app`` or ``qhsm api`` (``qhsm serve`` runs it with
workers and an embedded Redis). OpenAPI docs at /docs."""

from __future__ import annotations

import logging
import uuid

from fastapi import Depends, FastAPI, Request
from fastapi.responses import JSONResponse

from api.deps import QueueInspector, Services
from api.routes import estimate, health, jobs, solvers, usage
from api.uploads import UploadError
from api.users import UserStore, current_user
from shared.config import Settings, get_settings
from workers.app import load_plugins, make_celery
from workers.store import JobStore

log = logging.getLogger("qhsm.api")


def create_app(settings: Settings | None = None) -> FastAPI:
    """An app bound to ``settings`` (read from the environment when omitted)."""
    settings = settings or get_settings()
    load_plugins(settings)
    celery = make_celery(settings, with_tasks=False)
    app = FastAPI(
        title="qhsm",
        version="1",
        summary="Quantum-hybrid stereo matching as a job service",
        description="Upload a rectified stereo pair, poll the job, download the disparity map.",
    )
    app.state.services = Services(
        settings=settings,
        store=JobStore.from_settings(settings),
        celery=celery,
        queues=QueueInspector(celery, settings.inspect_timeout),
    )
    # every /v1 route needs an API key; /healthz, /readyz and /docs stay open
    authenticated = [Depends(current_user)]
    app.include_router(jobs.router, dependencies=authenticated)
    app.include_router(estimate.router, dependencies=authenticated)
    app.include_router(solvers.router, dependencies=authenticated)
    app.include_router(usage.router, dependencies=authenticated)
    app.include_router(health.router)
    app.state.users = UserStore.from_settings(settings, app.state.services.store.redis)

    @app.exception_handler(UploadError)
    async def upload_error(request: Request, error: UploadError) -> JSONResponse:
        return JSONResponse({"detail": error.message}, status_code=error.status_code)

    @app.exception_handler(Exception)
    async def unexpected(request: Request, error: Exception) -> JSONResponse:
        incident = uuid.uuid4().hex[:12]
        log.exception("incident %s: %s %s failed", incident, request.method, request.url.path)
        return JSONResponse(
            {"detail": f"internal error (incident {incident}); the details are in the server log"},
            status_code=500,
        )

    return app


app = create_app()
