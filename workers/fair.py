"""Fair share between users: each user's bundles wait in a queue of their own.

A job's solver tasks go to ``{solver queue}~{owner}`` (``sa~ada``) instead of the solver's
queue. Every worker that consumes a solver's queue also consumes each of its users' queues (it
subscribes to new ones at its next heartbeat, ``workers/liveness.py``), and kombu's Redis
transport takes from a worker's queues in turn (it rotates the queue that just gave a message to
the end), so the users whose bundles wait are served round-robin: a user's small job waits for
at most a task per other user, not behind everything another user queued before it. Within a
user's queue tasks keep their order.

Keys (under ``{key_prefix}:``):

    fair:{queue}       set    the user queues of solver queue ``queue`` that were ever used
"""

from __future__ import annotations

import redis

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
    return sorted(raw.decode() for raw in client.smembers(_key(prefix, queue)))


def with_user_queues(client: redis.Redis, prefix: str, queues: list[str]) -> list[str]:
    """``queues`` and all their user queues (what holds a solver's waiting tasks)."""
    return [name for queue in queues for name in (queue, *user_queues(client, prefix, queue))]
