"""FastAPI dependencies: the settings, the job store and the Celery client of this app, the
solvers (resolved here, the API's one door to the solver registry), and the ``Annotated``
aliases the routes declare their parameters with (one place, not one per route)."""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Annotated, Any, NamedTuple

from celery import Celery
from fastapi import Depends, Form, Request, UploadFile
from pydantic import BaseModel, Field

from api.auth import Principal, current_principal
from api.users import User, UserStore, admin_user, user_store
from shared.config import MatchConfig, Settings
from shared.solvers.base import Availability
from shared.solvers.errors import UnknownSolverError
from shared.solvers.registry import ResolvedSolver, queue_names, resolve, solver_names
from workers.store import JobStore

log = logging.getLogger(__name__)

#: A route's OpenAPI ``responses``: status code -> description and content.
Responses = dict[int | str, dict[str, Any]]

#: How long the answer of ``inspect active_queues`` is reused, seconds.
QUEUE_CACHE_SECONDS = 5.0


@dataclass
class QueueInspector:
    """Which workers consume which queue, from Celery's ``inspect active_queues`` (cached)."""

    celery: Celery
    timeout: float
    _cache: tuple[float, dict[str, list[str]] | None] | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def consumers(self) -> dict[str, list[str]] | None:
        """Queue name -> worker names; None when the broker cannot be asked."""
        with self._lock:
            if self._cache and time.monotonic() - self._cache[0] < QUEUE_CACHE_SECONDS:
                return self._cache[1]
            consumers: dict[str, list[str]] | None
            try:
                # a connection of our own, closed here: a pooled one would keep a pending BRPOP
                # that kombu's after-fork cleanup blocks on in any process forked later
                with self.celery.connection_for_write() as connection:
                    inspect = self.celery.control.inspect(
                        timeout=self.timeout, connection=connection
                    )
                    replies = inspect.active_queues()
            except Exception as error:  # broker down: report "unknown", not a 500
                log.warning("inspect active_queues failed: %s", error)
                consumers = None
            else:
                found: dict[str, list[str]] = {}
                for worker, queues in (replies or {}).items():  # None: no worker answered
                    for queue in queues:
                        found.setdefault(queue["name"], []).append(worker)
                consumers = found
            self._cache = (time.monotonic(), consumers)
            return consumers


@dataclass
class Services:
    settings: Settings
    store: JobStore
    celery: Celery
    queues: QueueInspector


def services(request: Request) -> Services:
    return request.app.state.services


ServicesDep = Annotated[Services, Depends(services)]
PrincipalDep = Annotated[Principal, Depends(current_principal)]
UsersDep = Annotated[UserStore, Depends(user_store)]
#: The caller when they are an admin (403 otherwise).
AdminDep = Annotated[User, Depends(admin_user)]


class Caller(NamedTuple):
    """Who calls, and the app's services and user store they act through: what every job,
    estimate and batch route takes (one parameter, not three per route)."""

    svc: Services
    principal: Principal
    users: UserStore


def caller(svc: ServicesDep, principal: PrincipalDep, users: UsersDep) -> Caller:
    return Caller(svc, principal, users)


CallerDep = Annotated[Caller, Depends(caller)]

#: What the ``params`` form field holds (jobs, estimates and batches).
PARAMS = 'MatchConfig fields as JSON, e.g. {"solver": "qpu"}'
ParamsForm = Annotated[str | None, Form(description=PARAMS)]


class UploadViews(BaseModel):
    """The upload form of POST /v1/estimate: a stereo pair and its params (POST /v1/jobs's form
    begins with the same fields)."""

    left: UploadFile = Field(description="Left view (PNG, PPM/PGM, JPEG, PFM, TIFF)")
    right: UploadFile = Field(description="Right view, same size")
    params: str | None = Field(None, description=PARAMS)


def load_solver(config: MatchConfig | str) -> tuple[ResolvedSolver, Availability]:
    """The job's solver (or the one named), resolved, and whether its adapter runs here; an
    adapter that fails to load is unavailable.

    Raises ``UnknownSolverError`` for names that are not registered.
    """
    solver = resolve(config)
    try:
        sampler = solver.sampler
    except UnknownSolverError:
        raise
    except Exception as error:  # a broken optional dependency must not take the API down
        log.exception("solver %s failed to load", solver.spec.name)
        reason = f"its adapter failed to load here ({type(error).__name__})"
        return solver, Availability(False, reason)
    return solver, sampler.available()


def solver_catalog() -> list[ResolvedSolver]:
    """Every registered solver, resolved by name (``dimod:`` names are accepted, not listed)."""
    return [resolve(name) for name in solver_names()]


def solver_queues() -> list[str]:
    """Every solver queue a worker may consume."""
    return queue_names()
