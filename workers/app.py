"""The Celery application: Redis broker and result backend, one queue per solver plus a control
queue for orchestration. Long-task settings (acks_late, reject_on_worker_lost, prefetch 1, a
visibility timeout above the longest task) make a killed worker's task run again elsewhere.

Start a worker bound to the solvers a machine can run, e.g.::

    celery -A workers worker -Q control,exact,sa -c 2
    celery -A workers worker -Q dimod -c 2        # every dimod:PACKAGE.MODULE.CLASS solver
    celery -A workers worker -Q qpu -c 1          # the only kind that needs DWAVE_API_TOKEN

Each solver's queue is declared in the registry (``shared.solvers.registry.SolverSpec.queue``);
solvers of installed packages' ``qhsm.solvers`` entry points are found there without any setting.
"""

from __future__ import annotations

import logging
from typing import Any

from celery import Celery

from shared.config import Settings, get_settings
from workers.redis_client import redis_url

log = logging.getLogger(__name__)

#: Task names (the API sends tasks by name so it never imports solver code).
START_JOB = "qhsm.start_job"
PLAN_LEVEL = "qhsm.plan_level"
FAN_OUT_LEVEL = "qhsm.fan_out_level"
#: ``workers.tasks.solve_bundles``; the name is the old one, so that messages queued (or held
#: unacknowledged) by an older version still find their task after an upgrade.
SOLVE_BUNDLES = "qhsm.solve_rows"
LEVEL_DONE = "qhsm.level_done"
#: On the pricing queue (``workers.pricing_tasks``): a metered job's price and admission, and
#: an estimate of ``POST /v1/estimate``.
PRICE_JOB = "qhsm.price_job"
PRICE_ESTIMATE = "qhsm.price_estimate"
#: What the pricing tasks' time limits are looked up as (``task_time_limits``; per deployment
#: ``QHSM_SOLVER_TIME_LIMITS={"pricing": ...}``).
PRICING = "pricing"


def pricing_task_id(job_id: str) -> str:
    """The id of a job's pricing task (a cancel revokes it by this id)."""
    return f"{job_id}-pricing"


def celery_config(settings: Settings) -> dict:
    """Celery settings derived from ``Settings`` (every key namespaced by ``key_prefix``)."""
    url = redis_url(settings)
    prefix = f"{settings.key_prefix}:"
    return {
        "broker_url": url,
        "result_backend": url,
        "broker_transport_options": {
            "visibility_timeout": settings.task_visibility_timeout,
            "global_keyprefix": prefix,
            # the next task from the user with the fewest running (workers/fair.py)
            "queue_order_strategy": "workers.fair:FewestRunningFirst",
        },
        "result_backend_transport_options": {"global_keyprefix": prefix},
        "broker_connection_retry_on_startup": True,
        "task_serializer": "json",
        "result_serializer": "json",
        "accept_content": ["json"],
        # bundle results only feed their level's fan-in; job results live in the job store
        "result_expires": settings.task_visibility_timeout + 3600,
        "task_default_queue": settings.control_queue,
        "task_acks_late": True,
        "task_reject_on_worker_lost": True,
        "worker_prefetch_multiplier": 1,
        # task events for Flower and `celery events` (docker compose --profile monitoring)
        "worker_send_task_events": True,
        "task_send_sent_event": True,
    }


def task_time_limits(settings: Settings, solver: str) -> dict[str, float]:
    """Celery options bounding one solver task: the soft limit raises in the task (the job
    fails with a message), the hard one kills a process stuck in native code."""
    soft = settings.solver_time_limits.get(solver, settings.task_soft_time_limit)
    return {"soft_time_limit": soft, "time_limit": soft + settings.task_time_limit_grace}


def send_first_task(celery: Celery, settings: Settings, job_id: str, *, pricing: bool) -> None:
    """Send a written job's first task: a pricing job's ``qhsm.price_job`` to the pricing queue
    (with the pricing's time limits, and an id a cancel revokes), any other's ``qhsm.start_job``
    to the control queue. The API sends it at submit; the watchdog again when it was lost
    (both tasks are idempotent)."""
    if pricing:
        celery.send_task(
            PRICE_JOB,
            args=(job_id,),
            queue=settings.pricing_queue,
            task_id=pricing_task_id(job_id),
            **task_time_limits(settings, PRICING),
        )
    else:
        celery.send_task(START_JOB, args=(job_id,), queue=settings.control_queue)


def terminate_tasks(celery: Celery, task_ids: list[str], solver: str) -> None:
    """Revoke tasks and kill the pool processes running them, so a cancelled or failed job
    frees its workers at once. SIGKILL: a solver in native code ignores anything softer;
    metered solvers get SIGTERM so their QPU slot and budget reservation are released."""
    from shared.solvers.meters import is_metered

    if task_ids:
        signal = "SIGTERM" if is_metered(solver) else "SIGKILL"
        celery.control.revoke(task_ids, terminate=True, signal=signal)


class QhsmCelery(Celery):
    """A Celery app that carries the :class:`Settings` it was made with: its tasks and worker
    bootsteps read them from the app, not from the environment again."""

    def __init__(self, *args: Any, settings: Settings | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # None where Celery rebuilds an app from its pickle (it passes its own keywords only)
        self.qhsm_settings = settings or get_settings()


def make_celery(settings: Settings | None = None, *, with_tasks: bool = True) -> QhsmCelery:
    """A Celery app for ``settings``; ``with_tasks=False`` gives a light client (the API's)."""
    include = ["workers.tasks", "workers.pricing_tasks"] if with_tasks else []
    celery = QhsmCelery("qhsm", include=include, settings=settings)
    celery.conf.update(celery_config(celery.qhsm_settings))
    if with_tasks:  # a worker: heartbeats with the messages it holds (workers/liveness.py)
        from workers import liveness

        liveness.install(celery)
    return celery


app = make_celery()
