"""A worker process's context: the :class:`Settings` its Celery app was made with and the
services built from them (job store, QPU meter, metrics writer, estimate store, quota ledger).

Built when the process starts (:func:`start`: at import for the worker's main process, again in
each pool process after the fork, so no Redis connection crosses a fork) and handed to the
tasks' code, which reads no settings from the environment or from module globals of its own.
The services are made on first use: a control worker never opens the QPU meter.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from shared.config import Settings
from shared.memory import worker_budget_mb
from workers import fair
from workers.estimates import EstimateStore
from workers.quota import QpuMeter, QuotaLedger
from workers.store import JobStore
from workers.telemetry import Telemetry


@dataclass
class WorkerContext:
    """What a worker process's tasks run with; one per process (:func:`current`)."""

    settings: Settings
    _store: JobStore | None = field(default=None, repr=False)
    _meter: QpuMeter | None = field(default=None, repr=False)
    _telemetry: Telemetry | None = field(default=None, repr=False)
    _estimates: EstimateStore | None = field(default=None, repr=False)
    _ledger: QuotaLedger | None = field(default=None, repr=False)

    @property
    def store(self) -> JobStore:
        """The job store (its connection opened in this process)."""
        if self._store is None:
            self._store = JobStore.from_settings(self.settings)
        return self._store

    @property
    def meter(self) -> QpuMeter:
        """The QPU meter (budgets and lab-wide slots), on the store's connection."""
        if self._meter is None:
            self._meter = QpuMeter.from_settings(self.settings, self.store.redis)
        return self._meter

    @property
    def telemetry(self) -> Telemetry:
        """The metrics writer (``workers.telemetry``), on the store's connection."""
        if self._telemetry is None:
            self._telemetry = Telemetry(self.store.redis, self.settings.key_prefix)
        return self._telemetry

    @property
    def estimates(self) -> EstimateStore:
        """The estimate store of ``POST /v1/estimate``, on the store's connection."""
        if self._estimates is None or self._estimates.redis is not self.store.redis:
            self._estimates = EstimateStore(self.store.redis, self.settings)
        return self._estimates

    @property
    def ledger(self) -> QuotaLedger:
        """The owners' QPU budgets (the pricing's admission check)."""
        if self._ledger is None or self._ledger.redis is not self.store.redis:
            self._ledger = QuotaLedger(
                self.store.redis, self.settings.key_prefix, self.settings.budget_period
            )
        return self._ledger

    def budget_mb(self) -> int | None:
        """This process's memory budget, MiB (``shared.memory.worker_budget_mb``: its share of
        its own host's memory)."""
        return worker_budget_mb(self.settings)


_current: WorkerContext | None = None


def start(settings: Settings) -> WorkerContext:
    """Build this process's context from ``settings`` (its app's); services are made anew."""
    global _current
    _current = WorkerContext(settings)
    fair.FewestRunningFirst.settings = settings  # kombu's queue order reads the worker's Redis
    return _current


def current() -> WorkerContext:
    """This process's context (:func:`start` must have run: ``workers.tasks`` starts it)."""
    if _current is None:
        raise RuntimeError("no worker context: workers.context.start(settings) was not called")
    return _current
