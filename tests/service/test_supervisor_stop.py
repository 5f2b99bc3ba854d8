"""`qhsm serve`'s stop (``workers.supervisor.stop_all``, ``Stack.stop``) on stand-in worker
processes (no Redis, no Celery): every worker gets its warm shutdown at once and the stop takes
the slowest one's time, not the sum; the kill after the one shared deadline; Redis stopped only
after the last worker is gone."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from shared.config import Settings
from workers.supervisor import Stack, WorkerProcess, stop_all

#: How long a stand-in worker's warm shutdown takes (its "running task" finishing), seconds.
WARM_SECONDS = 1.0

#: A stand-in for a Celery worker: on SIGTERM it "finishes its task" (sleeps, writes a marker)
#: and exits 0; with ``ignore`` it ignores SIGTERM (a task stuck in native code).
STAND_IN = """
import signal, sys, time
seconds, marker, ignore = float(sys.argv[1]), sys.argv[2], sys.argv[3] == "ignore"
def finish(signum, frame):
    time.sleep(seconds)
    open(marker, "w").write("finished")
    sys.exit(0)
signal.signal(signal.SIGTERM, signal.SIG_IGN if ignore else finish)
print("ready", flush=True)
while True:
    time.sleep(0.05)
"""


def stand_in(folder: Path, name: str, seconds: float, ignore: bool = False) -> WorkerProcess:
    """A running stand-in worker, its SIGTERM handler installed (else SIGTERM would end it at
    once and prove nothing)."""
    marker = folder / f"{name}.finished"
    worker = WorkerProcess(name, [name], 1, {}, folder / f"{name}.log")
    worker.process = subprocess.Popen(
        [sys.executable, "-c", STAND_IN, str(seconds), str(marker), "ignore" if ignore else ""],
        stdout=subprocess.PIPE,
    )
    assert worker.process.stdout is not None
    assert worker.process.stdout.readline() == b"ready\n"
    return worker


def finished(folder: Path, worker: WorkerProcess) -> bool:
    return (folder / f"{worker.name}.finished").exists()


def test_the_warm_stops_overlap_and_each_finishes_its_task(tmp_path):
    workers = [stand_in(tmp_path, name, WARM_SECONDS) for name in ("control", "pricing", "cpu")]
    started = time.monotonic()
    stop_all(workers, timeout=30)
    elapsed = time.monotonic() - started
    assert [worker.process.returncode for worker in workers] == [0, 0, 0]  # not killed
    assert all(finished(tmp_path, worker) for worker in workers)
    # one after another would take 3 * WARM_SECONDS
    assert WARM_SECONDS <= elapsed < 2 * WARM_SECONDS, elapsed


def test_workers_past_the_shared_deadline_are_killed_together(tmp_path):
    quick = stand_in(tmp_path, "quick", 0.0)
    names = ("stuck-a", "stuck-b", "stuck-c")
    stuck = [stand_in(tmp_path, name, 0.0, ignore=True) for name in names]
    started = time.monotonic()
    stop_all([*stuck, quick], timeout=WARM_SECONDS)
    elapsed = time.monotonic() - started
    assert quick.process.returncode == 0 and finished(tmp_path, quick)
    assert [worker.process.returncode for worker in stuck] == [-9, -9, -9]
    # one deadline for all: each stuck worker waited its own timeout would take 3 * WARM_SECONDS
    assert WARM_SECONDS <= elapsed < 2 * WARM_SECONDS, elapsed


class FakeRedis:
    """Records, when it is stopped, which workers were still running."""

    def __init__(self, workers: list[WorkerProcess]) -> None:
        self.workers = list(workers)
        self.alive_at_stop: list[bool] | None = None

    def stop(self) -> None:
        self.alive_at_stop = [worker.alive for worker in self.workers]


def test_stack_stops_redis_only_after_every_worker_has_exited(tmp_path):
    """A warm shutdown acks the finished tasks and puts held messages back, in Redis."""
    workers = [stand_in(tmp_path, name, WARM_SECONDS) for name in ("control", "cpu")]
    redis = FakeRedis(workers)
    stack = Stack(Settings(data_dir=tmp_path), workers=list(workers), supervise=False)
    stack.redis = redis  # type: ignore[assignment]
    started = time.monotonic()
    stack.stop()
    assert time.monotonic() - started < 2 * WARM_SECONDS
    assert redis.alive_at_stop == [False, False]
    assert all(finished(tmp_path, worker) for worker in workers)
    assert stack.workers == [] and stack.redis is None
