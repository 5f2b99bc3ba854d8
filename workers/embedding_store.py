"""Minor embeddings shared by every worker through Redis.

Implements the small store protocol of :mod:`shared.solvers.qpu.embedding_cache` (``get``/``set`` of
JSON text by structure key). The first worker that meets a bundle structure computes its
embedding (up to a minute at full resolution) and every other worker, job and restart reuses it.
Embeddings depend only on graph structure, so they are kept without expiry.
"""

from __future__ import annotations

import redis

from shared.config import Settings
from shared.solvers.qpu.embedding_cache import set_default_store
from workers.redis_client import client_for, connect, text

KEY_PREFIX = "qhsm:embedding:"
#: The count of embeddings stored, beside them (a structure key is a digest, never this).
GENERATION = "#generation"


class RedisEmbeddingStore:
    """``get``/``set`` of embedding JSON under ``{key_prefix}:embedding:<structure key>``."""

    def __init__(self, client: redis.Redis, prefix: str = KEY_PREFIX) -> None:
        self.client = client
        self.prefix = prefix

    @classmethod
    def from_url(cls, url: str) -> RedisEmbeddingStore:
        return cls(connect(url, decode_responses=True))

    def get(self, key: str) -> str | None:
        value = self.client.get(self.prefix + key)
        return None if value is None else text(value)

    def set(self, key: str, value: str) -> None:
        with self.client.pipeline() as pipe:
            pipe.set(self.prefix + key, value)
            pipe.incr(self.prefix + GENERATION)
            pipe.execute()

    def generation(self) -> int:
        """How many embeddings were stored so far: an estimate made before the last one may
        be priced with fewer known embeddings (``workers.estimates`` keys its cache by it)."""
        value = self.client.get(self.prefix + GENERATION)
        return 0 if value is None else int(text(value))


def for_settings(settings: Settings, client: redis.Redis | None = None) -> RedisEmbeddingStore:
    """The service's embedding store (``client``: an existing connection to its Redis)."""
    if client is None:
        client = client_for(settings, decode_responses=True)
    return RedisEmbeddingStore(client, prefix=f"{settings.key_prefix}:embedding:")


def install(settings: Settings) -> RedisEmbeddingStore:
    """Make Redis this process's embedding store (called at worker start-up)."""
    store = for_settings(settings)
    set_default_store(store)
    return store
