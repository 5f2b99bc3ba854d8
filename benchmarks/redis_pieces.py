"""One large job's level inputs against another user's small commands (issue 29, item 3): the
largest Redis command a level write and read sends, and the worst latency of a small command
(a job status poll's GET) issued meanwhile by another client, with the level written and read
in bounded commands (``QHSM_REDIS_MAX_COMMAND_BYTES``, 4 MiB: ``workers.bounded``) against
one MULTI/EXEC transaction of all its pieces and one HGETALL (as before issue 29).

    python benchmarks/redis_pieces.py [SIDE] [CANDIDATES]   # default 2000 64: the issue's pair

Runs its own embedded Redis (with its append-only file, as `qhsm serve` does) in a temporary
folder. Prints one markdown row per mode (docs/benchmarks.md, "Bounded Redis commands").
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from multiprocessing import Event, Process, Queue
from pathlib import Path

import numpy as np
import redis

from shared import pyramid
from shared.config import MatchConfig, Settings
from shared.level_inputs import LevelInputs
from workers.arrays import array_fields, array_from
from workers.embedded_redis import EmbeddedRedis
from workers.store import JobStore

ROUNDS = 3


def level(side: int, candidates: int) -> LevelInputs:
    rng = np.random.default_rng(0)
    left = rng.random((side, side, 3), dtype=np.float32)
    labels = rng.integers(0, 200, (side, side, candidates), dtype=np.int16)
    return LevelInputs(
        plan=pyramid.plan(MatchConfig(), 200)[-1], views=2, left=left, right=left[::-1],
        candidates=labels, initial_labels=labels[..., 0].astype(np.int32),
    )  # fmt: skip


def whole(client: redis.Redis, key: str, inputs: LevelInputs) -> int:
    """The level written as before: one transaction of every piece, read with one HGETALL;
    the largest command's bytes."""
    fields: dict[str, bytes] = {}
    for name in ("left", "right", "candidates", "initial_labels"):
        fields.update(array_fields(name, getattr(inputs, name)))
    with client.pipeline() as pipe:
        for field, value in fields.items():
            pipe.hset(key, field, value)
        pipe.execute()
    stored = client.hgetall(key)
    assert array_from(stored, "candidates").shape == inputs.candidates.shape
    client.delete(key)
    return sum(len(value) for value in fields.values())


def bounded(store: JobStore, job_id: str, inputs: LevelInputs, sizes: list[int]) -> int:
    send = store.redis.execute_command

    def measured(*args, **options):
        sizes.append(sum(len(a) if isinstance(a, bytes | str) else 8 for a in args))
        return send(*args, **options)

    store.redis.execute_command = measured  # type: ignore[method-assign]
    try:
        store.save_level(job_id, inputs, started=0.0)
        store._images.clear()
        loaded, _ = store.load_level(job_id, inputs.plan.index)
        assert loaded.candidates.shape == inputs.candidates.shape
    finally:
        store.redis.execute_command = send  # type: ignore[method-assign]
    for key in store.redis.scan_iter(match=store.key("job", job_id, "*")):
        store.redis.delete(key)
    return max(sizes)


def poll(url: str, stop: Event, out: Queue) -> None:
    """Another user's small commands, every 10 ms, from a process of its own (no GIL shared
    with the writer): their latencies, seconds, put on ``out`` at the end."""
    client = redis.Redis.from_url(url)
    client.set("poll", b"x" * 200)
    latencies = []
    while not stop.is_set():
        started = time.perf_counter()
        client.get("poll")
        latencies.append(time.perf_counter() - started)
        time.sleep(0.01)
    out.put(latencies)


def main() -> None:
    side = int(sys.argv[1]) if len(sys.argv) > 1 else 2000
    candidates = int(sys.argv[2]) if len(sys.argv) > 2 else 64
    inputs = level(side, candidates)
    with tempfile.TemporaryDirectory() as folder:
        server = EmbeddedRedis(Path(folder) / "redis").start()
        try:
            settings = Settings(redis_url=server.url, key_prefix="bench", data_dir=Path(folder))
            store = JobStore.from_settings(settings)
            print(f"level {side}x{side}, {candidates} candidates; {ROUNDS} rounds, alternating")
            print("| mode | largest command (MiB) | data (MiB) | worst poll (ms) | median (ms) |")
            print("|---|---|---|---|---|")
            rows: dict[str, list[tuple[float, float, float, float]]] = {"whole": [], "bounded": []}
            for round_ in range(ROUNDS):
                for mode in ("whole", "bounded"):
                    stop, out = Event(), Queue()
                    poller = Process(target=poll, args=(server.url, stop, out))
                    poller.start()
                    time.sleep(0.3)
                    sizes: list[int] = []
                    if mode == "whole":
                        data = largest = whole(store.redis, f"bench:whole:{round_}", inputs)
                    else:
                        largest = bounded(store, f"{round_:032x}", inputs, sizes)
                        data = sum(sizes)
                    stop.set()
                    latencies = out.get()
                    poller.join()
                    rows[mode].append(
                        (largest / 2**20, data / 2**20, max(latencies) * 1e3,
                         statistics.median(latencies) * 1e3)
                    )  # fmt: skip
            for mode, measured in rows.items():
                worst = max(m[2] for m in measured)
                median = statistics.median(m[3] for m in measured)
                print(
                    f"| {mode} | {measured[0][0]:.1f} | {measured[0][1]:.0f} | "
                    f"{worst:.0f} | {median:.2f} |"
                )
        finally:
            server.stop()


if __name__ == "__main__":
    main()
