"""Celery tasks: thin wrappers that turn errors into job states (see ``orchestration``).

Solver errors: ``TransientSolverError`` is retried with exponential backoff, up to
``Settings.task_retries`` times; any other ``SolverError`` fails the job with the solver's
message. Unexpected errors are logged with their traceback and fail the job with a short
message; tasks never raise into the chord, so every level's fan-in runs. The exception is an
unreachable Redis, which is not the job's fault: the task gives up without failing the job, and
the watchdog (``workers/watchdog.py``) re-sends what was lost once Redis is back.
"""

from __future__ import annotations

import importlib
import logging
import time

import redis
from celery import Task, signals
from celery.exceptions import SoftTimeLimitExceeded, TimeLimitExceeded

from shared.solvers import SolverError, TransientSolverError
from shared.threads import inherited_threads, limit_threads, thread_budget
from workers import fair, orchestration, watchdog
from workers.app import (
    FAN_OUT_LEVEL,
    LEVEL_DONE,
    PLAN_LEVEL,
    SOLVE_BUNDLES,
    START_JOB,
    app,
    task_time_limits,
    terminate_tasks,
)
from workers.bounded import DataNotStoredError
from workers.context import WorkerContext, current
from workers.context import start as start_context
from workers.level_store import LevelInputsMissingError
from workers.process import die_with_parent, lower_priority, memory_budget
from workers.quota import QuotaExceededError
from workers.store import JobStore, UploadsMissingError

log = logging.getLogger(__name__)
#: Errors of an unreachable Redis: the job is not at fault, so they never fail it.
REDIS_DOWN = (redis.ConnectionError, redis.TimeoutError)

#: This process's context (settings, store, meter, metrics): started from the app's settings
#: here, in the worker's main process, and again in each pool process after the fork.
start_context(app.qhsm_settings)


def install_embedding_store() -> None:
    """Share minor embeddings between workers through Redis when that module is present."""
    try:
        module = importlib.import_module("workers.embedding_store")
    except ModuleNotFoundError as error:
        if error.name != "workers.embedding_store":
            raise
        return
    install = getattr(module, "install", None)
    if callable(install):
        install(current().settings)
        log.info("embedding store installed")


#: Threads per pool process when the worker was started without a budget in its environment
#: (by hand: ``celery -A workers worker -c N``): the cores shared among its N processes.
_pool_threads: int | None = None


@signals.celeryd_init.connect
def _share_cores(options: dict | None = None, **_: object) -> None:
    global _pool_threads
    concurrency = (options or {}).get("concurrency")
    _pool_threads = thread_budget(int(concurrency)) if concurrency else None


@signals.worker_process_init.connect
def _init_process(**_: object) -> None:
    die_with_parent()  # a pool process never outlives its worker (even a SIGKILLed one)
    # OpenCV, OpenMP/BLAS and numba threads: this process's share of the cores (shared.threads)
    limit_threads(inherited_threads() or _pool_threads or thread_budget())
    start_context(app.qhsm_settings)  # this process's own connections, none from the parent
    install_embedding_store()


@signals.worker_ready.connect
def _start_watchdog(sender=None, **_: object) -> None:
    """The worker that runs orchestration also watches for stalled jobs (workers/watchdog.py)."""
    settings = current().settings
    queues = {queue.name for queue in getattr(sender.task_consumer, "queues", [])}
    if settings.control_queue in queues:
        watchdog.start_thread(app, JobStore.from_settings(settings), sender.hostname)


@app.task(name=START_JOB, bind=True, ignore_result=True)
def start_job(self, job_id: str) -> None:
    ctx = current()
    try:
        with memory_budget(ctx.budget_mb()):
            orchestration.start_job(app, ctx.store, job_id)
    except (SolverError, ValueError) as error:  # no segment embeds, data not stored (Redis full)
        log.warning("job %s: %s", job_id, error)
        ctx.store.fail(job_id, str(error))
    except MemoryError:
        log.warning("job %s: out of memory preparing level 1", job_id)
        ctx.store.fail(job_id, memory_message(ctx, 0))
    except Exception:
        log.exception("job %s: start failed", job_id)
        ctx.store.fail(job_id, orchestration.internal_error(job_id, "starting the job"))


