"""Worker liveness, and the messages a dead worker held put back in their queues; the heartbeat
also makes a worker consume the user queues of its solver queues (``workers/fair.py``).

With ``acks_late`` a task's message stays in the broker's ``unacked`` hash until the task ends,
and Redis would hand it out again only after the 6-hour visibility timeout. So every worker's
main process says every ``Settings.worker_heartbeat_seconds`` that it is alive and which
messages it holds (the delivery tags of the tasks it received and has not finished, retries
waiting for their countdown included): :class:`Heartbeat`, a consumer bootstep whose timer
runs in the worker's own event loop. A worker that missed :data:`MISSED_BEATS` heartbeats is
dead; :func:`restore_orphans` (run by the watchdog) puts every unacknowledged message that no
live worker holds back at the head of its queue, through kombu's own ``restore_by_tag``. A live
worker's messages, however long their tasks run (a QPU embedding), are never touched.

Keys (under ``{key_prefix}:``):

    workers                set    worker instances (hostname#pid#random) that sent a heartbeat
    worker:{instance}      string JSON {"hostname", "held": [delivery tags]}, expires after
                                  MISSED_BEATS heartbeats
    unacked, unacked_index        kombu's: unacknowledged messages and when they were delivered
"""

from __future__ import annotations

import json
import logging
import os
import time
import uuid
from collections.abc import Iterable
from typing import Any

import redis
from celery import Celery, bootsteps, signals
from celery.worker import state

from shared.config import Settings
from workers import fair
from workers.redis_client import client_for, scored, text

log = logging.getLogger(__name__)

#: Heartbeats a worker may miss before it counts as dead.
MISSED_BEATS = 5
#: Heartbeats a delivered message may wait to appear in its worker's heartbeat.
DELIVERY_GRACE_BEATS = 3
#: Retries waiting for their countdown are held this long past their due time (seconds), by
#: when the worker has taken them up (they are then among its reserved requests).
ETA_SLACK = 60.0

#: Delivery tags of this worker's tasks that wait for a countdown (tag -> due, epoch seconds).
_waiting: dict[str, float] = {}


def instance_key(prefix: str, instance: str) -> str:
    return f"{prefix}:worker:{instance}"


def workers_key(prefix: str) -> str:
    return f"{prefix}:workers"


def unacked_keys(prefix: str) -> tuple[str, str]:
    """kombu's Redis transport keys (``global_keyprefix`` applies to them too)."""
    return f"{prefix}:unacked", f"{prefix}:unacked_index"


@signals.task_received.connect
def _note_countdown(request: Any = None, **_: object) -> None:
    """A retry waiting for its countdown sits in the worker's timer, not among its reserved
    requests: remember its tag until it is due."""
    eta = getattr(request, "eta", None)
    message = getattr(request, "message", None)
    if eta is not None and message is not None:
        due = eta.timestamp() if hasattr(eta, "timestamp") else time.time()
        _waiting[message.delivery_tag] = due


def held_tags(now: float | None = None) -> list[str]:
    """Delivery tags of every message this worker holds: received and not finished (running,
    reserved, or waiting for a countdown)."""
    now = time.time() if now is None else now
    for tag, due in list(_waiting.items()):
        if due + ETA_SLACK < now:
            del _waiting[tag]
    tags = set(_waiting)
    for request in [*state.reserved_requests, *state.active_requests]:
        message = getattr(request, "message", None)
        if message is not None and message.delivery_tag:
            tags.add(message.delivery_tag)
    return sorted(tags)


