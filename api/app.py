"""The FastAPI application: ``uvicorn api.app:app`` or ``qhsm api`` (``qhsm serve`` runs it with
workers and an embedded Redis). OpenAPI docs at /docs and /redoc, their assets served from
the package (fastapi-offline), never from a CDN."""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import redis
from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from fastapi_offline import FastAPIOffline
from starlette.exceptions import HTTPException as StarletteHTTPException

from api import routes, web
from api.access_log import quiet_polls
from api.deps import QueueInspector, Services
from api.errors import DOMAIN_ERRORS, refusal_of, storage_full
from api.middleware import ErrorBoundary, RequestGuard, storage_full_response
from api.routes import health, metrics
from api.users import UserStore
from api.warmup import warm_up
from shared.config import Settings, get_settings
from workers.app import make_celery
from workers.records import finite_or_null
from workers.store import JobStore

log = logging.getLogger("qhsm.api")


def create_app(settings: Settings | None = None) -> FastAPI:
    """An app bound to ``settings`` (read from the environment when omitted)."""
    settings = settings or get_settings()
    celery = make_celery(settings, with_tasks=False)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await warm_up(app)  # before the first request is accepted (api/warmup.py)
        yield

    app: FastAPI = FastAPIOffline(
        lifespan=lifespan,
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
    app.include_router(routes.v1())  # every /v1 route needs an API key
    app.include_router(health.router)
    app.include_router(metrics.router)  # admin key checked by the route (and by RequestGuard)
    web.mount(app)
    app.state.users = UserStore.from_settings(settings, app.state.services.store.redis)

    async def refused(request: Request, error: Exception) -> JSONResponse:
        status_code, detail = refusal_of(error)
        return JSONResponse({"detail": detail}, status_code=status_code)

    for domain_error in DOMAIN_ERRORS:  # the service's refusals: a 4xx that says what to do
        app.add_exception_handler(domain_error, refused)

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, error: RequestValidationError) -> JSONResponse:
        # FastAPI's own handler echoes the input, which fails to encode when it is Infinity
        # or NaN (a JSON body may hold them): a 500 instead of the 422
        detail = finite_or_null(jsonable_encoder(error.errors()))
        return JSONResponse({"detail": detail}, status_code=422)

    @app.exception_handler(OSError)
    async def disk_error(request: Request, error: OSError) -> JSONResponse:
        if not storage_full(error):
            raise error  # a bug: the ErrorBoundary answers 500 with an incident id
        return storage_full_response(request, error)

    @app.exception_handler(redis.ResponseError)
    async def redis_refused(request: Request, error: redis.ResponseError) -> JSONResponse:
        if not storage_full(error):
            raise error
        return storage_full_response(request, error)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, error: StarletteHTTPException) -> Response:
        # FastAPI turns any error while it reads a form into "400 error parsing the body",
        # a full disk under the spooled upload included
        cause = error.__cause__
        if cause is not None and storage_full(cause):
            return storage_full_response(request, cause)
        return await http_exception_handler(request, error)

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
    guarded = [*((routes.V1, part) for part, _ in routes.v1_parts()), ("", health.router)]
    guarded.append(("", metrics.router))
    app.add_middleware(RequestGuard, settings=settings, routers=guarded)
    app.add_middleware(ErrorBoundary)
    quiet_polls()
    return app


app = create_app()
