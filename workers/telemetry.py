"""The service's Prometheus metrics (``GET /metrics``), the one place they are defined.

Workers, the API and the watchdog run in many processes (and containers), so nothing is kept in
process memory: events are counted in Redis under ``{key_prefix}:metrics:*`` and the API's
collector reads them, with the job records, the queues and the QPU ledger, at scrape time.

    qhsm_jobs{state}                      jobs whose records exist now, by state
    qhsm_bundles_solved_total{solver}     bundles solved by the solver tasks
    qhsm_task_seconds{solver}             histogram of solver task run times
    qhsm_queue_depth{queue}               messages waiting in each Celery queue
    qhsm_qpu_seconds_used_total{user}     metered D-Wave seconds charged to each user
    qhsm_watchdog_resends_total           chunks re-sent by the watchdog (:meth:`Telemetry.resent`)
    qhsm_pixels_decided_total{solver,stage}  pixels of succeeded jobs' final maps by the stage
                                          that decided them (``shared.provenance_map``)
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Iterable, Iterator

import redis
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    Metric,
)
from prometheus_client.registry import Collector

from shared.config import Settings
from workers.redis_client import client_for, members, text

#: Upper bounds (seconds) of the task-time histogram's buckets.
TASK_SECONDS_BUCKETS = (0.1, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1800.0)
#: Job records read per Redis round trip when counting states.
BATCH = 500


def _bucket(seconds: float) -> str:
    """The name of the (non-cumulative) bucket ``seconds`` falls in."""
    for bound in TASK_SECONDS_BUCKETS:
        if seconds <= bound:
            return repr(bound)
    return "+Inf"


class Telemetry:
    """Counters in Redis, written by whichever process sees the event."""

    def __init__(self, client: redis.Redis, key_prefix: str):
        self.redis = client
        self.prefix = key_prefix

    @classmethod
    def from_settings(cls, settings: Settings, client: redis.Redis | None = None) -> Telemetry:
        return cls(client or client_for(settings), settings.key_prefix)

    def key(self, *parts: object) -> str:
        return ":".join([self.prefix, "metrics", *map(str, parts)])

    def task_done(self, solver: str, seconds: float, bundles: int) -> None:
        """A solver task of ``solver`` solved ``bundles`` bundles in ``seconds``."""
        with self.redis.pipeline(transaction=False) as pipe:
            pipe.hincrby(self.key("bundles"), solver, bundles)
            histogram = self.key("task_seconds", solver)
            pipe.hincrby(histogram, _bucket(seconds), 1)
            pipe.hincrbyfloat(histogram, "sum", seconds)
            pipe.sadd(self.key("task_seconds", "solvers"), solver)
            pipe.execute()

    def pixels_decided(self, solver: str, counts: dict[str, int]) -> None:
        """A job of ``solver`` succeeded with these pixels per stage (its provenance map's)."""
        with self.redis.pipeline(transaction=False) as pipe:
            for stage, pixels in counts.items():
                pipe.hincrby(self.key("pixels", solver), stage, pixels)
            pipe.sadd(self.key("pixels", "solvers"), solver)
            pipe.execute()

    def resent(self, chunks: int = 1) -> None:
        """The watchdog re-sent ``chunks`` unsolved chunks of a stalled job."""
        self.redis.incrby(self.key("watchdog_resends"), chunks)


class ServiceCollector(Collector):
    """Reads every metric from Redis when Prometheus scrapes ``/metrics``."""

    def __init__(self, settings: Settings, client: redis.Redis, queues: Iterable[str]):
        self.settings = settings
        self.redis = client
        self.telemetry = Telemetry(client, settings.key_prefix)
        self.queues = sorted(set(queues))

    def _key(self, *parts: object) -> str:
        return ":".join([self.settings.key_prefix, *map(str, parts)])

    def collect(self) -> Iterator[Metric]:
        yield self._jobs()
        yield self._bundles()
        yield self._task_seconds()
        yield self._queue_depth()
        yield self._qpu_seconds()
        yield self._pixels()
        resends = CounterMetricFamily(
            "qhsm_watchdog_resends", "Chunks of stalled jobs re-sent by the watchdog"
        )
        resends.add_metric([], float(self.redis.get(self.telemetry.key("watchdog_resends")) or 0))
        yield resends

    def _jobs(self) -> Metric:
        from workers.records import JobState

        states: Counter[str] = Counter({state.value: 0 for state in JobState})
        index, start = self._key("jobs"), 0
        while ids := members(self.redis.zrange(index, start, start + BATCH - 1)):
            raws = self.redis.mget([self._key("job", job_id) for job_id in ids])
            states.update(json.loads(raw).get("state", "unknown") for raw in raws if raw)
            start += BATCH
        family = GaugeMetricFamily(
            "qhsm_jobs", "Jobs by state (records not expired)", None, ["state"]
        )
        for state, count in sorted(states.items()):
            family.add_metric([state], count)
        return family

    def _bundles(self) -> Metric:
        family = CounterMetricFamily(
            "qhsm_bundles_solved", "Bundles solved, by solver", labels=["solver"]
        )
        for solver, count in sorted(self.redis.hgetall(self.telemetry.key("bundles")).items()):
            family.add_metric([text(solver)], float(count))
        return family

    def _pixels(self) -> Metric:
        family = CounterMetricFamily(
            "qhsm_pixels_decided",
            "Pixels of succeeded jobs' maps by the stage that decided them (provenance map)",
            labels=["solver", "stage"],
        )
        solvers = self.redis.smembers(self.telemetry.key("pixels", "solvers"))
        for solver in sorted(text(raw) for raw in solvers):
            stages = self.redis.hgetall(self.telemetry.key("pixels", solver))
            for stage, count in sorted(stages.items()):
                family.add_metric([solver, text(stage)], float(count))
        return family

    def _task_seconds(self) -> Metric:
        family = HistogramMetricFamily(
            "qhsm_task_seconds", "Run time of solver tasks, seconds", labels=["solver"]
        )
        solvers = self.redis.smembers(self.telemetry.key("task_seconds", "solvers"))
        for solver in sorted(text(raw) for raw in solvers):
            counts = {
                text(key): value
                for key, value in self.redis.hgetall(
                    self.telemetry.key("task_seconds", solver)
                ).items()
            }
            cumulative, buckets = 0, []
            for bound in (*map(repr, TASK_SECONDS_BUCKETS), "+Inf"):
                cumulative += int(counts.get(bound, 0))
                buckets.append((bound, cumulative))
            total = float(counts.get("sum", 0.0))
            family.add_metric([solver], buckets, sum_value=total if math.isfinite(total) else 0)
        return family

    def _queue_depth(self) -> Metric:
        family = GaugeMetricFamily(
            "qhsm_queue_depth", "Messages waiting in each Celery queue", labels=["queue"]
        )
        from workers.fair import user_queues

        prefix = self.settings.key_prefix
        lists = {queue: [queue, *user_queues(self.redis, prefix, queue)] for queue in self.queues}
        with self.redis.pipeline(transaction=False) as pipe:
            for names in lists.values():  # kombu's Redis transport: a list per queue
                for name in names:
                    pipe.llen(self._key(name))
            depths = iter(pipe.execute())
        for queue, names in lists.items():  # a solver's users' queues count as its own
            family.add_metric([queue], sum(next(depths) for _ in names))
        return family

    def _qpu_seconds(self) -> Metric:
        from workers.quota import QuotaLedger

        ledger = QuotaLedger(self.redis, self.settings.key_prefix)
        family = CounterMetricFamily(
            "qhsm_qpu_seconds_used", "Metered D-Wave seconds charged, by user", labels=["user"]
        )
        for user in ledger.users():
            family.add_metric([user], ledger.status(user).total_used)  # every period: a counter
        return family


def exposition(settings: Settings, client: redis.Redis, queues: Iterable[str]) -> bytes:
    """The metrics in Prometheus' text format."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(ServiceCollector(settings, client, queues))
    return generate_latest(registry)
