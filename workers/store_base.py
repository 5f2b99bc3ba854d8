"""What the parts of :class:`workers.store.JobStore` share: the Redis client, the settings, the
key scheme and the bounds of one command; each part (records, level inputs, progress, results)
is a mixin over this base, in a module of its own."""

from __future__ import annotations

import redis

from shared.config import Settings


class StoreBase:
    """The client, the settings and the keys (under ``{key_prefix}:``) of a job store."""

    def __init__(self, client: redis.Redis, settings: Settings):
        self.redis = client
        self.settings = settings
        self.prefix = settings.key_prefix
        #: Seconds a finished job's record, result and views are kept.
        self.ttl = settings.result_ttl_seconds

    def key(self, *parts: object) -> str:
        return ":".join([self.prefix, *map(str, parts)])

    @property
    def limit(self) -> int:
        """Largest Redis command or reply of a job's data (``redis_max_command_bytes``)."""
        return self.settings.redis_max_command_bytes

    @property
    def view_ttl(self) -> int:
        """Lifetime of uploads and views while the job runs (at its end: :attr:`ttl`)."""
        return self.ttl + self.settings.task_visibility_timeout