@app.task(name=LEVEL_DONE, bind=True, ignore_result=True)
def level_done(self, results: list[dict], job_id: str, index: int) -> None:
    ctx = current()
    try:
        with memory_budget(ctx.budget_mb()):
            orchestration.level_done(app, ctx.store, results, job_id, index)
    except REDIS_DOWN as error:  # the watchdog re-sends the fan-in when Redis is back
        log.warning("job %s: Redis unavailable in the fan-in of level %d: %s", job_id, index, error)
    except (SolverError, UploadsMissingError, DataNotStoredError) as error:  # e.g. no embedding
        log.warning("job %s: %s", job_id, error)
        ctx.store.fail(job_id, str(error))
    except MemoryError:
        log.warning("job %s: out of memory assembling level %d", job_id, index + 1)
        ctx.store.fail(job_id, memory_message(ctx, index + 1))
    except Exception:
        log.exception("job %s: fan-in of level %d failed", job_id, index)
        message = orchestration.internal_error(job_id, f"assembling level {index + 1}")
        ctx.store.fail(job_id, message)


class SolverTask(Task):
    """A solver task; a hard time limit (the pool process was killed) fails its job."""

    def on_failure(self, exc, task_id, args, kwargs, einfo) -> None:
        if isinstance(exc, TimeLimitExceeded) and args:
            ctx, job_id, index = current(), args[0], args[1]
            ctx.store.task_ended(job_id, task_id)
            _fail(ctx, job_id, time_limit_message(ctx, job_id, index, hard=True))


@app.task(name=PLAN_LEVEL, bind=True, base=SolverTask, ignore_result=True)
def plan_level(self, job_id: str, index: int) -> None:
    """On the solver's queue (where the D-Wave token is): the level's bundle plan."""
    ctx = current()
    try:
        orchestration.plan_level(ctx.store, job_id, index)
    except SoftTimeLimitExceeded:
        _fail(ctx, job_id, time_limit_message(ctx, job_id, index, hard=False))
    except TransientSolverError as error:  # the QPU's graph could not be fetched
        _retry_or_fail(ctx, self, job_id, error, "planning")
    except SolverError as error:  # e.g. no segment embeds, or no token here: what to change
        _fail(ctx, job_id, str(error))
    except (LevelInputsMissingError, orchestration.JobGoneError):
        return
    except REDIS_DOWN as error:  # the watchdog re-sends the plan when Redis is back
        log.warning("job %s: Redis unavailable planning level %d: %s", job_id, index, error)
        raise
    except MemoryError:
        _fail(ctx, job_id, memory_message(ctx, index))
    except Exception:
        log.exception("job %s: planning level %d failed", job_id, index)
        _fail(ctx, job_id, orchestration.internal_error(job_id, f"planning level {index + 1}"))


@app.task(name=FAN_OUT_LEVEL, bind=True, ignore_result=True)
def fan_out_level(self, job_id: str, index: int) -> None:
    """On the control queue, after ``plan_level``: the level's chord."""
    ctx = current()
    try:
        orchestration.fan_out_level(app, ctx.store, job_id, index)
    except REDIS_DOWN as error:
        log.warning("job %s: Redis unavailable fanning out level %d: %s", job_id, index, error)
    except LevelInputsMissingError:
        return
    except Exception:
        log.exception("job %s: fan-out of level %d failed", job_id, index)
        message = orchestration.internal_error(job_id, f"starting level {index + 1}")
        ctx.store.fail(job_id, message)


