"""A real Redis for the user/quota tests (the session's ``redis_url``: the local one, database
13, when it answers, else the embedded redis-server; ``QHSM_TEST_REDIS_URL`` chooses); every test
gets its own key prefix, deleted afterwards."""

from __future__ import annotations

import uuid

import pytest
import redis


@pytest.fixture(scope="session")
def redis_client(redis_url):
    client = redis.Redis.from_url(redis_url)
    yield client
    client.close()


@pytest.fixture
def prefix(redis_client):
    name = f"qhsm-test-users-{uuid.uuid4().hex[:10]}"
    yield name
    keys = list(redis_client.scan_iter(match=f"{name}:*", count=1000))
    if keys:
        redis_client.delete(*keys)


def redis_text(client, match: str) -> bytes:
    """Every key name and value (strings, hashes, sets, sorted sets, lists) matching ``match``,
    concatenated: for "this secret is nowhere in Redis" checks."""
    parts: list[bytes] = []
    for key in client.scan_iter(match=match, count=1000):
        kind = client.type(key).decode()
        parts.append(key)
        if kind == "string":
            parts.append(client.get(key) or b"")
        elif kind == "hash":
            for field, value in client.hgetall(key).items():
                parts += [field, value]
        elif kind == "set":
            parts += list(client.smembers(key))
        elif kind == "zset":
            parts += [member for member, _ in client.zrange(key, 0, -1, withscores=True)]
        elif kind == "list":
            parts += client.lrange(key, 0, -1)
        elif kind == "stream":
            for _, fields in client.xrange(key):
                for field, value in fields.items():
                    parts += [field, value]
    return b"\n".join(parts)


@pytest.fixture
def redis_values():
    return redis_text
