"""Job records, uploads, level inputs and results: all in Redis, nothing on disk.

Workers need Redis and nothing else (no shared volume, no data directory of the API's): a
worker on another host reads everything a job needs from here. Large arrays are stored as hash
fields of bounded size (:mod:`workers.arrays`; views as the 8- or 16-bit integers they were
decoded from), and everything expires.

Keys (all under ``{key_prefix}:``):

    job:{id}                 JSON ``JobRecord`` (expires ``result_ttl_seconds`` after the end)
    jobs                     sorted set id -> creation time (newest-first listing)
    jobs:owner:{user}        the same, one user's jobs
    jobs:tag:{tag}           the same, the jobs with that tag (and jobs:owner:{user}:tag:{tag})
    jobs:active              hash id -> owner of the jobs queued or running (the per-user cap)
    job:{id}:upload          hash of the decoded views ``left``, ``right`` (their integer form,
                             in pieces): written by the API at submission, read by the control
                             worker; deleted when the job ends
    job:{id}:level:...       level inputs and solved bundles (:mod:`workers.level_store`)
    job:{id}:chunks, :tasks  chunk reports and running tasks (:mod:`workers.job_progress`)
    job:{id}:result, :view:  the result and the views beside it (:mod:`workers.job_results`)

Chunk reports and solved bundles are written with HSET, so a task that runs twice (a worker died
after solving, or the watchdog re-sent it) is counted once. A record changes by
:meth:`JobStore.apply` of one of its pure methods (``JobRecord.started``, ``failed``, ...), an
optimistic compare-and-set checked against ``workers.records.TRANSITIONS``, so a cancel racing
with the last fan-in resolves to exactly one final state.
"""

from __future__ import annotations

import contextlib
import json
import logging
from collections import OrderedDict
from collections.abc import Callable, Iterable
from functools import partial
from importlib.resources import files
from typing import Any, NamedTuple

import numpy as np
import redis
from redis.client import Pipeline

from shared.config import Settings
from workers.arrays import array_fields, array_from, from_npy
from workers.bounded import piece_bytes, read_hash, write_hash
from workers.job_progress import ProgressStorage
from workers.job_results import ResultStorage
from workers.level_store import LevelStorage
from workers.records import (
    ACTIVE,
    JOB_ID,
    JobRecord,
    JobState,
    TransitionError,
    allowed,
    load_record,
    now,
)
from workers.redis_client import Writes, client_for, members, text, update_watched

log = logging.getLogger(__name__)

#: Writes a new job and takes a place under its owner's active-job cap, in one script.
_CREATE = files(__package__).joinpath("create_job.lua").read_text(encoding="utf-8")


class UploadsMissingError(ValueError):
    """The job's uploads are gone from Redis (it ended, expired, or predates uploads in Redis)."""


class ActiveJobsCapError(Exception):
    """The owner already has ``cap`` jobs queued or running; nothing was written."""

    def __init__(self, owner: str, active: int, cap: int):
        super().__init__(f"user {owner!r} already has {active} jobs queued or running")
        self.owner, self.active, self.cap = owner, active, cap


class Applied(NamedTuple):
    """What :meth:`JobStore.apply` left: the record as stored afterwards (None: no such job),
    and whether the change was written."""

    record: JobRecord | None
    changed: bool