class Heartbeat(bootsteps.StartStopStep):
    """Writes this worker's liveness and held messages every ``worker_heartbeat_seconds``."""

    requires = ("celery.worker.consumer.tasks:Tasks",)

    def __init__(self, parent: Any, **kwargs: Any) -> None:
        super().__init__(parent, **kwargs)
        self.settings = parent.app.qhsm_settings  # the worker's app (workers.app.QhsmCelery)
        self.instance = f"{parent.hostname}#{os.getpid()}#{uuid.uuid4().hex[:8]}"
        self.client: redis.Redis | None = None
        self.timer_ref: Any = None

    def start(self, parent: Any) -> None:
        self.client = client_for(self.settings)
        self.beat(parent)
        self.timer_ref = parent.timer.call_repeatedly(
            self.settings.worker_heartbeat_seconds, self.beat, (parent,), priority=10
        )

    def stop(self, parent: Any) -> None:
        if self.timer_ref is not None:
            self.timer_ref.cancel()
            self.timer_ref = None

    def beat(self, parent: Any) -> None:
        """Say we are alive and what we hold, and consume the user queues of our solver
        queues that appeared since (``workers/fair.py``); a Redis outage only skips a beat."""
        if self.client is None:
            return
        prefix = self.settings.key_prefix
        ttl = MISSED_BEATS * self.settings.worker_heartbeat_seconds
        record = json.dumps({"hostname": parent.hostname, "held": held_tags()})
        try:
            with self.client.pipeline() as pipe:
                pipe.set(instance_key(prefix, self.instance), record, px=int(ttl * 1000))
                pipe.sadd(workers_key(prefix), self.instance)
                pipe.execute()
            self.follow_user_queues(parent)
        except redis.RedisError as error:
            log.warning("heartbeat not written (Redis unavailable): %s", error)

    def follow_user_queues(self, parent: Any) -> None:
        """Consume every user queue of the solver queues this worker consumes."""
        consumer = getattr(parent, "task_consumer", None)
        if consumer is None or self.client is None:
            return
        consumed = {queue.name for queue in consumer.queues}
        bases = {name for name in consumed if fair.SEPARATOR not in name}
        bases.discard(self.settings.control_queue)
        for base in sorted(bases):
            for name in fair.user_queues(self.client, self.settings.key_prefix, base):
                if name not in consumed:
                    parent.add_task_queue(name)
                    log.info("consuming %s (a user queue of %s)", name, base)


def install(celery: Celery) -> None:
    """Add the heartbeat to every worker of ``celery`` (called where the tasks are defined)."""
    celery.steps["consumer"].add(Heartbeat)


def live_holdings(client: redis.Redis, prefix: str) -> dict[str, set[str]]:
    """Live worker instance -> the delivery tags it holds; instances whose heartbeat expired
    are forgotten."""
    instances = sorted(text(raw) for raw in client.smembers(workers_key(prefix)))
    if not instances:
        return {}
    records = client.mget([instance_key(prefix, instance) for instance in instances])
    live, dead = {}, []
    for instance, raw in zip(instances, records, strict=True):
        if raw is None:
            dead.append(instance)
            continue
        try:
            live[instance] = set(json.loads(raw)["held"])
        except (ValueError, KeyError):
            live[instance] = set()
    if dead:
        client.srem(workers_key(prefix), *dead)
    return live


def orphans(client: redis.Redis, prefix: str, grace: float, now: float | None = None) -> list[str]:
    """Delivery tags of unacknowledged messages that no live worker holds, delivered more than
    ``grace`` seconds ago (younger ones may not be in their worker's heartbeat yet)."""
    unacked, index = unacked_keys(prefix)
    tags = [text(raw) for raw in client.hkeys(unacked)]
    if not tags:
        return []
    now = time.time() if now is None else now
    delivered = scored(client.zrange(index, 0, -1, withscores=True))
    held = set().union(*live_holdings(client, prefix).values())
    return [tag for tag in tags if tag not in held and now - delivered.get(tag, now) > grace]


def restore(celery: Celery, tags: Iterable[str]) -> int:
    """Put the messages ``tags`` back at the head of their queues (kombu's ``restore_by_tag``,
    which also marks them redelivered); returns how many were given."""
    tags = list(tags)
    if not tags:
        return 0
    with celery.connection_for_write() as connection:
        qos = connection.default_channel.qos
        for tag in tags:
            qos.restore_by_tag(tag)
    return len(tags)


def restore_orphans(celery: Celery, client: redis.Redis, settings: Settings) -> int:
    """Re-queue what dead workers held (see the module docstring); returns how many."""
    grace = DELIVERY_GRACE_BEATS * settings.worker_heartbeat_seconds
    found = orphans(client, settings.key_prefix, grace)
    if found:
        log.warning(
            "re-queueing %d unacknowledged messages that no live worker holds (their worker died)",
            len(found),
        )
    return restore(celery, found)
