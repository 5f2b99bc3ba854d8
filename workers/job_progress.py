"""What a running job's tasks report, in Redis: the part of :class:`workers.store.JobStore` the
job status reads while the job runs (progress, solver time, D-Wave problem ids) and that a
cancel reads to stop its tasks.

Keys (under ``{key_prefix}:``; see :mod:`workers.store` for the rest):

    job:{id}:chunks   hash "{level}:{first row}" -> JSON ``ChunkReport`` (progress, usage)
    job:{id}:tasks    set of the ids of the job's solver tasks running now

Chunk reports are written with HSET, so a task that runs twice (a worker died after solving, or
the watchdog re-sent it) is counted once.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from workers.records import ChunkReport, JobRecord, JobState, Progress
from workers.redis_client import text
from workers.store_base import StoreBase


class ProgressStorage(StoreBase):
    """Chunk reports and running tasks of a job (mixed into ``JobStore``)."""

    if TYPE_CHECKING:  # LevelStorage's (the preparing level's phase, in words)

        def phase(self, job_id: str, index: int) -> str | None: ...

    def record_chunk(self, job_id: str, first_row: int | str, chunk: ChunkReport) -> None:
        """Idempotent (a task solved twice counts once); expires like the job's record."""
        key = self.key("job", job_id, "chunks")
        with self.redis.pipeline() as pipe:
            pipe.hset(key, f"{chunk.level}:{first_row}", chunk.model_dump_json())
            pipe.expire(key, self.ttl + self.settings.task_visibility_timeout)
            pipe.execute()

    def chunks(self, job_id: str) -> list[ChunkReport]:
        raw = self.redis.hvals(self.key("job", job_id, "chunks"))
        return [ChunkReport.model_validate_json(value) for value in raw]

    def progress(self, record: JobRecord, chunks: list[ChunkReport] | None = None) -> Progress:
        chunks = self.chunks(record.id) if chunks is None else chunks
        current = record.level - 1
        done = sum(chunk.bundles for chunk in chunks if chunk.level == current)
        done = record.bundles_total if record.state is JobState.SUCCEEDED else done
        preparing = record.state is JobState.RUNNING and not record.bundles_total
        return Progress(
            level=record.level,
            levels=record.levels_total,
            bundles_done=min(done, record.bundles_total),
            bundles_total=record.bundles_total,
            phase=self.phase(record.id, max(current, 0)) if preparing else None,
            stage=record.pricing_stage,  # a pricing job's (workers.pricing)
            fraction=record.pricing_fraction,
        )

    @staticmethod
    def usage(chunks: list[ChunkReport]) -> dict[str, float]:
        """Solver time spent on the job so far, summed over solved chunks (seconds)."""
        total: dict[str, float] = {"solver_seconds": 0.0}
        for chunk in chunks:
            total["solver_seconds"] += chunk.wall_time
            for key, value in chunk.timing.items():
                total[key] = total.get(key, 0.0) + value
        return total

    @staticmethod
    def problem_ids(chunks: list[ChunkReport]) -> list[str]:
        """The ids SAPI gave the job's D-Wave problems, level by level."""
        return [i for chunk in sorted(chunks, key=lambda c: c.level) for i in chunk.problem_ids]

    # running solver tasks (what a cancel terminates) ------------------------------------------

    def task_started(self, job_id: str, task_id: str) -> None:
        key = self.key("job", job_id, "tasks")
        with self.redis.pipeline() as pipe:
            pipe.sadd(key, task_id)
            pipe.expire(key, self.settings.task_visibility_timeout)
            pipe.execute()

    def task_ended(self, job_id: str, task_id: str) -> None:
        self.redis.srem(self.key("job", job_id, "tasks"), task_id)

    def running_tasks(self, job_id: str) -> list[str]:
        """Ids of the job's solver tasks that started and have not ended (or were killed)."""
        return sorted(text(raw) for raw in self.redis.smembers(self.key("job", job_id, "tasks")))
