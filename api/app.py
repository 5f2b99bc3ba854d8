"""The FastAPI application: ``uvicorn api.app:app`` or ``qhsm api`` (``qhsm serve`` runs it with
workers and an embedded Redis). OpenAPI docs at /docs and /redoc, their assets served from
the package (fastapi-offline), never from a CDN."""

from __future__ import annotations

import logging
import warnings

import redis
from fastapi import Depends, FastAPI, Request
from fastapi.responses import JSONResponse
from fastapi_offline import FastAPIOffline

from api import web
from api.access_log import quiet_polls
from api.deps import QueueInspector, Services
from api.middleware import ErrorBoundary, RequestGuard
from api.routes import estimate, health, jobs, metrics, solvers, usage, users, views
from api.uploads import UploadError
from api.users import UserStore, current_user
from shared.config import Settings, get_settings
from shared.disparity_range import ViewsWarning
from workers.app import make_celery
from workers.store import JobStore

log = logging.getLogger("qhsm.api")


def create_app(settings: Settings | None = None) -> FastAPI:
    """An app bound to ``settings`` (read from the environment when omitted)."""
    settings = settings or get_settings()
    # a job's view warnings go back to its submitter (JobCreated, JobStatus), not to this log
    warnings.filterwarnings("ignore", category=ViewsWarning)
    celery = make_celery(settings, with_tasks=False)
    app: FastAPI = FastAPIOffline(
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
    # every /v1 route needs an API key; /healthz, /readyz, /docs and the web page stay open
    authenticated = [Depends(current_user)]
    app.include_router(jobs.router, dependencies=authenticated)
    app.include_router(estimate.router, dependencies=authenticated)
    app.include_router(views.router, dependencies=authenticated)
    app.include_router(views.thumbnails, dependencies=authenticated)
    app.include_router(solvers.router, dependencies=authenticated)
    app.include_router(usage.router, dependencies=authenticated)
    app.include_router(users.router)
    app.include_router(users.me_router)
    app.include_router(health.router)
    app.include_router(metrics.router)  # admin key checked by the route
    web.mount(app)
    app.state.users = UserStore.from_settings(settings, app.state.services.store.redis)

    @app.exception_handler(UploadError)
    async def upload_error(request: Request, error: UploadError) -> JSONResponse:
        return JSONResponse({"detail": error.message}, status_code=error.status_code)

    @app.exception_handler(redis.ConnectionError)
    @app.exception_handler(redis.TimeoutError)
    async def store_down(request: Request, error: redis.RedisError) -> JSONResponse:
        log.warning("%s %s: Redis unavailable: %s", request.method, request.url.path, error)
        return JSONResponse(
            {
                "detail": "the service's job store (Redis) is unavailable right now; nothing "
                "was changed. Try again in a minute (running jobs resume when it is back)"
            },
            status_code=503,
            headers={"Retry-After": "30"},
        )

    # added last = outermost: the boundary also catches what the guard raises
    app.add_middleware(RequestGuard, settings=settings)
    app.add_middleware(ErrorBoundary)
    quiet_polls()
    return app


app = create_app()
