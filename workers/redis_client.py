"""The one place a Redis client is made, and the decoding of its replies.

Every store (jobs, users, quota, telemetry, liveness, embeddings) connects through
:func:`client_for` (or :func:`connect` for a URL given on a command line), so connection options
are decided here and a store takes an existing client in tests. Clients return ``bytes``
(``decode_responses`` off) unless a caller asks otherwise; :func:`text` turns a reply into ``str``
whatever the client's setting, which is also what redis-py's type hints (``bytes | str``) ask for.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any, TypeVar

import redis
from redis.client import Pipeline

from shared.config import Settings

T = TypeVar("T")

#: Queues a change's commands on a pipeline (inside its MULTI).
Writes = Callable[[Pipeline], object]

#: Where the service looks for Redis when ``QHSM_REDIS_URL`` is unset.
DEFAULT_REDIS_URL = "redis://127.0.0.1:6379/0"


def redis_url(settings: Settings) -> str:
    """The configured Redis, or a local one on the default port."""
    return settings.redis_url or DEFAULT_REDIS_URL


def connect(url: str, **options: Any) -> redis.Redis:
    """A client of the Redis at ``url`` (``options``: redis-py's, e.g. ``socket_timeout``)."""
    return redis.Redis.from_url(url, **options)


def client_for(settings: Settings, **options: Any) -> redis.Redis:
    """A client of the service's Redis (:func:`redis_url`)."""
    return connect(redis_url(settings), **options)


def text(value: bytes | str) -> str:
    """A Redis reply as ``str`` (UTF-8), whether or not the client decodes responses."""
    return value.decode() if isinstance(value, bytes) else value


def as_bytes(value: bytes | str) -> bytes:
    """A Redis reply as ``bytes``, whether or not the client decodes responses."""
    return value if isinstance(value, bytes) else value.encode()


def members(reply: Iterable[object]) -> list[str]:
    """The members of a sorted-set range read without scores (``ZRANGE``), as ``str``."""
    names = []
    for member in reply:
        if not isinstance(member, bytes | str):
            raise TypeError(f"a sorted-set member, not {type(member).__name__}: read with scores?")
        names.append(text(member))
    return names


def scored(reply: Iterable[object]) -> dict[str, float]:
    """A sorted-set range read with scores (``ZRANGE ... WITHSCORES``): member -> score."""
    scores = {}
    for pair in reply:
        if not isinstance(pair, tuple | list) or len(pair) != 2:
            raise TypeError(f"a (member, score) pair, not {pair!r}: read without scores?")
        member, score = pair
        scores[text(member)] = float(score)
    return scores


def update_watched(
    client: redis.Redis, key: str, step: Callable[[bytes | None], tuple[T, Writes | None]]
) -> T:
    """Optimistic locking of one key: ``step(value)`` (None: no such key) says what to answer
    and what to write (None: nothing); the writes go in one ``MULTI``/``EXEC`` that fails when
    another client changed ``key`` since it was read, and then ``step`` runs again on the new
    value. An exception from ``step`` leaves the key unchanged."""
    with client.pipeline() as pipe:
        while True:
            try:
                pipe.watch(key)
                raw = pipe.get(key)
                answer, writes = step(None if raw is None else as_bytes(raw))
                if writes is None:
                    pipe.unwatch()
                    return answer
                pipe.multi()
                writes(pipe)
                pipe.execute()
                return answer
            except redis.WatchError:
                continue
