"""What the API builds at start instead of on its first request (issue 29: ``POST /v1/estimate``
answers within 1 s, the process's first one too). Measured on fresh processes (2000x2000 pair,
2 cores at load 10-23, docs/benchmarks.md "Estimates off the API"): FastAPI builds every
route's dependency and body models on the first request that walks past it (0.3-0.9 s, for
any route); the first ``send_task`` imported Celery's result backend and events and built its
router and producer pool (0.06-0.4 s); the solver check imported its adapter (``qpu-sim``:
0.005-0.06 s). Building these at start left their objects to the cyclic garbage collector's
oldest generation, whose next full pass then landed in a request (0.3-0.7 s at that load, the
fifth of the benchmark's misses): they are frozen (``gc.freeze``) once built. Nothing here opens
a connection: a broker or solver cloud that is down at start leaves the API starting as before.
"""

from __future__ import annotations

import gc
import logging
import time
from collections.abc import MutableMapping
from typing import Any

import cv2
import numpy as np
from fastapi import FastAPI
from starlette.exceptions import HTTPException

from api.deps import Services, load_solver, solver_catalog
from api.uploads import decode_pair
from workers.arrays import array_fields

log = logging.getLogger("qhsm.api")


#: A path no route serves: matching it walks every route (``_routes``).
NO_ROUTE = "/-warm-up-"


async def warm_up(app: FastAPI) -> dict[str, float]:
    """Build what the first request, upload, estimate or submit would build on first use;
    returns the seconds each part took (logged). Never raises: a part that fails is built on
    first use as before (and reports its error there)."""
    started = time.perf_counter()
    try:
        await _routes(app)
    except Exception as error:
        log.warning("warm-up of the routes failed (built on first use): %s", error)
    seconds = {"routes": time.perf_counter() - started}
    svc: Services = app.state.services
    for part, load in (
        ("solvers", _solvers),
        ("celery", lambda: _celery(svc)),
        ("images", lambda: _images(svc)),
    ):
        started = time.perf_counter()
        try:
            load()
        except Exception as error:  # loaded on first use instead, as without the warm-up
            log.warning("warm-up of %s failed (loaded on first use): %s", part, error)
        seconds[part] = time.perf_counter() - started
    started = time.perf_counter()
    gc.collect()
    gc.freeze()  # what start-up built lives as long as the process: no collection scans it
    seconds["gc"] = time.perf_counter() - started
    log.info("warm-up: %s", ", ".join(f"{part} {value:.3f} s" for part, value in seconds.items()))
    return seconds


async def _routes(app: FastAPI) -> None:
    """One request for :data:`NO_ROUTE` sent to the router alone (no middleware: nothing
    logged, no key asked): FastAPI builds each route's models while matching (404)."""
    scope: dict[str, Any] = {
        "type": "http",
        "http_version": "1.1",
        "method": "GET",
        "scheme": "http",
        "path": NO_ROUTE,
        "raw_path": NO_ROUTE.encode(),
        "root_path": "",
        "query_string": b"",
        "headers": [],
        "client": ("127.0.0.1", 0),
        "server": ("127.0.0.1", 80),
        "app": app,
    }

    async def receive() -> dict[str, Any]:
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message: MutableMapping[str, Any]) -> None:
        return None

    try:
        await app.router(scope, receive, send)
    except HTTPException as answer:  # FastAPI's router raises its 404; the middleware answers
        if answer.status_code != 404:
            raise


def _solvers() -> None:
    """Every registered solver's adapter imported and its availability read (what
    ``check_solver`` does per request; one per process, kept by the registry)."""
    for solver in solver_catalog():
        load_solver(solver.spec.name)


def _celery(svc: Services) -> None:
    """The parts of ``send_task`` built on its first call, without connecting."""
    celery = svc.celery
    amqp = celery.amqp
    _ = celery.backend, amqp.router, amqp.send_task_message, celery.producer_pool


def _images(svc: Services) -> None:
    """An upload's path on a tiny pair: PNG decoding and the views' Redis form."""
    tiny = cv2.imencode(".png", np.zeros((4, 4, 3), np.uint8))[1].tobytes()
    for view in decode_pair(tiny, tiny, svc.settings):
        array_fields("view", view, images=True)