@app.task(name=SOLVE_BUNDLES, bind=True, base=SolverTask)
def solve_bundles(self, job_id: str, index: int, row_ranges: list[list[int]]) -> dict:
    """Solve the bundles ``row_ranges`` of level ``index`` (``orchestration.solve_chunk``)."""
    ctx = current()
    settings, store = ctx.settings, ctx.store
    ranges = [[int(value) for value in bundle] for bundle in row_ranges]
    lower_priority(settings.solver_nice)  # orchestration and the API get the CPU first
    worker = self.request.hostname or ""
    task_id = self.request.id
    queue = (self.request.delivery_info or {}).get("routing_key") or "unknown"
    if task_id:
        store.task_started(job_id, task_id)
        limit = task_time_limits(settings, fair.base_queue(queue))["time_limit"]
        fair.task_started(store.redis, settings.key_prefix, queue, task_id, limit)
    started = time.perf_counter()
    try:
        with memory_budget(ctx.budget_mb()):  # dimod: samplers included
            result = orchestration.solve_chunk(
                store, job_id, index, ranges, worker, meter=lambda: ctx.meter
            )
        if result is not None and not result.get("duplicate"):
            seconds = time.perf_counter() - started
            ctx.telemetry.task_done(fair.base_queue(queue), seconds, result["bundles"])
    except SoftTimeLimitExceeded:
        return _fail(ctx, job_id, time_limit_message(ctx, job_id, index, hard=False), task_id)
    except MemoryError:
        log.warning("job %s: a task of level %d ran out of memory", job_id, index)
        return _fail(ctx, job_id, memory_message(ctx, index), task_id)
    except TransientSolverError as error:
        return _retry_or_fail(ctx, self, job_id, error, "transient solver error", task_id)
    except QuotaExceededError as error:
        message = f"stopped: {error}; bundles not solved yet were not sent"
        store.fail(job_id, message)
        return {"error": message}
    except (SolverError, DataNotStoredError) as error:
        return _fail(ctx, job_id, str(error), task_id)
    except (LevelInputsMissingError, orchestration.JobGoneError):
        return {"skipped": True}
    except REDIS_DOWN as error:  # not the job's fault: the watchdog re-sends it later
        log.warning("job %s: Redis unavailable while solving level %d: %s", job_id, index, error)
        raise
    except Exception:
        log.exception("job %s: bundle task of level %d failed", job_id, index)
        message = orchestration.internal_error(job_id, f"solving level {index + 1}")
        return _fail(ctx, job_id, message, task_id)
    finally:
        if task_id:
            store.task_ended(job_id, task_id)
            fair.task_ended(store.redis, settings.key_prefix, queue, task_id)
    return result if result is not None else {"skipped": True}


def _retry_or_fail(
    ctx: WorkerContext,
    task: Task,
    job_id: str,
    error: TransientSolverError,
    doing: str,
    task_id: str | None = None,
) -> dict:
    """Retry ``task`` after ``min(retry_backoff * 2**retries, retry_backoff_max)`` seconds
    (``orchestration.retry_delay``), or fail the job once ``Settings.task_retries`` are spent.

    By hand, not Celery's ``autoretry_for``/``retry_backoff``: that backoff is whole seconds (the
    service tests retry after 0.1 s) and, retries spent, raises into the chord instead of failing
    the job with a message.
    """
    settings = ctx.settings
    retries = task.request.retries
    if retries < settings.task_retries:
        delay = orchestration.retry_delay(settings, retries)
        log.warning("job %s: %s: %s; retry in %.1f s", job_id, doing, error, delay)
        raise task.retry(countdown=delay, max_retries=settings.task_retries) from error
    message = f"{error} (still failing after {retries} retries; try again later)"
    return _fail(ctx, job_id, message, task_id)


def time_limit_message(ctx: WorkerContext, job_id: str, index: int, *, hard: bool) -> str:
    """What a user reads when one of the job's solver tasks ran out of time."""
    record = ctx.store.get(job_id)
    solver = record.config.solver if record else "?"
    limits = task_time_limits(ctx.settings, solver)
    limit = limits["time_limit" if hard else "soft_time_limit"]
    how = "was stopped" if hard else "ran out of time"
    return (
        f"a task of level {index + 1} {how} after the time limit of {limit:g} s per task "
        "(QHSM_TASK_SOFT_TIME_LIMIT, per solver QHSM_SOLVER_TIME_LIMITS); use fewer reads or "
        "sweeps, a smaller image, or ask the operator to raise the limit"
    )


def memory_message(ctx: WorkerContext, index: int) -> str:
    """What a user reads when one of the job's tasks needed more memory than a process has."""
    return (
        f"a task of level {index + 1} needed more memory than the limit of {ctx.budget_mb()} "
        "MiB per worker process (its share of the host's memory: QHSM_MEMORY_HOST_FRACTION and "
        "QHSM_HOST_WORKER_PROCESSES, or QHSM_TASK_MEMORY_LIMIT_MB) and was stopped; use fewer "
        "reads, smaller bundles, a smaller image or range, or ask the operator for more memory"
    )


def _fail(ctx: WorkerContext, job_id: str, message: str, task_id: str | None = None) -> dict:
    """Fail the job; its other running solver tasks are stopped (they would only waste
    workers: their results are no longer wanted)."""
    store = ctx.store
    record = store.get(job_id)
    solver = record.config.solver if record else "?"
    full = f"solver {solver!r} failed: {message}"
    log.warning("job %s failed: %s", job_id, full)  # in full: the record keeps a bounded text
    if store.fail(job_id, full):
        others = [other for other in store.running_tasks(job_id) if other != task_id]
        terminate_tasks(app, others, solver)
    return {"error": full}
