"""Pricing on a worker: what a job would be charged (the exact pyramid's survey of what the
classical steps leave, :mod:`shared.residual`, and the meters' walk,
:func:`shared.solvers.meters.qpu_time.job_seconds`), for ``POST /v1/estimate``
(:func:`price_estimate`) and for a metered job before it is queued (:func:`price_job`: its
budget checked, its levels' estimate kept for the reservations, then started). The API only
writes the request and polls: this module runs in the pricing worker
(``workers.pricing_tasks``), under its memory budget and time limit, never in the API process.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from celery import Celery

from shared.config import MatchConfig
from shared.disparity_range import RangeEstimate, resolve_max_disparity
from shared.memory import check_fits, job_memory_mb
from shared.pipeline import match_views
from shared.pyramid import plan
from shared.residual import job_residual
from shared.solvers.meters.qpu_time import JobEstimate, job_seconds
from shared.solvers.qpu.embedding_cache import EmbeddingCache
from workers import embedding_store
from workers.app import START_JOB
from workers.estimates import EstimateRecord, EstimateStore
from workers.queues import job_solver
from workers.quota import QuotaLedger
from workers.records import JobRecord, JobState, now
from workers.store import JobStore

log = logging.getLogger(__name__)

#: What a pricing job's status says it is doing (``JobRecord.pricing_stage``).
RANGE, SURVEY, ADMISSION = "estimating the disparity range", "surveying the levels", "admitting"

#: Told what pricing is doing and the share of the levels priced so far (0-1): a pricing
#: job's or estimate's progress.
Stage = Callable[[str, float], object]


def _quiet(stage: str, fraction: float) -> None:
    return None


class PricingError(ValueError):
    """The job cannot be priced with these parameters (the message says which)."""


@dataclass(frozen=True)
class Priced:
    """A job's price: its metered time, the range it was priced at (None: given) and its
    peak memory."""

    estimate: JobEstimate
    max_disparity: int
    disparity_range: RangeEstimate | None
    memory_mb: int

    def result(self) -> dict[str, Any]:
        """The wire ``Estimate``'s fields that do not depend on the reader's budget or the
        API's host (its memory budget)."""
        return {
            **self.estimate.as_dict(),
            "max_disparity": self.max_disparity,
            "memory_mb": self.memory_mb,
        }


def disparity_range_of(left: np.ndarray, right: np.ndarray, config: MatchConfig) -> RangeEstimate:
    """The job's disparity range (given, or estimated from the views): it decides the levels,
    hence the job's size."""
    return resolve_max_disparity(
        *match_views(left, right, config), config.max_disparity, warn=False
    )


def price(
    config: MatchConfig,
    left: np.ndarray,
    right: np.ndarray,
    cache: EmbeddingCache,
    stage: Stage = _quiet,
    resolve_range: bool = True,
) -> Priced:
    """The job's metered time with the embeddings workers have found for the bundle shapes
    they met and what the classical steps leave of its bundles (surveyed on the pair; its
    levels are what ``stage``'s fraction counts). ``resolve_range`` False: a given range is
    taken as it is (the job's start checks the views); ``PricingError`` for solver parameters
    the estimate cannot use."""
    found: RangeEstimate | None = None
    if resolve_range or not isinstance(config.max_disparity, int):
        stage(RANGE, 0.0)
        found = disparity_range_of(left, right, config)
    top = found.max_disparity if found is not None else int(config.max_disparity)
    stage(SURVEY, 0.0)

    def surveyed(done: int, total: int) -> None:
        stage(SURVEY, done / total)

    try:
        residual = job_residual(config, left, right, top, cache, surveyed)
        estimate = job_seconds(job_solver(config), left.shape[:2], top, cache, residual)
    except (TypeError, ValueError, KeyError) as error:
        raise PricingError(
            f"params: cannot estimate the job's QPU time from solver_params ({error})"
        ) from None
    memory = job_memory_mb(config, left.shape[0], left.shape[1], top)
    return Priced(estimate, top, found, memory)


def embedding_cache(store: JobStore) -> EmbeddingCache:
    """The embeddings the service's workers share through Redis."""
    return EmbeddingCache(embedding_store.for_settings(store.settings, store.redis))


def price_estimate(
    estimates: EstimateStore, store: JobStore, estimate_id: str
) -> EstimateRecord | None:
    """Compute an open estimate (``PricingError`` for unusable parameters): the record as
    finished, or None when it ended meanwhile (cancelled, abandoned) or is gone. Its result
    also goes to the cache under the request's digest."""
    started = estimates.last_poll(estimate_id)
    abandon = estimates.settings.estimate_abandon_seconds
    if started is None or now().timestamp() - started > abandon:  # ended, or nobody waits
        return None
    record = estimates.apply(estimate_id, EstimateRecord.running)
    views = estimates.load_views(estimate_id)
    if record is None or views is None:
        return None

    def stage(name: str, fraction: float) -> None:
        estimates.apply(estimate_id, EstimateRecord.progressed, name, fraction)

    priced = price(record.config, *views, embedding_cache(store), stage)
    result = priced.result()
    estimates.cache(record.digest, result)
    return estimates.apply(estimate_id, EstimateRecord.done, result)


def price_job(
    celery: Celery,
    store: JobStore,
    ledger: QuotaLedger,
    job_id: str,
    budget_mb: int | None,
) -> JobRecord | None:
    """Price a metered job and admit it: within its owner's budget (and this worker's memory
    budget) it is queued with its levels' estimate and started; else it fails with the reason
    a submit used to be refused with (``QuotaExceededError``, ``MemoryBudgetError``,
    ``PricingError``: the caller fails the job with the message). None when it is no longer
    pricing (cancelled meanwhile, or gone)."""
    record = store.get(job_id)
    if record is None or record.state is not JobState.PRICING:
        log.info("job %s: not pricing any more (cancelled or gone); nothing to do", job_id)
        return None
    left, right = store.load_views(job_id)

    def stage(name: str, fraction: float) -> None:
        store.apply(job_id, JobRecord.pricing_at, name, fraction)

    priced = price(record.config, left, right, embedding_cache(store), stage, resolve_range=False)
    stage(ADMISSION, 1.0)
    check_fits(priced.memory_mb, budget_mb)
    bundles = priced.estimate.bundles
    ledger.check(record.owner or "", priced.estimate.seconds, f"this job ({bundles} bundles)")
    applied = store.apply(
        job_id,
        JobRecord.priced,
        now(),
        [level.seconds for level in priced.estimate.levels],
        priced.disparity_range,
        len(plan(record.config, priced.max_disparity)),
        priced.memory_mb,
    )
    if not applied.changed or applied.record is None:
        return None
    celery.send_task(START_JOB, args=(job_id,), queue=store.settings.control_queue)
    store.mark_dispatched(job_id)
    return store.get(job_id)
