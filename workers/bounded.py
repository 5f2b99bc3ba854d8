"""Hashes written to and read from Redis in commands of bounded size
(``Settings.redis_max_command_bytes``): Redis runs one command at a time, so a command that
carries a gigabyte (a 2000x2000 pair's level inputs in one transaction) stalls every other
client for seconds; in pieces of a few MiB, another job's small commands run between them.

A hash that must appear whole (uploads, a level's inputs) is written under a staging key and
renamed into place (``RENAME`` is one constant-time command), so a reader sees all of it or
none. A write Redis refuses (full memory or disk) raises :class:`DataNotStoredError`, whose
message says what could not be stored, why, and what to do.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterable, Iterator, Mapping

import redis

from workers.redis_client import as_bytes

#: Room for a command's framing and field names beside its values, bytes.
COMMAND_OVERHEAD = 1024


class DataNotStoredError(ValueError):
    """Redis refused to store a job's data (out of memory or disk): the message says what,
    why and what to do. A ``ValueError``, so the job fails with it (it is not a bug)."""


def piece_bytes(limit: int) -> int:
    """Largest value of one hash field under a command limit of ``limit`` bytes."""
    return max(limit - COMMAND_OVERHEAD, 1)


def batches(fields: Mapping[str, bytes], limit: int) -> Iterator[dict[str, bytes]]:
    """``fields`` in groups whose names and values add up to at most ``limit`` bytes (a field
    larger than that alone is a group of its own: :func:`array_fields` never makes one)."""
    batch: dict[str, bytes] = {}
    size = 0
    for name, value in fields.items():
        cost = len(name) + len(value)
        if batch and size + cost > limit - COMMAND_OVERHEAD:
            yield batch
            batch, size = {}, 0
        batch[name] = value
        size += cost
    if batch:
        yield batch


def write_hash(
    client: redis.Redis,
    key: str,
    fields: Mapping[str, bytes],
    limit: int,
    ttl: int | None = None,
    what: str = "the job's data",
) -> None:
    """Write ``fields`` to the hash ``key`` in HSET commands of at most ``limit`` bytes, under a
    staging key renamed to ``key`` at the end (it replaces what ``key`` held): readers see the
    whole hash or none of it. Raises :class:`DataNotStoredError` when Redis refuses a write."""
    staging = f"{key}:partial:{uuid.uuid4().hex}"
    total = sum(len(value) for value in fields.values())
    try:
        for batch in batches(fields, limit):
            client.hset(staging, mapping=batch)  # type: ignore[arg-type]
            client.expire(staging, 3600)  # a writer that dies leaves nothing for long
        if fields:
            client.rename(staging, key)
        if ttl is not None:
            client.expire(key, ttl)
    except redis.ResponseError as error:
        client.delete(staging)
        raise not_stored(what, total, error) from error


def not_stored(what: str, total: int, error: Exception) -> DataNotStoredError:
    """The error of a write Redis refused, saying what and what to do."""
    return DataNotStoredError(
        f"{what} ({total / 2**20:.1f} MiB) could not be stored in the service's Redis "
        f"({str(error).split(chr(10))[0][:200]}); submit a smaller pair or fewer disparities "
        "(max_disparity), or ask the operator to give Redis more memory (maxmemory) or disk"
    )


def read_hash(
    client: redis.Redis, key: str, limit: int, names: Iterable[str] | None = None
) -> dict[bytes | str, bytes | str]:
    """The hash ``key`` (only ``names`` when given), read with HMGET commands whose replies are
    at most ``limit`` bytes each (the sizes come first, from one pipeline of HSTRLEN); an empty
    dict when it does not exist."""
    listed = names if names is not None else client.hkeys(key)
    wanted = [as_bytes(name) for name in listed]
    if not wanted:
        return {}
    with client.pipeline(transaction=False) as pipe:
        for name in wanted:
            pipe.hstrlen(key, name)
        sizes = pipe.execute()
    found: dict[bytes | str, bytes | str] = {}
    group: list[bytes] = []
    size = 0
    ends: list[tuple[bytes | None, int]] = [*zip(wanted, sizes, strict=True), (None, 0)]
    for field, length in ends:
        if group and (field is None or size + length > limit - COMMAND_OVERHEAD):
            values = client.hmget(key, group)
            found.update(
                {n: as_bytes(v) for n, v in zip(group, values, strict=True) if v is not None}
            )
            group, size = [], 0
        if field is not None:
            group.append(field)
            size += int(length)
    return found
