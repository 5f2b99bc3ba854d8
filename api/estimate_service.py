"""The estimate service (``POST /v1/estimate``, ``GET`` and ``DELETE /v1/estimates/{id}``): the
request is checked and its views decoded here, as a job's are; the estimate itself is computed on
a pricing worker (``workers.pricing``), never in the API process, so the POST answers at once
(202) and the client polls. An identical request (the same views, config and solver) is answered
from the cache of finished estimates, done at once.
"""

from __future__ import annotations

import math

from api.auth import Principal
from api.deps import Services
from api.errors import EstimateNotFoundError, PricingBusyError
from api.job_service import check_solver_name
from api.schemas import Estimate, EstimateStatus
from api.uploads import Upload, decode_pair, parse_config, read_upload
from api.users import UserStore
from shared.memory import worker_budget_mb
from workers import embedding_store
from workers.app import PRICE_ESTIMATE, PRICING, task_time_limits
from workers.estimates import (
    EstimateRecord,
    EstimateState,
    EstimateStore,
    request_digest,
    revoke,
)


def estimate_store(svc: Services) -> EstimateStore:
    return EstimateStore(svc.store.redis, svc.settings)


def request_estimate(
    params: str | None, left: Upload, right: Upload, owner: str, svc: Services
) -> EstimateRecord:
    """Check the request as a job's admission does up to its budget, then answer it from the
    cache or send it to the pricing queue (at most ``max_estimates_per_user`` of the owner's
    open at once: :class:`PricingBusyError`)."""
    settings = svc.settings
    config = parse_config(params)
    check_solver_name(config)
    uploads = read_upload(left, "left", settings), read_upload(right, "right", settings)
    store = estimate_store(svc)
    embeddings = embedding_store.for_settings(settings, svc.store.redis).generation()
    digest = request_digest(*uploads, config, embeddings)
    record = EstimateRecord(owner=owner, config=config, digest=digest)
    cached = store.cached(digest)
    if cached is not None:  # the same files and config were read and priced before
        done = record.done(cached, cached=True)
        assert done is not None  # a new record has not ended
        store.create_done(done)
        return done
    if store.open_for(owner) >= settings.max_estimates_per_user:
        raise PricingBusyError(settings.max_estimates_per_user)
    left_image, right_image = decode_pair(*uploads, settings)
    store.create(record, left_image, right_image)
    try:
        svc.celery.send_task(
            PRICE_ESTIMATE,
            args=(record.id,),
            queue=settings.pricing_queue,
            task_id=record.id,
            **task_time_limits(settings, PRICING),
        )
    except BaseException:
        store.apply(record.id, EstimateRecord.failed, "the estimate could not be queued")
        raise
    return record


def find_estimate(estimate_id: str, svc: Services, principal: Principal) -> EstimateRecord:
    """The caller's estimate (``EstimateNotFoundError``: none, expired, or someone else's);
    asking for it keeps it alive (``estimate_abandon_seconds``)."""
    store = estimate_store(svc)
    record = store.get(estimate_id)
    if record is None or (record.owner != principal.name and not principal.admin):
        raise EstimateNotFoundError(estimate_id, svc.settings.estimate_ttl_seconds)
    if not record.state.terminal:
        store.polled(estimate_id)
    return record


def cancel_estimate(estimate_id: str, svc: Services, principal: Principal) -> EstimateRecord:
    """Cancel the caller's estimate and stop its task; one that has ended is returned as it
    is (nothing to stop)."""
    record = find_estimate(estimate_id, svc, principal)
    if record.state.terminal:
        return record
    reason = "cancelled by its client (DELETE /v1/estimates/{id})"
    cancelled = estimate_store(svc).apply(estimate_id, EstimateRecord.cancelled, reason)
    revoke(svc.celery, [estimate_id])
    return cancelled or find_estimate(estimate_id, svc, principal)


def status_of(record: EstimateRecord, svc: Services, users: UserStore) -> EstimateStatus:
    """The wire form: the result against its owner's budget left now and the memory budget
    jobs are admitted with here (``check_memory``), once done."""
    result = None
    if record.state is EstimateState.DONE and record.result is not None:
        seconds = float(record.result["seconds"])
        remaining = users.ledger.status(record.owner).remaining if seconds > 0 else math.inf
        result = Estimate.of(record.result, remaining, worker_budget_mb(svc.settings))
    return EstimateStatus.of(record, result)
