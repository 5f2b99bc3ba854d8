"""A job's data travels to and from Redis in commands of at most
``QHSM_REDIS_MAX_COMMAND_BYTES`` (issue 29: a 2000x2000 pair's level was one ~1 GB
transaction that stalled Redis for everyone), and a job whose data Redis refuses fails with a
message that says why and what to do. Small arrays against a 64 KiB limit."""

from __future__ import annotations

import base64

import numpy as np
import pytest
import redis

from shared import pyramid
from shared.config import MatchConfig
from shared.level_inputs import LevelInputs
from workers.bounded import DataNotStoredError
from workers.records import JobRecord, JobState, new_job_id, now
from workers.store import JobStore

LIMIT = 64 * 2**10


@pytest.fixture
def store(settings, monkeypatch) -> tuple[JobStore, list[int]]:
    """A store under a 64 KiB limit, and the sizes (bytes) of every command it sent and every
    reply it got, measured on the client."""
    bounded = JobStore.from_settings(settings.model_copy(update={"redis_max_command_bytes": LIMIT}))
    sizes: list[int] = []
    send = bounded.redis.execute_command

    def measured(*args, **options):
        reply = send(*args, **options)
        sizes.append(sum(len(a) if isinstance(a, bytes | str) else 8 for a in args))
        items = reply if isinstance(reply, list | dict) else [reply]
        values = items.items() if isinstance(items, dict) else items
        sizes.append(sum(len(v) if isinstance(v, bytes) else 8 for v in values))
        return reply

    monkeypatch.setattr(bounded.redis, "execute_command", measured)
    return bounded, sizes


def level_inputs(rng: np.random.Generator) -> LevelInputs:
    left = rng.random((120, 160, 3), dtype=np.float32)  # 230 KB a view
    candidates = rng.integers(0, 60, (120, 160, 6)).astype(np.int64)
    return LevelInputs(
        plan=pyramid.plan(MatchConfig(), 60)[-1], views=2, left=left, right=left[::-1],
        candidates=candidates, initial_labels=candidates[..., 0].astype(np.int32),
    )  # fmt: skip


def new_job(
    store: JobStore, width: int = 160, height: int = 120
) -> tuple[JobRecord, dict[str, np.ndarray]]:
    rng = np.random.default_rng(1)
    record = JobRecord(
        id=new_job_id(), config=MatchConfig(), width=width, height=height, created_at=now()
    )
    views = {
        "left": rng.random((height, width, 3), dtype=np.float32),
        "right": rng.random((height, width, 3), dtype=np.float32),
        "ground_truth": rng.random((height, width), dtype=np.float32) * 64,
    }
    store.create(record, views)
    return record, views


def test_uploads_levels_bundles_and_results_travel_in_bounded_commands(store):
    store, sizes = store
    record, views = new_job(store)
    for name, array in views.items():  # 690 KB of uploads
        assert np.array_equal(store.load_upload(record.id, name), array), name
    rng = np.random.default_rng(2)
    inputs = level_inputs(rng)
    store.save_level(record.id, inputs, started=1.0)
    loaded, _ = store.load_level(record.id, inputs.plan.index)
    for name in ("left", "right", "candidates", "initial_labels"):
        assert np.array_equal(getattr(loaded, name), getattr(inputs, name)), name
    # a whole view's labels (exact's bundle) are above a piece: they travel in pieces too
    labels = rng.integers(0, 6, (300, 400)).astype(np.uint8)
    big = {"rows": [0, 300], "columns": [0, 400], "energy": 1.0,
           "labels": base64.b64encode(labels.tobytes()).decode("ascii")}  # fmt: skip
    small = {**big, "rows": [300, 301], "labels": "AAAA"}
    store.save_bundles(record.id, 0, [big, small])
    solved = store.solved_bundles(record.id, 0)
    assert sorted(b["rows"][0] for b in solved.values()) == [0, 300]
    assert [b["labels"] for b in solved.values() if b["rows"][0] == 0] == [big["labels"]]
    assert store.solved_count(record.id, 0) == 2
    disparity = rng.random((300, 400), dtype=np.float32)  # 480 KB
    store.save_result(record.id, disparity)
    assert np.array_equal(store.load_result(record.id), disparity)
    assert max(sizes) <= LIMIT, max(sizes)
    assert sum(sizes) > 20 * LIMIT  # megabytes went through, in many commands


def test_a_job_whose_data_redis_refuses_fails_saying_why_and_what_to_do(store, monkeypatch):
    store, _ = store
    record, _ = new_job(store)
    store.transition(record.id, JobState.RUNNING, {JobState.QUEUED})

    def full(*args, **options):
        raise redis.ResponseError("OOM command not allowed when used memory > 'maxmemory'.")

    monkeypatch.setattr(store.redis, "hset", full)
    with pytest.raises(DataNotStoredError) as refused:
        store.save_level(record.id, level_inputs(np.random.default_rng(3)), started=1.0)
    message = str(refused.value)
    assert "inputs of level" in message and "could not be stored" in message
    assert "maxmemory" in message and "smaller pair" in message
    monkeypatch.undo()
    assert not list(store.redis.scan_iter(match=store.key("job", record.id, "level", "*")))