class JobStore(LevelStorage, ProgressStorage, ResultStorage):
    """Job records and uploads in Redis (see the module's keys); level inputs, progress and
    results are its mixins' (:mod:`workers.level_store`, :mod:`workers.job_progress`,
    :mod:`workers.job_results`), over :class:`~workers.store_base.StoreBase`."""

    def __init__(self, client: redis.Redis, settings: Settings):
        super().__init__(client, settings)
        self._create = client.register_script(_CREATE)
        self._images = OrderedDict()  # LevelStorage._level_images

    @classmethod
    def from_settings(cls, settings: Settings) -> JobStore:
        return cls(client_for(settings), settings)

    def ping(self) -> bool:
        return bool(self.redis.ping())

    # records ----------------------------------------------------------------------------------

    def create(
        self, record: JobRecord, arrays: dict[str, np.ndarray], cap: int | None = None
    ) -> None:
        """Write the uploads (``left``, ``right``, optional ``ground_truth``) and the record.

        The uploads go to Redis first, in one transaction (integer form, bounded pieces), so
        a worker that sees the record finds them. With ``cap``, the owner may have at most
        that many jobs queued or running: the count and the record's write are one Redis
        script (:class:`ActiveJobsCapError` when full), so simultaneous submits never get past it.
        Whatever fails on the way (the cap, Redis full or gone) leaves no upload behind."""
        if not JOB_ID.match(record.id):
            raise ValueError(f"malformed job id {record.id!r}")
        written = [self._upload_key(record.id), self._truth_key(record.id)]
        uploads: list[dict[str, bytes]] = [{}, {}]
        piece = piece_bytes(self.limit)
        for name, array in arrays.items():
            fields = array_fields(name, array, images=True, piece=piece)
            uploads[1 if name == "ground_truth" else 0].update(fields)
        try:
            for key, fields in zip(written, uploads, strict=True):
                # bounded commands, renamed into place: all of an upload or none
                write_hash(self.redis, key, fields, self.limit, self.view_ttl, "the uploads")
            owner = record.owner or ""
            keys = [
                self.key("job", record.id),
                self.key("jobs"),
                self.key("jobs", "active"),
                self.key("jobs", "owner", owner),
            ]
            args: list[str | int] = [
                record.id,
                owner,
                record.model_dump_json(),
                repr(record.created_at.timestamp()),
                cap or 0,
                self.key("job", ""),
            ]
            active = int(self._create(keys=keys, args=args))
            if active < 0:
                raise ActiveJobsCapError(owner, -1 - active, cap or 0)
            if record.tags:
                created = record.created_at.timestamp()
                with self.redis.pipeline() as pipe:
                    for index in self._tag_indexes(record):
                        pipe.zadd(index, {record.id: created})
                    pipe.execute()
        except BaseException:
            with contextlib.suppress(redis.RedisError):
                self.redis.delete(*written)
            raise

    def mark_dispatched(self, job_id: str) -> None:
        """Record that the job's start was sent (:attr:`JobRecord.dispatched`)."""
        self.update(
            job_id, lambda r: None if r.dispatched else r.model_copy(update={"dispatched": True})
        )

    def discard(self, job_id: str) -> None:
        """Remove a job that was written but could not be queued (its submit failed after
        :meth:`create`): record, indexes, uploads and views, as if it had never been."""
        record = self.get(job_id)
        with self.redis.pipeline() as pipe:
            pipe.delete(self.key("job", job_id), self._upload_key(job_id))
            pipe.zrem(self.key("jobs"), job_id)
            pipe.hdel(self.key("jobs", "active"), job_id)
            if record is not None and record.owner is not None:
                pipe.zrem(self.key("jobs", "owner", record.owner), job_id)
            for index in self._tag_indexes(record) if record is not None else []:
                pipe.zrem(index, job_id)
            pipe.execute()
        for key in self.redis.scan_iter(match=self.key("job", job_id, "view", "*")):
            self.redis.delete(key)

    def _tag_indexes(self, record: JobRecord) -> list[str]:
        """The job's entries in the tag indexes: everyone's (admins) and its owner's."""
        mine = ("jobs", "owner", record.owner or "")
        return [self.key(*scope, "tag", tag) for tag in record.tags for scope in (("jobs",), mine)]

    def _upload_key(self, job_id: str) -> str:
        return self.key("job", job_id, "upload")

    def _truth_key(self, job_id: str) -> str:
        return self.key("job", job_id, "view", "ground_truth")

    def load_upload(self, job_id: str, name: str) -> np.ndarray:
        """One upload of an active job: ``left``, ``right`` or ``ground_truth``."""
        if name == "ground_truth":
            truth = self.load_ground_truth(job_id)
            if truth is None:
                raise UploadsMissingError(
                    f"job {job_id}: its ground truth is gone; submit it again"
                )
            return truth
        return self.load_views(job_id)[0 if name == "left" else 1]

    def load_views(self, job_id: str) -> tuple[np.ndarray, np.ndarray]:
        """The uploaded left and right views of an active job, from Redis (one read).

        Raises
        ------
        UploadsMissingError
            The job ended or expired (or was queued before uploads were kept in Redis)."""
        fields = read_hash(self.redis, self._upload_key(job_id), self.limit)
        if b"left" not in fields or b"right" not in fields:
            raise UploadsMissingError(
                f"job {job_id}: its uploaded views are gone (it ended or expired, or was "
                "submitted before an upgrade of the service); submit it again"
            )
        return array_from(fields, "left"), array_from(fields, "right")

    def load_ground_truth(self, job_id: str) -> np.ndarray | None:
        """The job's ground truth (stored values) while its record lasts; None without one."""
        fields = read_hash(self.redis, self._truth_key(job_id), self.limit)
        if fields:
            return array_from(fields, "ground_truth")
        older = self.load_view(job_id, "ground_truth.npy")  # jobs of earlier versions
        return None if older is None else from_npy(older)

    def get(self, job_id: str) -> JobRecord | None:
        if not JOB_ID.match(job_id):
            return None
        raw = self.redis.get(self.key("job", job_id))
        return None if raw is None else load_record(raw, job_id)

    def state(self, job_id: str) -> JobState | None:
        record = self.get(job_id)
        return None if record is None else record.state

    def apply(
        self, job_id: str, change: Callable[..., JobRecord | None], /, *args: Any, **kwargs: Any
    ) -> Applied:
        """Write ``change(record, *args, **kwargs)`` atomically (optimistic locking): a pure
        function of the current record, usually one of :class:`JobRecord`'s state changes,
        that returns None to leave it alone. A state the transition table does not allow
        from the current one raises :class:`TransitionError`."""
        key = self.key("job", job_id)

        def step(raw: bytes | None) -> tuple[tuple[Applied, JobRecord | None], Writes | None]:
            current = None if raw is None else load_record(raw, job_id)
            if current is None:
                return (Applied(None, False), None), None
            changed = change(current.model_copy(deep=True), *args, **kwargs)
            if changed is None:
                return (Applied(current, False), None), None
            if not allowed(current.state, changed.state):
                raise TransitionError(
                    f"job {job_id}: {current.state} -> {changed.state} is not allowed"
                )
            ended = changed if changed.state.terminal and not current.state.terminal else None
            return (Applied(changed, True), ended), partial(self._write_change, key, changed)

        applied, ended = update_watched(self.redis, key, step)
        if ended is not None:
            self._finished(job_id, ended.pinned)
        return applied

    def _write_change(self, key: str, changed: JobRecord, pipe: Pipeline) -> None:
        """The changed record, kept for the results' time once it has ended (unless pinned)."""
        pipe.set(key, changed.model_dump_json(), keepttl=True)
        if changed.state.terminal and not changed.pinned:
            pipe.expire(key, self.ttl)

    def update(
        self, job_id: str, change: Callable[[JobRecord], JobRecord | None]
    ) -> JobRecord | None:
        """:meth:`apply` ``change``; the record as stored afterwards (None: no such job)."""
        return self.apply(job_id, change).record

    def transition(
        self,
        job_id: str,
        to: JobState,
        allowed_from: Iterable[JobState],
        **fields: Any,
    ) -> JobRecord | None:
        """Move to ``to`` if the current state is in ``allowed_from``; None if it was not."""
        applied = self.apply(job_id, JobRecord.moved, to, now(), allowed_from, **fields)
        return applied.record if applied.changed else None

    def fail(self, job_id: str, message: str) -> bool:
        """Fail an active job with a message for the user; False if it had already ended."""
        return self.apply(job_id, JobRecord.failed, now(), message).changed

    def _finished(self, job_id: str, pinned: bool = False) -> None:
        """A job reached a final state: drop what only running jobs need; what it keeps expires
        with its record (a pinned job's is kept)."""
        self.redis.hdel(self.key("jobs", "active"), job_id)
        for key in self.redis.scan_iter(match=self.key("job", job_id, "level", "*")):
            self.redis.delete(key)
        self.redis.delete(self._upload_key(job_id))
        if pinned:
            self._keep(job_id, None)
            return
        for key in self.redis.scan_iter(match=self.key("job", job_id, "view", "*")):
            self.redis.expire(key, self.ttl)

    def _kept_keys(self, job_id: str) -> list[str]:
        """What a job keeps after its end: record, result (with its maps), views, progress."""
        keys = [self.key("job", job_id, part) for part in ("result", "chunks")]
        found = self.redis.scan_iter(match=self.key("job", job_id, "view", "*"))
        return [self.key("job", job_id), *keys, *(text(key) for key in found)]

    def _keep(self, job_id: str, seconds: int | None) -> None:
        """Every kept key of the job without expiry (None) or expiring in ``seconds``."""
        with self.redis.pipeline() as pipe:
            for key in self._kept_keys(job_id):
                if seconds is None:
                    pipe.persist(key)
                else:
                    pipe.expire(key, seconds)
            pipe.execute()

    def pin(self, job_id: str, pinned: bool) -> JobRecord | None:
        """Pin the job (nothing of it expires) or unpin it: a finished job then expires
        ``result_ttl_seconds`` after its end (at once when that has passed), an active one's
        views as while it runs. The record as stored (None: no such job)."""
        record = self.apply(job_id, JobRecord.pinned_as, pinned).record
        if record is None or record.pinned is not pinned:
            return record
        if pinned:
            self._keep(job_id, None)
        elif record.state.terminal and record.finished_at is not None:
            left = record.finished_at.timestamp() + self.ttl - now().timestamp()
            self._keep(job_id, max(1, int(left)))
        else:
            for key in self._kept_keys(job_id)[1:]:
                self.redis.expire(key, self.view_ttl)
        return record

    def list_jobs(
        self, offset: int = 0, limit: int = 20, owner: str | None = None, tag: str | None = None
    ) -> tuple[list[JobRecord], int]:
        """Jobs newest first (only ``owner``'s, only those tagged ``tag``, when given), and how
        many there are; expired records are dropped on the way."""
        scope = ("jobs",) if owner is None else ("jobs", "owner", owner)
        index = self.key(*scope) if tag is None else self.key(*scope, "tag", tag)
        ids = members(self.redis.zrevrange(index, offset, offset + limit - 1))
        raws = self.redis.mget([self.key("job", job_id) for job_id in ids]) if ids else []
        records, expired = [], []
        for job_id, raw in zip(ids, raws, strict=True):
            if raw is None:
                expired.append(job_id)
            elif (record := load_record(raw, job_id)) is not None:
                records.append(record)
        if expired:
            self.redis.zrem(index, *expired)
        return records, int(self.redis.zcard(index))

    def active_jobs(self, owner: str) -> int:
        """How many of ``owner``'s jobs are queued or running (the per-user cap counts them).

        Reads the small ``jobs:active`` index, not the owner's history; entries whose record
        is gone or already final (a crash between the two writes) are dropped on the way."""
        index = self.key("jobs", "active")
        ids = [text(job) for job, who in self.redis.hgetall(index).items() if text(who) == owner]
        if not ids:
            return 0
        raws = self.redis.mget([self.key("job", job_id) for job_id in ids])
        stale = [
            job_id
            for job_id, raw in zip(ids, raws, strict=True)
            if raw is None or json.loads(raw).get("state") not in ACTIVE
        ]
        if stale:
            self.redis.hdel(index, *stale)
        return len(ids) - len(stale)
