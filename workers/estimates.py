"""Estimates (``POST /v1/estimate``) as the service keeps them: computed on a pricing worker
(``workers.pricing_tasks``), never in the API, and polled by the client.

The API writes an :class:`EstimateRecord` (``pending``) and the decoded pair (bounded pieces,
:mod:`workers.bounded`), then sends ``qhsm.price_estimate`` to the pricing queue with the
estimate's id as the task's id; the worker moves it to ``running`` and then ``done`` (with the
result, which also goes to the cache under the request's digest: the same views, config and
solver are answered from there at once) or ``failed`` (with the reason). A client that leaves
cancels (``DELETE /v1/estimates/{id}``); one that stops polling for
``Settings.estimate_abandon_seconds`` has its estimate revoked by :func:`sweep_abandoned`
(the control worker's watchdog).

Keys (all under ``{key_prefix}:``):
    estimate:{id}            JSON ``EstimateRecord`` (expires ``estimate_ttl_seconds``)
    estimate:{id}:views      hash of the decoded views (deleted when the estimate ends)
    estimates:open           sorted set id -> last poll (the estimates not ended yet)
    estimates:owner:{user}   set of that user's open estimates (``max_estimates_per_user``)
    estimate-cache:{digest}  JSON result of a finished estimate (expires ``estimate_ttl_seconds``)
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Callable
from datetime import datetime
from enum import StrEnum
from functools import partial
from typing import Any

import numpy as np
import redis
from celery import Celery
from pydantic import BaseModel, Field
from redis.client import Pipeline

from shared.config import MatchConfig, Settings
from workers.arrays import array_fields, array_from
from workers.bounded import piece_bytes, read_hash, write_hash
from workers.records import JOB_ID, bounded_message, new_job_id, now
from workers.redis_client import Writes, members, update_watched

log = logging.getLogger(__name__)


class EstimateState(StrEnum):
    PENDING = "pending"  # waiting for a pricing worker
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"  # by its client, or abandoned (nobody polled it)

    @property
    def terminal(self) -> bool:
        return self in (EstimateState.DONE, EstimateState.FAILED, EstimateState.CANCELLED)


class EstimateRecord(BaseModel):
    """One estimate: who asked, where it is, and its result or why there is none.

    ``result`` holds the wire ``Estimate``'s fields that do not depend on who reads it (not
    the budget left, which is read when it is polled)."""

    id: str = Field(default_factory=new_job_id)
    state: EstimateState = EstimateState.PENDING
    owner: str = ""
    config: MatchConfig
    digest: str = Field("", description="The request's cache key (views, config, solver)")
    created_at: datetime = Field(default_factory=now)
    finished_at: datetime | None = None
    cached: bool = False
    result: dict[str, Any] | None = None
    error: str | None = None
    #: While running: what the pricing worker is doing, and the share of the levels priced
    stage: str | None = None
    fraction: float | None = None

    # state changes: pure, the record to write or None where the estimate has ended already

    def _ended(self, state: EstimateState, **fields: Any) -> EstimateRecord | None:
        if self.state.terminal:
            return None
        ended = {"state": state, "finished_at": now(), "stage": None, "fraction": None}
        return self.model_copy(update=ended | fields)

    def running(self) -> EstimateRecord | None:
        if self.state is not EstimateState.PENDING:
            return None
        return self.model_copy(update={"state": EstimateState.RUNNING})

    def progressed(self, stage: str, fraction: float) -> EstimateRecord | None:
        if self.state is not EstimateState.RUNNING or (self.stage, self.fraction) == (
            stage,
            fraction,
        ):
            return None
        return self.model_copy(update={"stage": stage, "fraction": fraction})

    def done(self, result: dict[str, Any], cached: bool = False) -> EstimateRecord | None:
        return self._ended(EstimateState.DONE, result=result, cached=cached)

    def failed(self, message: str) -> EstimateRecord | None:
        return self._ended(EstimateState.FAILED, error=bounded_message(message))

    def cancelled(self, reason: str) -> EstimateRecord | None:
        return self._ended(EstimateState.CANCELLED, error=reason)


def request_digest(left: bytes, right: bytes, config: MatchConfig, embeddings: int = 0) -> str:
    """The cache key of an estimate: the uploaded files' digests, the config (its solver and
    solver parameters included) as JSON, and how many embeddings the workers have stored
    (``embeddings``: an estimate made before a bundle shape was embedded assumed its qubits;
    once it is, the same request is priced again with the embedding). Read before the views
    are decoded, so a repeat is answered without decoding them."""
    digest = hashlib.sha256(f"{embeddings}:".encode())
    for upload in (left, right):
        digest.update(hashlib.sha256(upload).digest())
    digest.update(config.model_dump_json().encode())
    return digest.hexdigest()


class EstimateStore:
    """Estimate records, their views and the cache of results, in Redis (module's keys)."""

    def __init__(self, client: redis.Redis, settings: Settings):
        self.redis = client
        self.settings = settings
        self.ttl = settings.estimate_ttl_seconds

    def key(self, *parts: object) -> str:
        return ":".join([self.settings.key_prefix, *map(str, parts)])

    # records ----------------------------------------------------------------------------------

    def create(self, record: EstimateRecord, left: np.ndarray, right: np.ndarray) -> None:
        """Write the views (bounded pieces, whole or not at all) and then the record, open."""
        piece = piece_bytes(self.settings.redis_max_command_bytes)
        fields = array_fields("left", left, images=True, piece=piece)
        fields |= array_fields("right", right, images=True, piece=piece)
        views = self.key("estimate", record.id, "views")
        limit = self.settings.redis_max_command_bytes
        write_hash(self.redis, views, fields, limit, self.ttl, "the estimate's views")
        self._write(record)
        self._opened(record)

    def create_done(self, record: EstimateRecord) -> None:
        """Write an estimate answered at once (from the cache): nothing to compute."""
        self._write(record)

    def _write(self, record: EstimateRecord) -> None:
        self.redis.set(self.key("estimate", record.id), record.model_dump_json(), ex=self.ttl)

    def _opened(self, record: EstimateRecord) -> None:
        with self.redis.pipeline() as pipe:
            pipe.zadd(self.key("estimates", "open"), {record.id: now().timestamp()})
            pipe.sadd(self.key("estimates", "owner", record.owner), record.id)
            pipe.expire(self.key("estimates", "owner", record.owner), self.ttl)
            pipe.execute()

    def get(self, estimate_id: str) -> EstimateRecord | None:
        if not JOB_ID.match(estimate_id):
            return None
        raw = self.redis.get(self.key("estimate", estimate_id))
        return None if raw is None else EstimateRecord.model_validate_json(raw)

    def load_views(self, estimate_id: str) -> tuple[np.ndarray, np.ndarray] | None:
        key = self.key("estimate", estimate_id, "views")
        fields = read_hash(self.redis, key, self.settings.redis_max_command_bytes)
        if b"left" not in fields or b"right" not in fields:
            return None
        return array_from(fields, "left"), array_from(fields, "right")

    def apply(
        self, estimate_id: str, change: Callable[..., EstimateRecord | None], *args: Any
    ) -> EstimateRecord | None:
        """Write ``change(record, *args)`` atomically (optimistic locking); the record written,
        or None where there is none or the change does not apply (:meth:`_write_change`)."""
        key = self.key("estimate", estimate_id)

        def step(raw: bytes | None) -> tuple[EstimateRecord | None, Writes | None]:
            current = None if raw is None else EstimateRecord.model_validate_json(raw)
            changed = None if current is None else change(current, *args)
            if changed is None:
                return None, None
            return changed, partial(self._write_change, estimate_id, changed)

        return update_watched(self.redis, key, step)

    def _write_change(self, estimate_id: str, changed: EstimateRecord, pipe: Pipeline) -> None:
        """The changed record; an estimate that ends leaves the open index, its owner's count
        and its views behind."""
        pipe.set(self.key("estimate", estimate_id), changed.model_dump_json(), keepttl=True)
        if changed.state.terminal:
            pipe.zrem(self.key("estimates", "open"), estimate_id)
            pipe.srem(self.key("estimates", "owner", changed.owner), estimate_id)
            pipe.delete(self.key("estimate", estimate_id, "views"))

    def polled(self, estimate_id: str) -> None:
        """Its client is still there: the abandon clock starts again (open estimates only)."""
        self.redis.zadd(self.key("estimates", "open"), {estimate_id: now().timestamp()}, xx=True)

    def last_poll(self, estimate_id: str) -> float | None:
        """When its client last asked (epoch seconds); None once it has ended."""
        score = self.redis.zscore(self.key("estimates", "open"), estimate_id)
        return None if score is None else float(score)

    def open_for(self, owner: str) -> int:
        """How many of ``owner``'s estimates have not ended (records gone are dropped)."""
        key = self.key("estimates", "owner", owner)
        ids = members(self.redis.smembers(key))
        if not ids:
            return 0
        raws = self.redis.mget([self.key("estimate", i) for i in ids])
        stale = [i for i, raw in zip(ids, raws, strict=True) if raw is None]
        if stale:
            self.redis.srem(key, *stale)
        return len(ids) - len(stale)

    def abandoned(self, seconds: float) -> list[str]:
        """Open estimates nobody asked about for ``seconds``."""
        before = now().timestamp() - seconds
        return members(self.redis.zrangebyscore(self.key("estimates", "open"), 0, before))

    # the cache --------------------------------------------------------------------------------

    def cached(self, digest: str) -> dict[str, Any] | None:
        raw = self.redis.get(self.key("estimate-cache", digest))
        return None if raw is None else json.loads(raw)

    def cache(self, digest: str, result: dict[str, Any]) -> None:
        self.redis.set(self.key("estimate-cache", digest), json.dumps(result), ex=self.ttl)


def revoke(celery: Celery, task_ids: list[str]) -> None:
    """Stop pricing tasks: revoked where still queued, killed where running (SIGKILL: the
    survey is native code that ignores anything softer; a pricing task holds no QPU slot)."""
    if task_ids:
        celery.control.revoke(task_ids, terminate=True, signal="SIGKILL")


def sweep_abandoned(celery: Celery, store: EstimateStore) -> list[str]:
    """Cancel and stop the estimates nobody polled for ``estimate_abandon_seconds``; their
    ids."""
    seconds = store.settings.estimate_abandon_seconds
    reason = (
        f"abandoned: nobody asked for it for {seconds:g} s (QHSM_ESTIMATE_ABANDON_SECONDS); "
        "poll GET /v1/estimates/{id} while you wait for it"
    )
    gone = [i for i in store.abandoned(seconds) if store.apply(i, EstimateRecord.cancelled, reason)]
    for estimate_id in store.abandoned(seconds):  # its record expired: only the index is left
        if store.get(estimate_id) is None:
            store.redis.zrem(store.key("estimates", "open"), estimate_id)
    if gone:
        log.info("estimates abandoned by their clients, stopped: %s", ", ".join(gone))
        revoke(celery, gone)
    return gone
