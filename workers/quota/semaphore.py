"""The lab-wide limit on QPU problems in flight (one D-Wave token serves the whole lab).

Slots are members of a sorted set scored by their expiry (Redis server time), so a killed
worker's slot frees itself after its ttl; taking one is ``acquire.lua``, counting ``count.lua``.

Keys (under ``{key_prefix}:``):

    qpu:slots                zset  slot token -> expiry        (lab-wide semaphore)
    qpu:slots:{user}         zset  slot token -> expiry        (per-user share, optional)
"""

from __future__ import annotations

import random
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager

import redis

from shared.config import Settings
from shared.solvers import TransientSolverError
from workers.quota.scripts import load_script

_ACQUIRE = load_script("now", "acquire")
_COUNT = load_script("now", "count")


class NoQpuSlotError(TransientSolverError):
    """Every lab-wide QPU slot stayed busy for the whole wait (retried later)."""


class QpuSemaphore:
    """At most ``limit`` QPU problems in flight lab-wide (and ``per_user`` per user).

    Waiting is polling with jittered backoff (QPU calls take tenths of a second to seconds, so
    this costs nothing noticeable).
    """

    def __init__(
        self, client: redis.Redis, key_prefix: str, limit: int, per_user: int | None = None
    ):
        self.redis = client
        self.prefix = key_prefix
        self.limit = limit
        self.per_user = per_user
        self._acquire = client.register_script(_ACQUIRE)
        self._count = client.register_script(_COUNT)

    @classmethod
    def from_settings(cls, settings: Settings, client: redis.Redis | None = None) -> QpuSemaphore:
        from workers.redis_client import client_for

        client = client or client_for(settings)
        return cls(
            client, settings.key_prefix, settings.qpu_max_in_flight,
            settings.qpu_max_in_flight_per_user,
        )  # fmt: skip

    def _keys(self, user: str) -> list[str]:
        slots = f"{self.prefix}:qpu:slots"
        return [slots, f"{slots}:{user}"]

    def try_acquire(self, user: str, ttl: float) -> str | None:
        """A slot token, or None when the lab (or this user's share) is full.

        Parameters
        ----------
        user : str
            Whose share the slot counts against.
        ttl : float
            Seconds after which the slot frees itself.

        Returns
        -------
        str or None
            The token to :meth:`release`.
        """
        token = uuid.uuid4().hex
        taken = self._acquire(
            keys=self._keys(user), args=[token, self.limit, self.per_user or 0, repr(float(ttl))]
        )
        return token if int(taken) else None

    def acquire(self, user: str, ttl: float, wait: float) -> str:
        """Wait up to ``wait`` seconds for a slot; :class:`NoQpuSlotError` when none frees up.

        Parameters
        ----------
        user, ttl
            As for :meth:`try_acquire`.
        wait : float
            Longest wait in seconds.

        Returns
        -------
        str
            The token to :meth:`release`.
        """
        deadline = time.monotonic() + wait
        delay = 0.02
        while True:
            token = self.try_acquire(user, ttl)
            if token is not None:
                return token
            if time.monotonic() >= deadline:
                raise NoQpuSlotError(
                    f"all {self.limit} lab-wide QPU slots stayed busy for {wait:g} s; "
                    "the bundle will be retried"
                )
            time.sleep(min(delay * random.uniform(0.5, 1.5), max(0.0, deadline - time.monotonic())))
            delay = min(delay * 2, 0.5)

    def release(self, user: str, token: str) -> None:
        """Free the slot ``token`` taken for ``user`` (a no-op once it expired)."""
        with self.redis.pipeline() as pipe:
            for key in self._keys(user):
                pipe.zrem(key, token)
            pipe.execute()

    def in_flight(self) -> int:
        """Live slots lab-wide."""
        return int(self._count(keys=self._keys("")[:1]))

    @contextmanager
    def slot(self, user: str, ttl: float, wait: float) -> Iterator[str]:
        """:meth:`acquire` for the body of a ``with`` block, released after it."""
        token = self.acquire(user, ttl, wait)
        try:
            yield token
        finally:
            self.release(user, token)
