"""Fair share between users: each user's bundles wait in a queue of their own, and a free worker
process takes the next task from the user who has the fewest tasks running lab-wide.

A job's solver tasks go to ``{solver queue}~{owner}`` (``sa~ada``) instead of the solver's
queue. Every worker that consumes a solver's queue also consumes each of its users' queues (it
subscribes to new ones at its next heartbeat, ``workers/liveness.py``). Which of its queues a
worker takes from is kombu's *queue order strategy*: :class:`FewestRunningFirst` puts the queues
of the users with the fewest solver tasks running now first (round-robin among equals, kombu's
own rotation), so a user whose small job arrives while another user's large jobs fill every
process gets the next free process, and the one after while they still run fewer. Within a
user's queue tasks keep their order.

Keys (under ``{key_prefix}:``):

    fair:{queue}           set    the user queues of solver queue ``queue`` that were ever used
    fair:running:{user}    zset   the user's solver tasks running now -> when their time limit
                                  ends (a killed task's entry lapses then)
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, ClassVar

import redis
from kombu.utils.scheduling import round_robin_cycle

from workers.redis_client import client_for, text

if TYPE_CHECKING:
    from shared.config import Settings

#: Between a solver's queue and the owner in a user queue's name (not allowed in user names).
SEPARATOR = "~"
#: The owner of jobs made without authentication (``workers.quota.LOCAL_USER``'s queue).
NOBODY = "local"


def user_queue(queue: str, owner: str | None) -> str:
    """The queue of ``owner``'s tasks for solver queue ``queue``."""
    return f"{queue}{SEPARATOR}{owner or NOBODY}"


def base_queue(queue: str) -> str:
    """The solver queue a (user) queue belongs to."""
    return queue.split(SEPARATOR, 1)[0]


def _key(prefix: str, queue: str) -> str:
    return f"{prefix}:fair:{queue}"


def route(client: redis.Redis, prefix: str, queue: str, owner: str | None) -> str:
    """The user queue for ``owner``'s tasks on ``queue``, recorded so that the workers of
    ``queue`` subscribe to it."""
    name = user_queue(queue, owner)
    client.sadd(_key(prefix, queue), name)
    return name


def user_queues(client: redis.Redis, prefix: str, queue: str) -> list[str]:
    """Every user queue of solver queue ``queue``."""
    return sorted(text(raw) for raw in client.smembers(_key(prefix, queue)))


def with_user_queues(client: redis.Redis, prefix: str, queues: list[str]) -> list[str]:
    """``queues`` and all their user queues (what holds a solver's waiting tasks)."""
    return [name for queue in queues for name in (queue, *user_queues(client, prefix, queue))]


def owner_of(queue: str) -> str | None:
    """The user whose queue this is (None for a solver's own queue)."""
    _, separator, owner = queue.partition(SEPARATOR)
    return owner if separator else None


def _running_key(prefix: str, owner: str) -> str:
    return f"{prefix}:fair:running:{owner}"


def task_started(client: redis.Redis, prefix: str, queue: str, task_id: str, limit: float) -> None:
    """A solver task taken from ``queue`` runs (for at most ``limit`` seconds)."""
    owner = owner_of(queue)
    if owner is not None:
        client.zadd(_running_key(prefix, owner), {task_id: time.time() + limit})


def task_ended(client: redis.Redis, prefix: str, queue: str, task_id: str) -> None:
    owner = owner_of(queue)
    if owner is not None:
        client.zrem(_running_key(prefix, owner), task_id)


def running(client: redis.Redis, prefix: str, owners: list[str]) -> dict[str, int]:
    """How many solver tasks each of ``owners`` has running lab-wide now."""
    now = time.time()
    with client.pipeline(transaction=False) as pipe:
        for owner in owners:
            pipe.zcount(_running_key(prefix, owner), now, "+inf")
        return dict(zip(owners, map(int, pipe.execute()), strict=True))


class FewestRunningFirst(round_robin_cycle):
    """kombu's order of a worker's queues (``broker_transport_options``' ``queue_order_strategy``):
    each poll, the queues of the users with the fewest tasks running first, then the solvers' own
    queues' order; kombu's rotation of the queue that just gave a message breaks ties."""

    #: Seconds a count of running tasks is reused (a poll comes at least once a second).
    FRESH = 0.2
    #: The worker's settings (its Redis and key prefix), handed over by its context when the
    #: process starts (:func:`workers.context.start`): kombu builds the strategy without
    #: arguments. None: kombu's own order.
    settings: ClassVar[Settings | None] = None

    def __init__(self, it=None) -> None:
        super().__init__(it)
        self._client: redis.Redis | None = None
        self._counts: tuple[float, dict[str, int]] = (0.0, {})

    def consume(self, n: int) -> list:
        queues = super().consume(n)
        owners = sorted({owner for queue in queues if (owner := owner_of(str(queue)))})
        if len(owners) < 2:
            return queues
        counts = self._running(owners)
        if counts is None:
            return queues
        return sorted(queues, key=lambda queue: counts.get(owner_of(str(queue)) or "", -1))

    def _running(self, owners: list[str]) -> dict[str, int] | None:
        """The owners' running tasks, from Redis at most every :attr:`FRESH` seconds; None
        when Redis cannot be asked (kombu's own order then)."""
        stamp, counts = self._counts
        if time.monotonic() - stamp < self.FRESH and set(owners) <= set(counts):
            return counts
        try:
            settings = self.settings
            if settings is None:
                return None
            if self._client is None:
                self._client = client_for(settings, socket_timeout=1)
            counts = running(self._client, settings.key_prefix, owners)
        except redis.RedisError:
            return None
        self._counts = (time.monotonic(), counts)
        return counts
