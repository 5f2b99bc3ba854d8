"""Batches (``POST /v1/batches``): many pairs sent as one request, one job per pair under one
batch id. A batch is one JSON value in Redis, ``{prefix}:batch:{id}``: its owner, tags and
its jobs' ids in the order of the pairs; each job's record names its batch too
(``JobRecord.batch``). It expires ``Settings.result_ttl_seconds`` after it was made or last
read while one of its jobs is still kept."""

from __future__ import annotations

import uuid
from datetime import datetime

import redis
from pydantic import BaseModel

from workers.redis_client import text


class BatchEntry(BaseModel):
    """One pair of a batch: the name it was sent under and its job's id."""

    name: str
    id: str


class BatchRecord(BaseModel):
    id: str
    owner: str
    created_at: datetime
    tags: list[str]
    jobs: list[BatchEntry]


def new_batch_id() -> str:
    return uuid.uuid4().hex


class BatchStore:
    """The batches in Redis, under the service's key prefix."""

    def __init__(self, client: redis.Redis, key_prefix: str, ttl_seconds: int):
        self.redis = client
        self.prefix = key_prefix
        self.ttl = ttl_seconds

    def key(self, batch_id: str) -> str:
        return f"{self.prefix}:batch:{batch_id}"

    def save(self, record: BatchRecord) -> None:
        self.redis.set(self.key(record.id), record.model_dump_json(), ex=self.ttl)

    def get(self, batch_id: str) -> BatchRecord | None:
        raw = self.redis.get(self.key(batch_id))
        return None if raw is None else BatchRecord.model_validate_json(text(raw))

    def keep(self, batch_id: str) -> None:
        """Keep the batch another ``ttl`` seconds (one of its jobs is still there)."""
        self.redis.expire(self.key(batch_id), self.ttl)
