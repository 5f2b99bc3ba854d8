"""Celery tasks of the pricing queue (``Settings.pricing_queue``): thin wrappers of
:mod:`workers.pricing` that turn its errors into a failed job or estimate with the reason.

They run under the same limits as every task: the process's memory budget
(:func:`workers.process.memory_budget`) and the time limits the API sends them with
(``task_time_limits(settings, "pricing")``); a task killed at its hard limit fails its job or
estimate too (:class:`PricingTask`).
"""

from __future__ import annotations

import logging

from celery import Task
from celery.exceptions import SoftTimeLimitExceeded, TimeLimitExceeded

from shared.memory import MemoryBudgetError
from workers import orchestration, pricing
from workers.app import PRICE_ESTIMATE, PRICE_JOB, PRICING, app, task_time_limits
from workers.bounded import DataNotStoredError
from workers.context import WorkerContext, current
from workers.estimates import EstimateRecord
from workers.process import memory_budget
from workers.quota import QuotaExceededError
from workers.store import UploadsMissingError
from workers.tasks import REDIS_DOWN

log = logging.getLogger(__name__)


def out_of_time(ctx: WorkerContext, hard: bool) -> str:
    limits = task_time_limits(ctx.settings, PRICING)
    limit = limits["time_limit" if hard else "soft_time_limit"]
    return (
        f"pricing was stopped after the time limit of {limit:g} s (QHSM_TASK_SOFT_TIME_LIMIT, "
        'or QHSM_SOLVER_TIME_LIMITS={"pricing": ...}); give max_disparity, send a smaller '
        "pair, or ask the operator to raise the limit"
    )


def out_of_memory(ctx: WorkerContext) -> str:
    return (
        f"pricing needed more memory than the limit of {ctx.budget_mb()} MiB per worker "
        "process (QHSM_TASK_MEMORY_LIMIT_MB, or the host's share); send a smaller pair or range"
    )


class PricingTask(Task):
    """A pricing task; one killed at its hard time limit fails its job or estimate."""

    def on_failure(self, exc, task_id, args, kwargs, einfo) -> None:
        if isinstance(exc, TimeLimitExceeded) and args:
            ctx = current()
            if self.name == PRICE_JOB:
                ctx.store.fail(args[0], out_of_time(ctx, hard=True))
            else:
                ctx.estimates.apply(args[0], EstimateRecord.failed, out_of_time(ctx, hard=True))


@app.task(name=PRICE_JOB, bind=True, base=PricingTask, ignore_result=True)
def price_job(self, job_id: str) -> None:
    """Price a metered job, then queue and start it, or fail it with the reason."""
    ctx = current()
    store = ctx.store
    try:
        with memory_budget(ctx.budget_mb()):
            pricing.price_job(app, store, ctx.ledger, job_id, ctx.budget_mb())
    except (QuotaExceededError, MemoryBudgetError, pricing.PricingError) as error:
        log.info("job %s refused at pricing: %s", job_id, error)
        store.fail(job_id, f"refused: {error}")
    except SoftTimeLimitExceeded:
        store.fail(job_id, out_of_time(ctx, hard=False))
    except MemoryError:
        store.fail(job_id, out_of_memory(ctx))
    except UploadsMissingError:
        return
    except (ValueError, DataNotStoredError) as error:  # views the range estimate cannot use
        store.fail(job_id, str(error))
    except REDIS_DOWN as error:
        log.warning("job %s: Redis unavailable while pricing it: %s", job_id, error)
        raise
    except Exception:
        log.exception("job %s: pricing failed", job_id)
        store.fail(job_id, orchestration.internal_error(job_id, "pricing the job"))


@app.task(name=PRICE_ESTIMATE, bind=True, base=PricingTask, ignore_result=True)
def price_estimate(self, estimate_id: str) -> None:
    """Compute an estimate (``POST /v1/estimate``), or fail it with the reason."""
    ctx = current()
    message = None
    try:
        with memory_budget(ctx.budget_mb()):
            pricing.price_estimate(ctx.estimates, ctx.store, estimate_id)
    except (pricing.PricingError, ValueError) as error:
        message = str(error)
    except SoftTimeLimitExceeded:
        message = out_of_time(ctx, hard=False)
    except MemoryError:
        message = out_of_memory(ctx)
    except REDIS_DOWN as error:
        log.warning("estimate %s: Redis unavailable: %s", estimate_id, error)
        raise
    except Exception:
        log.exception("estimate %s failed", estimate_id)
        message = f"internal error computing estimate {estimate_id}; report it"
    if message is not None:
        ctx.estimates.apply(estimate_id, EstimateRecord.failed, message)
