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
from workers.estimates import EstimateRecord, EstimateStore
from workers.process import memory_budget
from workers.quota import QuotaExceededError, QuotaLedger
from workers.store import UploadsMissingError
from workers.tasks import REDIS_DOWN, budget, settings, store

log = logging.getLogger(__name__)

_estimates: EstimateStore | None = None
_ledger: QuotaLedger | None = None


def estimates() -> EstimateStore:
    """This process's estimate store (sharing the job store's connection)."""
    global _estimates
    if _estimates is None or _estimates.redis is not store().redis:
        _estimates = EstimateStore(store().redis, settings)
    return _estimates


def ledger() -> QuotaLedger:
    global _ledger
    if _ledger is None or _ledger.redis is not store().redis:
        _ledger = QuotaLedger(store().redis, settings.key_prefix)
    return _ledger


def out_of_time(hard: bool) -> str:
    limits = task_time_limits(settings, PRICING)
    limit = limits["time_limit" if hard else "soft_time_limit"]
    return (
        f"pricing was stopped after the time limit of {limit:g} s (QHSM_TASK_SOFT_TIME_LIMIT, "
        'or QHSM_SOLVER_TIME_LIMITS={"pricing": ...}); give max_disparity, send a smaller '
        "pair, or ask the operator to raise the limit"
    )


def out_of_memory() -> str:
    return (
        f"pricing needed more memory than the limit of {budget()} MiB per worker process "
        "(QHSM_TASK_MEMORY_LIMIT_MB, or the host's share); send a smaller pair or range"
    )


class PricingTask(Task):
    """A pricing task; one killed at its hard time limit fails its job or estimate."""

    def on_failure(self, exc, task_id, args, kwargs, einfo) -> None:
        if isinstance(exc, TimeLimitExceeded) and args:
            if self.name == PRICE_JOB:
                store().fail(args[0], out_of_time(hard=True))
            else:
                estimates().apply(args[0], EstimateRecord.failed, out_of_time(hard=True))


@app.task(name=PRICE_JOB, bind=True, base=PricingTask, ignore_result=True)
def price_job(self, job_id: str) -> None:
    """Price a metered job, then queue and start it, or fail it with the reason."""
    try:
        with memory_budget(budget()):
            pricing.price_job(app, store(), ledger(), job_id, budget())
    except (QuotaExceededError, MemoryBudgetError, pricing.PricingError) as error:
        log.info("job %s refused at pricing: %s", job_id, error)
        store().fail(job_id, f"refused: {error}")
    except SoftTimeLimitExceeded:
        store().fail(job_id, out_of_time(hard=False))
    except MemoryError:
        store().fail(job_id, out_of_memory())
    except UploadsMissingError:
        return
    except (ValueError, DataNotStoredError) as error:  # views the range estimate cannot use
        store().fail(job_id, str(error))
    except REDIS_DOWN as error:
        log.warning("job %s: Redis unavailable while pricing it: %s", job_id, error)
        raise
    except Exception:
        log.exception("job %s: pricing failed", job_id)
        store().fail(job_id, orchestration.internal_error(job_id, "pricing the job"))


@app.task(name=PRICE_ESTIMATE, bind=True, base=PricingTask, ignore_result=True)
def price_estimate(self, estimate_id: str) -> None:
    """Compute an estimate (``POST /v1/estimate``), or fail it with the reason."""
    message = None
    try:
        with memory_budget(budget()):
            pricing.price_estimate(estimates(), store(), estimate_id)
    except (pricing.PricingError, ValueError) as error:
        message = str(error)
    except SoftTimeLimitExceeded:
        message = out_of_time(hard=False)
    except MemoryError:
        message = out_of_memory()
    except REDIS_DOWN as error:
        log.warning("estimate %s: Redis unavailable: %s", estimate_id, error)
        raise
    except Exception:
        log.exception("estimate %s failed", estimate_id)
        message = f"internal error computing estimate {estimate_id}; report it"
    if message is not None:
        estimates().apply(estimate_id, EstimateRecord.failed, message)
